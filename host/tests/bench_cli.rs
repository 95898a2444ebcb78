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
        assert!(row["mpx_per_s"].as_f64().unwrap() > 0.0);
        assert!(row["x_sort"].as_f64().unwrap() > 0.0);
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
