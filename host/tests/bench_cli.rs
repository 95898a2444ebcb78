//! `brightpix bench` end to end on the host side (short runs: these check
//! what is printed and written, never how fast anything is).

use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brightpix-bench-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn brightpix(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .args(args)
        .output()
        .unwrap()
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

#[test]
fn host_bench_writes_a_row_per_workload_with_agreeing_peers() {
    let json = scratch("standard").join("figures.json");
    let run = brightpix(&[
        "bench",
        "--host-only",
        "--quick",
        "--rounds",
        "2",
        "--min-run-ms",
        "1",
        "--threads",
        "2",
        "--json",
        json.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(stdout.contains("canary-subtract-next-n20"), "{stdout}");
    assert!(stdout.contains("engine/baseline"), "{stdout}");
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    let names: Vec<&str> = rows
        .iter()
        .map(|r| r["workload"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "canary-subtract-next-n20",
            "ocam240-subtract-next-n20",
            "ocam240-level-filter-n20"
        ]
    );
    for row in rows {
        assert_eq!(row["kind"], "host");
        assert_eq!(row["threads"], 2);
        for figure in ["mpx_per_s", "x_sort", "x_best_peer", "engine_over_baseline"] {
            let stats = &row[figure];
            let (min, median, max) = (
                stats["min"].as_f64().unwrap(),
                stats["median"].as_f64().unwrap(),
                stats["max"].as_f64().unwrap(),
            );
            assert!(
                0.0 < min && min <= median && median <= max,
                "{figure}: {stats}"
            );
        }
        assert_eq!(row["rounds"], 2);
        // The no-selection baseline equals the engine with no selection.
        assert_eq!(row["baseline"]["agrees"], true);
        assert!(row["baseline"]["mpx_per_s"]["median"].as_f64().unwrap() > 0.0);
        let peers = row["peers"].as_array().unwrap();
        assert_eq!(peers.len(), 4);
        for peer in peers {
            assert_eq!(peer["agrees"], true, "{peer}");
        }
        // The sort in the engine's arithmetic is identical, the f32 peers within 2^-16 px.
        assert_eq!(peers[0]["max_slope_difference_px"], 0.0);
        assert!(peers[1]["max_slope_difference_px"].as_f64().unwrap() <= 1.0 / 65536.0);
    }
    assert_eq!(rows[2]["split"], "2 bands of sub-apertures");
}

#[test]
fn a_user_configuration_on_its_frames_says_whether_the_camera_fits_the_host() {
    let dir = scratch("user");
    let frames = dir.join("frames.npy");
    let pixels: Vec<u16> = (0..4 * 112 * 112)
        .map(|k| 50 + ((k * 7919) % 13) as u16 + if k % 16 == 7 { 300 } else { 0 })
        .collect();
    brightpix::io::write_array(&frames, &[4, 112, 112], &pixels).unwrap();
    let json = dir.join("figures.json");
    let config = examples().join("canary.toml");
    let run = brightpix(&[
        "bench",
        "--host-only",
        "--quick",
        "--rounds",
        "1",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--camera-rate",
        "250",
        "--json",
        json.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(stdout.contains("Your configuration"), "{stdout}");
    assert!(
        stdout.contains("this host:") && stdout.contains("at 250 Hz"),
        "{stdout}"
    );
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(rows[0]["workload"], "user");
    assert_eq!(rows[0]["frames"], 4);
}

#[test]
fn bad_arguments_are_refused_before_any_work() {
    for (args, expected) in [
        (vec!["--core", "m9"], "not a QEMU core"),
        (
            vec![
                "--config",
                "examples/canary.toml",
                "--camera-rate",
                "100",
                "--camera-size",
                "12",
            ],
            "not WIDTHxHEIGHT",
        ),
        (vec!["--mhz", "0"], "not a positive clock"),
        (vec!["--frames", "x.npy"], "--config"),
        // The board's bench mode (--port).
        (
            vec!["--port", "/nonexistent/tty", "--frames", "many"],
            "frames per workload",
        ),
        (vec!["--workload", "canary-subtract-next-n20"], "--port"),
        (
            vec!["--port", "/nonexistent/tty", "--host-only"],
            "--host-only",
        ),
        (vec!["--port", "/nonexistent/tty"], "/nonexistent/tty"),
        // The link test (--port --link): its figures are checked before
        // the port is opened.
        (vec!["--link"], "--port"),
        (
            vec!["--port", "/nonexistent/tty", "--link", "--workload", "x"],
            "--workload",
        ),
        (
            vec!["--port", "/nonexistent/tty", "--link", "--link-bytes", "0"],
            "--link-bytes 0: 1 to 16777216",
        ),
        (
            vec![
                "--port",
                "/nonexistent/tty",
                "--link",
                "--link-chunk",
                "961",
            ],
            "--link-chunk 961: 1 to 960",
        ),
        (
            vec!["--port", "/nonexistent/tty", "--link-bytes", "9"],
            "--link",
        ),
        (
            vec!["--config", "/nonexistent/c.toml", "--host-only"],
            "/nonexistent/c.toml",
        ),
    ] {
        let mut all = vec!["bench"];
        all.extend(args);
        let run = brightpix(&all);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{all:?} succeeded");
        assert!(stderr.contains(expected), "{all:?}: {stderr}");
    }
}

/// A source tree whose QEMU bench script is a stand-in that prints the
/// contract's `BENCH` lines (for `--config`, with the sizes of the files it
/// was given), and a `qemu-system-arm` on PATH: the plumbing of
/// `brightpix bench` without emulating anything.
fn fake_tree(name: &str) -> (PathBuf, String) {
    let root = scratch(name).join("tree");
    let scripts = root.join("firmware/boards/qemu/scripts");
    std::fs::create_dir_all(&scripts).unwrap();
    let bin = root.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let script = r#"#!/bin/sh
case "$1" in m4) name=cortex-m4 ;; m7) name=cortex-m7 ;; *) echo "bad core $1" >&2; exit 2 ;; esac
shift
echo "the bench's own table"
if [ "$1" = "--config" ] && [ "$3" = "--frames" ]; then
  echo "BENCH {\"workload\":\"user\",\"core\":\"$name\",\"instr_per_px\":24.0,\"floor_instr_per_px\":null,\"last_row_instructions\":4800,\"pixels\":50176,\"frames\":4,\"config_bytes\":$(wc -c < "$2"),\"frames_bytes\":$(wc -c < "$4")}"
else
  echo "BENCH {\"workload\":\"canary-subtract-next-n20\",\"core\":\"$name\",\"instr_per_px\":20.0,\"floor_instr_per_px\":8.0,\"last_row_instructions\":1900,\"pixels\":12544,\"frames\":8}"
fi
"#;
    for (path, text) in [
        (scripts.join("run-bench"), script),
        (bin.join("qemu-system-arm"), "#!/bin/sh\nexit 0\n"),
    ] {
        std::fs::write(&path, text).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    (root, path)
}

#[test]
fn qemu_rows_come_from_the_bench_script_into_the_table_and_json() {
    let (root, path) = fake_tree("qemu");
    let json = root.join("figures.json");
    let run = Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .args(["bench", "--qemu-only", "--json", json.to_str().unwrap()])
        .current_dir(&root)
        .env("PATH", path)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}{stdout}",
        String::from_utf8_lossy(&run.stderr)
    );
    let row = stdout
        .lines()
        .find(|l| l.starts_with("canary-subtract-next-n20"))
        .unwrap_or_else(|| panic!("{stdout}"));
    let numbers: Vec<&str> = row.split_whitespace().skip(1).collect();
    assert_eq!(
        numbers,
        ["20.00", "2.50", "1900", "20.00", "2.50", "1900"],
        "{row}"
    );
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let cores: Vec<&str> = rows
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["core"].as_str().unwrap())
        .collect();
    assert_eq!(cores, ["cortex-m4", "cortex-m7"]);
    assert_eq!(rows[0]["instr_per_px"], 20.0);
    assert_eq!(rows[0]["floor_instr_per_px"], 8.0);
    assert_eq!(rows[0]["last_row_instructions"], 1900.0);
}

#[test]
fn a_user_configuration_goes_to_the_qemu_bench_as_upload_bytes_and_raw_frames() {
    let (root, path) = fake_tree("qemu-user");
    let frames = root.join("frames.npy");
    let pixels: Vec<u16> = (0..6 * 112 * 112).map(|k| 50 + (k % 11) as u16).collect();
    brightpix::io::write_array(&frames, &[6, 112, 112], &pixels).unwrap();
    let config = examples().join("canary.toml");
    let json = root.join("figures.json");
    let run = Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .args(["bench", "--qemu-only", "--config"])
        .arg(&config)
        .arg("--frames")
        .arg(&frames)
        .args(["--camera-rate", "1000", "--json"])
        .arg(&json)
        .current_dir(&root)
        .env("PATH", path)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}{stdout}",
        String::from_utf8_lossy(&run.stderr)
    );
    // 480 MHz / 24 instructions per pixel = 20 Mpx/s; 4800 / 480 = 10 us; a
    // 112x112 camera at 1 kHz is 12.5 Mpx/s: 63% of the board.
    assert!(
        stdout.contains("20.0 Mpx/s per board; 10.0 us after the last row"),
        "{stdout}"
    );
    assert!(stdout.contains("FITS one board (63%"), "{stdout}");
    // The Cortex-M7 row again as an STM32H743 with its camera path: its
    // model's per-pixel and after-the-last-pixel costs added.
    let board = brightpix::rig::CostModel::STM32H743;
    assert!(board.camera_per_pixel > 0.5 && board.last_row_per_frame > 500.0);
    let expected = format!(
        "{:.1} Mpx/s per board; {:.1} us after the last row",
        480.0 / (24.0 + board.camera_per_pixel),
        (4800.0 + board.last_row_per_frame) / 480.0
    );
    let h743 = stdout
        .lines()
        .skip_while(|l| !l.contains("an STM32H743 at 480 MHz with its camera path"))
        .take(2)
        .collect::<Vec<_>>();
    assert!(h743[0].contains(&expected), "{stdout}");
    let share = 12.544 / (480.0 / (24.0 + board.camera_per_pixel));
    assert!(
        h743[1].contains(&format!("FITS one board ({:.0}%", share * 100.0)),
        "{stdout}"
    );
    // And its results on its USB link: 7 rows of 7 results, each row's
    // message at most 7 x 12 + 13 bytes, and the frame's end.
    let whole = brightpix::config_file::ProcessingConfig::load(&config).unwrap();
    let all: Vec<usize> = (0..49).collect();
    let bytes = brightpix::rig::frame_bytes(
        &whole,
        &brightpix::rig::ResultBounds::of(&whole),
        &all,
        false,
    );
    assert!(bytes > 7 * (7 * 12 + 13));
    let link = stdout
        .lines()
        .find(|l| l.contains("its results at 1000 Hz"))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(
        link.contains(&format!(
            "up to {:.2} MB/s ({bytes} bytes a frame): FIT its USB full speed link ({:.0}%",
            bytes as f64 * 1e-3,
            bytes as f64 * 1e-1
        )),
        "{link}"
    );
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let upload = brightpix::bench::qemu::config_upload_bytes(
        &brightpix::config_file::ProcessingConfig::load(&config)
            .unwrap()
            .view(),
    );
    for row in rows.as_array().unwrap() {
        assert_eq!(row["workload"], "user");
        assert_eq!(row["config_bytes"], upload.len());
        assert_eq!(
            row["frames_bytes"],
            4 * 112 * 112 * 2,
            "--qemu-frames 4 by default"
        );
        assert_eq!(row["px_per_s_per_board"], 20e6);
        // A user's windows have no floor (the bench prints null), and the
        // rate and latency are still reported.
        assert!(row["floor_instr_per_px"].is_null(), "{row}");
        assert!(row["x_floor"].is_null(), "{row}");
    }
}
