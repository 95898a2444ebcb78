//! `brightpix process` end to end: .npy and FITS frame cubes through the
//! engine and the reference give identical slopes, in the documented shape;
//! bad inputs give a specific error and a non-zero exit.

use brightpix::io::{read_array, write_array};
use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brightpix-process-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// Spot-like 112x112 frames: a bright blob per 16x16 sub-aperture on a
/// background of about 50 counts.
fn frames(count: usize) -> Vec<u16> {
    let mut state = 99u64;
    let mut out = Vec::with_capacity(count * 112 * 112);
    for f in 0..count {
        for y in 0..112usize {
            for x in 0..112usize {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let (i, j) = ((x % 16) as f64, (y % 16) as f64);
                let (cx, cy) = (6.0 + (f % 5) as f64, 9.0 - (f % 3) as f64);
                let spot = 400.0 * (-((i - cx).powi(2) + (j - cy).powi(2)) / 5.0).exp();
                out.push((50.0 + spot) as u16 + (state % 7) as u16);
            }
        }
    }
    out
}

fn brightpix(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn engine_and_reference_agree_on_npy_and_fits() {
    let dir = scratch("agree");
    let config = examples().join("canary.toml");
    let pixels = frames(12);
    let mut outputs = Vec::new();
    for extension in ["npy", "fits"] {
        let frames_path = dir.join(format!("frames.{extension}"));
        write_array(&frames_path, &[12, 112, 112], &pixels).unwrap();
        for (name, extra) in [
            ("engine", vec!["--chunk", "37"]),
            ("engine-all-cores", vec![]),
            ("engine-3-threads", vec!["--threads", "3"]),
            ("reference", vec!["--reference"]),
        ] {
            let out = dir.join(format!("{name}-{extension}.npy"));
            let mut args = vec![
                "process",
                "--config",
                config.to_str().unwrap(),
                "--frames",
                frames_path.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ];
            args.extend(extra);
            let run = brightpix(&args);
            assert!(
                run.status.success(),
                "{}",
                String::from_utf8_lossy(&run.stderr)
            );
            let slopes = read_array(&out).unwrap();
            assert_eq!(slopes.shape, vec![12, 49, 2]);
            outputs.push(slopes.data);
        }
    }
    assert!(
        outputs.windows(2).all(|w| w[0] == w[1]),
        "engine (chunked, all cores, 3 threads) and reference, npy and FITS: identical"
    );
    // The spots were placed off-centre: slopes are not all zero.
    assert!(outputs[0].iter().any(|&s| s.abs() > 0.5));
}

#[test]
fn bad_inputs_are_refused_with_specific_errors() {
    let dir = scratch("bad");
    let config = examples().join("canary.toml");
    let out = dir.join("out.npy");
    // Frames of the wrong size for the configured camera.
    let wrong = dir.join("wrong.npy");
    write_array(&wrong, &[2, 100, 112], &vec![0u16; 2 * 100 * 112]).unwrap();
    let run = brightpix(&[
        "process",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        wrong.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!run.status.success());
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        message.contains("wrong.npy") && message.contains("112"),
        "{message}"
    );
    assert!(!out.exists(), "nothing is written on error");
    // A configuration with N = 0.
    let bad_config = dir.join("bad.toml");
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("pixels = 20", "pixels = 0");
    assert!(text.contains("pixels = 0"), "the example sets pixels = 20");
    std::fs::write(&bad_config, text).unwrap();
    let good_frames = dir.join("good.npy");
    write_array(&good_frames, &[1, 112, 112], &frames(1)).unwrap();
    let run = brightpix(&[
        "process",
        "--config",
        bad_config.to_str().unwrap(),
        "--frames",
        good_frames.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!run.status.success());
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        message.contains("bad.toml") && message.contains("selection.pixels"),
        "{message}"
    );
}
