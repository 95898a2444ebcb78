//! What the result-writing commands leave on disk when things go wrong
//! (issue 10, faults 2, 3 and 5): an output never replaces an input; a
//! failed run leaves no output behind; `stream --out` keeps every frame
//! received when it is interrupted or killed, and says how many the file
//! holds; summaries count what the file holds.

mod common;
use common::{brightpix, run};

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use brightpix::io::{read_array, write_array};
use brightpix::sim_device::InProcessDevice;

fn scratch(name: &str) -> PathBuf {
    common::scratch("outputs", name)
}

/// A 16x16 camera with four 8x8 sub-apertures, and `count` frames.
fn small_case(dir: &Path, count: usize) -> (PathBuf, PathBuf) {
    let config = dir.join("small.toml");
    std::fs::write(
        &config,
        "[camera]\nwidth = 16\nheight = 16\nbit_depth = 12\n\
         [subapertures.grid]\nx = 0\ny = 0\ncolumns = 2\nrows = 2\nwidth = 8\nheight = 8\n\
         [selection]\npixels = 5\n",
    )
    .unwrap();
    let mut state = 7u64;
    let pixels: Vec<u16> = (0..count * 256)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % 4096) as u16
        })
        .collect();
    let frames = dir.join("frames.npy");
    write_array(&frames, &[count, 16, 16], &pixels).unwrap();
    (config, frames)
}

/// Fault 3: `process --out` equal to the frames replaced them with slopes.
#[test]
fn an_output_that_is_an_input_is_refused_before_any_work() {
    let dir = scratch("same");
    let (config, frames) = small_case(&dir, 3);
    let before = std::fs::read(&frames).unwrap();
    let other_spelling = dir.join(".").join("frames.npy");
    for out in [&frames, &other_spelling, &config] {
        let out = out.to_str().unwrap();
        for extra in [
            vec!["--out", out],
            vec!["--out", "s.npy", "--valid-out", out],
        ] {
            let mut args = vec![
                "process",
                "--config",
                config.to_str().unwrap(),
                "--frames",
                frames.to_str().unwrap(),
            ];
            args.extend(extra);
            let (ok, text) = run(&args);
            assert!(!ok, "{text}");
            assert!(text.contains("the same file as the input"), "{text}");
        }
    }
    assert_eq!(
        std::fs::read(&frames).unwrap(),
        before,
        "the frames are intact"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// Fault 5: an unwritable `--valid-out` made the run fail but left `--out`.
#[test]
fn a_failed_run_leaves_no_output_behind() {
    let dir = scratch("whole");
    let (config, frames) = small_case(&dir, 3);
    let out = dir.join("slopes.npy");
    let (ok, text) = run(&[
        "process",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--valid-out",
        dir.join("no/such/dir/valid.npy").to_str().unwrap(),
    ]);
    assert!(!ok && text.contains("does not exist"), "{text}");
    assert!(!out.exists(), "no --out after a failed run");
    // A --valid-out that cannot be renamed into place (a directory there)
    // fails only after the work: still nothing is left behind.
    std::fs::create_dir(dir.join("valid.npy")).unwrap();
    let (ok, text) = run(&[
        "process",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--valid-out",
        dir.join("valid.npy").to_str().unwrap(),
    ]);
    assert!(!ok, "{text}");
    let leftovers: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert_eq!(leftovers, Vec::<String>::new(), "temporary files left");
    // `--chunk 0` is refused before any work (fault 6).
    let (ok, text) = run(&[
        "process",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--chunk",
        "0",
    ]);
    assert!(!ok && text.contains("at least 1"), "{text}");
    let _ = std::fs::remove_dir_all(dir);
}

/// Rows of a (frames, sub-apertures, 2) slopes file, as numpy would read it.
fn rows(path: &Path) -> usize {
    let a = read_array(path).unwrap();
    assert_eq!(a.shape[1..], [4, 2]);
    a.shape[0]
}

/// Fault 2: Ctrl-C (SIGINT) or SIGKILL during `stream --out` kept nothing.
/// Now the file holds every frame received, whole, at any moment.
#[test]
fn an_interrupted_or_killed_stream_keeps_its_slopes() {
    let dir = scratch("stream");
    let (config, frames) = small_case(&dir, 20_000);
    let device = InProcessDevice::start_pty().unwrap();
    for (signal, name) in [("-INT", "int"), ("-KILL", "kill")] {
        let out = dir.join(format!("slopes-{name}.npy"));
        let mut child = brightpix()
            .args([
                "stream",
                "--port",
                device.port(),
                "--config",
                config.to_str().unwrap(),
                "--frames",
                frames.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Wait until some frames are in the file, then signal.
        let t = Instant::now();
        let written = |out: &Path| read_array(out).map_or(0, |a| a.shape[0]);
        while written(&out) < 20 {
            assert!(t.elapsed() < Duration::from_secs(30), "no frames written");
            std::thread::sleep(Duration::from_millis(5));
        }
        let status = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(status.success());
        let exit = child.wait().unwrap();
        let mut text = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut text)
            .unwrap();
        child
            .stdout
            .take()
            .unwrap()
            .read_to_string(&mut text)
            .unwrap();
        let held = rows(&out);
        assert!(
            (20..20_000).contains(&held),
            "{held} frames after {signal}: {text}"
        );
        // Every frame whose results were complete is whole; after SIGINT
        // the frames that were in flight (at most 4) follow with what had
        // arrived of them (NaN for the rest); after SIGKILL there are none.
        let slopes = read_array(&out).unwrap();
        let complete = slopes
            .data
            .chunks(8)
            .take_while(|row| row.iter().all(|v| v.is_finite()))
            .count();
        let in_flight = if signal == "-INT" { 4 } else { 0 };
        assert!(complete + in_flight >= held, "{complete} of {held}: {text}");
        if signal == "-INT" {
            assert!(!exit.success());
            // The summary counts what the file holds.
            assert!(
                text.contains(&format!("holds the slopes of {held} frames")),
                "{text}"
            );
            assert!(text.contains("interrupted"), "{text}");
        }
    }
    drop(device);
    let _ = std::fs::remove_dir_all(dir);
}

/// Fault 5: after the device died the client kept its frames but printed
/// "streamed 0 frames" and "slopes of 256 frames written" (252 of them
/// NaN). Now the file holds the frames that were sent and answered, and the
/// summaries say how many.
#[test]
fn when_the_device_dies_the_summary_counts_what_the_file_holds() {
    let dir = scratch("died");
    let (config, frames) = small_case(&dir, 20_000);
    let device = InProcessDevice::start_pty().unwrap();
    let out = dir.join("slopes.npy");
    let child = brightpix()
        .args([
            "stream",
            "--port",
            device.port(),
            "--config",
            config.to_str().unwrap(),
            "--frames",
            frames.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while read_array(&out).map_or(0, |a| a.shape[0]) < 20 {
        assert!(t.elapsed() < Duration::from_secs(30), "no frames written");
        std::thread::sleep(Duration::from_millis(5));
    }
    device.stop(); // the device dies mid-stream
    let output = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&output.stdout).into_owned()
        + &String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{text}");
    let held = rows(&out);
    assert!((20..20_000).contains(&held), "{held}: {text}");
    assert!(
        text.contains(&format!("holds the slopes of {held} frames")),
        "{text}"
    );
    // "streamed N of 20000 frames": N complete frames, all in the file.
    let streamed: usize = text
        .split("streamed ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count in: {text}"));
    assert!(
        streamed > 0 && streamed <= held,
        "{streamed} vs {held}: {text}"
    );
    let _ = std::fs::remove_dir_all(dir);
}
