//! `stream --no-configure` trusts the device's active configuration only
//! when its digest (PROTOCOL.md §7) is that of `--config`.

use std::path::{Path, PathBuf};
use std::process::Command;

use brightpix::io::write_array;
use brightpix::sim_device::InProcessDevice;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brightpix-stream-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A 16x16 camera with four 8x8 sub-apertures selecting `n` pixels.
fn config(dir: &Path, n: u16) -> PathBuf {
    let path = dir.join(format!("n{n}.toml"));
    std::fs::write(
        &path,
        format!(
            "[camera]\nwidth = 16\nheight = 16\nbit_depth = 12\n\
             [subapertures.grid]\nx = 0\ny = 0\ncolumns = 2\nrows = 2\nwidth = 8\nheight = 8\n\
             [selection]\npixels = {n}\n"
        ),
    )
    .unwrap();
    path
}

fn frames(dir: &Path, count: usize) -> PathBuf {
    let pixels: Vec<u16> = (0..count * 256)
        .map(|k| ((k * 2654435761) % 4093) as u16)
        .collect();
    let path = dir.join("frames.npy");
    write_array(&path, &[count, 16, 16], &pixels).unwrap();
    path
}

fn run(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .args(args)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

#[test]
fn no_configure_checks_the_devices_configuration_digest() {
    let dir = scratch("digest");
    let five = config(&dir, 5);
    let six = config(&dir, 6);
    let frames = frames(&dir, 8);
    let (five, six, frames) = (
        five.to_str().unwrap(),
        six.to_str().unwrap(),
        frames.to_str().unwrap(),
    );
    let device = InProcessDevice::start_pty().unwrap();
    let port = device.port();
    let stream = |config: &str, extra: &[&str]| {
        let mut args = vec![
            "stream",
            "--port",
            port,
            "--config",
            config,
            "--frames",
            frames,
            "--no-configure",
            "--verify",
        ];
        args.extend_from_slice(extra);
        run(&args)
    };

    // Nothing uploaded yet.
    let (ok, text) = stream(five, &[]);
    assert!(!ok, "{text}");
    assert!(text.contains("no active configuration"), "{text}");
    assert!(
        !text.contains("streamed"),
        "refused before any frame: {text}"
    );

    let (ok, text) = run(&["configure", "--port", port, "--config", five]);
    assert!(ok, "{text}");

    // Another configuration than the device's: refused, with the way out.
    let (ok, text) = stream(six, &[]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("is not") && text.contains("n6.toml"),
        "{text}"
    );
    assert!(text.contains("--force"), "{text}");

    // Forced: it streams, and the mismatches name their units.
    let (ok, text) = stream(six, &["--force"]);
    assert!(!ok, "the results differ: {text}");
    assert!(text.contains("warning"), "{text}");
    assert!(
        text.contains("2^-16 px") && text.contains("1/16 count"),
        "{text}"
    );

    // The device's own configuration: accepted and bit-exact.
    let (ok, text) = stream(five, &[]);
    assert!(ok, "{text}");
    assert!(text.contains("verified 8 of 8 frames"), "{text}");
    drop(device);
    let _ = std::fs::remove_dir_all(dir);
}
