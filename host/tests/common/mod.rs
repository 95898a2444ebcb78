//! What the command-line tests share: a scratch directory per test and a
//! way to run the `brightpix` binary under test. Each test file uses a part.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// A fresh, empty `brightpix-SUITE-PID-NAME` in the system's temporary
/// directory.
pub fn scratch(suite: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brightpix-{suite}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The `brightpix` binary under test.
pub fn brightpix() -> Command {
    Command::new(env!("CARGO_BIN_EXE_brightpix"))
}

/// Runs `brightpix ARGS`: whether it succeeded, and its stdout then stderr.
pub fn run(args: &[&str]) -> (bool, String) {
    let out = brightpix().args(args).output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

/// `rig plan --boards 2 --camera-rate 1000` of `config` (the 3x3 windows of
/// [`small_wfs_config`]) on a link (`--link-rate`) of `share` of what the
/// busier of two bands of whole rows (6 windows) sends at 1 kHz: at 0.92,
/// runs of 5 and 4 windows in raster order keep up where the bands do not.
pub fn plan_two_on_a_link(config: &std::path::Path, share: f64, extra: &[&str]) -> (bool, String) {
    use brightpix::rig::{self, BoardKind, CostModel};
    let whole = brightpix::config_file::ProcessingConfig::load(config).unwrap();
    let (kind, model) = (BoardKind::Stm32h743, CostModel::STM32H743);
    let bands = rig::plan(&whole, 2, kind, &model).unwrap();
    let busiest = rig::loads(&whole, &bands.shares, kind, &model, Some(1000.0), false)
        .iter()
        .map(|l| l.result_bytes_per_s.unwrap())
        .fold(0.0, f64::max);
    let rate = format!("{:.6}", busiest * share / 1e6);
    let mut args = vec!["--camera-rate", "1000", "--link-rate", &rate];
    args.extend_from_slice(extra);
    plan_boards(config, 2, &args)
}

/// The rig tests' camera: 48x48, 12 bits, 3x3 sub-apertures of 16x16,
/// N = 6; written as `DIR/wfs.toml`, whose path is returned.
pub fn small_wfs_config(dir: &std::path::Path) -> PathBuf {
    let config = dir.join("wfs.toml");
    std::fs::write(
        &config,
        "[camera]\nwidth = 48\nheight = 48\nbit_depth = 12\n\
         [subapertures.grid]\nx = 0\ny = 0\ncolumns = 3\nrows = 3\nwidth = 16\nheight = 16\n\
         [selection]\npixels = 6\n",
    )
    .unwrap();
    config
}

/// Runs `brightpix rig plan --config CONFIG --boards BOARDS EXTRA..`.
pub fn plan_boards(config: &std::path::Path, boards: usize, extra: &[&str]) -> (bool, String) {
    let boards = boards.to_string();
    let mut args = vec![
        "rig",
        "plan",
        "--config",
        config.to_str().unwrap(),
        "--boards",
        &boards,
    ];
    args.extend_from_slice(extra);
    run(&args)
}

/// [`plan_boards`] with three boards: what it printed; panics if it fails.
pub fn plan_three_boards(config: &std::path::Path, extra: &[&str]) -> String {
    let (ok, text) = plan_boards(config, 3, extra);
    assert!(ok, "{text}");
    text
}
