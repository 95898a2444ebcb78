//! `stream --no-configure` trusts the device's active configuration only
//! when its digest (PROTOCOL.md §7) is that of `--config`.

mod common;
use common::run;

use std::path::{Path, PathBuf};

use brightpix::io::write_array;
use brightpix::sim_device::InProcessDevice;

fn scratch(name: &str) -> PathBuf {
    common::scratch("stream", name)
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

/// `stream --out` writes flux, validity and provenance beside the slopes,
/// in each format, equal to what `process` writes for the same frames.
#[test]
fn stream_out_has_flux_validity_and_provenance_in_every_format() {
    let dir = scratch("out");
    let config = config(&dir, 5);
    let frames = frames(&dir, 8);
    let device = InProcessDevice::start_pty().unwrap();
    let (c, f) = (config.to_str().unwrap(), frames.to_str().unwrap());
    let reference = dir.join("ref.npy");
    let (ok, text) = run(&[
        "process",
        "--config",
        c,
        "--frames",
        f,
        "--out",
        reference.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let want_flux = brightpix::io::read_array(dir.join("ref.flux.npy")).unwrap();
    for ext in ["npy", "fits", "csv", "aot.fits"] {
        let out = dir.join(format!("s.{ext}"));
        let (ok, text) = run(&[
            "stream",
            "--port",
            device.port(),
            "--config",
            c,
            "--frames",
            f,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{ext}: {text}");
        match ext {
            "npy" => {
                let flux = brightpix::io::read_array(dir.join("s.flux.npy")).unwrap();
                assert_eq!(flux, want_flux);
                let valid = brightpix::io::read_array(dir.join("s.valid.npy")).unwrap();
                assert_eq!(valid.shape, [8, 4]);
                let json = std::fs::read_to_string(dir.join("s.json")).unwrap();
                assert!(
                    json.contains("\"bpcfgid\"") && json.contains("stream"),
                    "{json}"
                );
            }
            "fits" => {
                let mut file = fitsio::FitsFile::open(&out).unwrap();
                let primary = file.primary_hdu().unwrap();
                let rule: String = primary.read_key(&mut file, "BPRULE").unwrap();
                assert_eq!(rule, "subtract-next");
                let slopes: Vec<f64> = primary.read_image(&mut file).unwrap();
                assert_eq!(slopes, brightpix::io::read_array(&reference).unwrap().data);
                // Found by name as process's SLOPES extension is.
                let named = file.hdu("SLOPES").unwrap();
                let slopes: Vec<f64> = named.read_image(&mut file).unwrap();
                assert_eq!(slopes, brightpix::io::read_array(&reference).unwrap().data);
                let hdu = file.hdu("FLUX").unwrap();
                let flux: Vec<f64> = hdu.read_image(&mut file).unwrap();
                assert_eq!(flux, want_flux.data);
            }
            "aot.fits" => {
                // Written whole at the end: AOT's (frames, 2, sub-apertures).
                let mut file = fitsio::FitsFile::open(&out).unwrap();
                let primary = file.primary_hdu().unwrap();
                let version: String = primary.read_key(&mut file, "AOT-VERS").unwrap();
                assert_eq!(version, "2.0.0");
                let hdu = file.hdu("MEASUREMENTS").unwrap();
                let measured: Vec<f64> = hdu.read_image(&mut file).unwrap();
                let pairs = brightpix::io::read_array(&reference).unwrap().data;
                let vector: Vec<f64> = pairs
                    .chunks(8)
                    .flat_map(|f| (0..2).flat_map(move |axis| f.iter().skip(axis).step_by(2)))
                    .copied()
                    .collect();
                assert_eq!(measured, vector);
                let hdu = file.hdu("SUBAPERTURE_INTENSITIES").unwrap();
                let flux: Vec<f64> = hdu.read_image(&mut file).unwrap();
                assert_eq!(flux, want_flux.data);
            }
            _ => {
                let text = std::fs::read_to_string(&out).unwrap();
                let rows = text.lines().filter(|l| !l.starts_with('#')).count();
                assert_eq!(rows, 1 + 8 * 4, "{text}");
            }
        }
    }
    drop(device);
    let _ = std::fs::remove_dir_all(dir);
}

/// `stream --out --layout vector` writes the AO slope vector
/// `[x_0..x_S-1, y_0..y_S-1]` per frame, as `process --layout vector`
/// does; a configuration whose every sub-aperture is invalid gets the
/// same warning as from `process`.
#[test]
fn stream_layout_vector_and_the_all_invalid_warning() {
    let dir = scratch("layout");
    let config = config(&dir, 5);
    let frames = frames(&dir, 6);
    let device = InProcessDevice::start_pty().unwrap();
    let (c, f) = (config.to_str().unwrap(), frames.to_str().unwrap());
    let reference = dir.join("ref.npy");
    let (ok, text) = run(&[
        "process",
        "--config",
        c,
        "--frames",
        f,
        "--out",
        reference.to_str().unwrap(),
        "--layout",
        "vector",
    ]);
    assert!(ok, "{text}");
    let want = brightpix::io::read_array(&reference).unwrap();
    assert_eq!(want.shape, [6, 8]);
    for ext in ["npy", "fits"] {
        let out = dir.join(format!("v.{ext}"));
        let (ok, text) = run(&[
            "stream",
            "--port",
            device.port(),
            "--config",
            c,
            "--frames",
            f,
            "--out",
            out.to_str().unwrap(),
            "--layout",
            "vector",
        ]);
        assert!(ok, "{ext}: {text}");
        assert!(!text.contains("every sub-aperture is invalid"), "{text}");
        let got = brightpix::io::read_array(&out).unwrap();
        assert_eq!(got, want, "{ext}");
    }
    let json = std::fs::read_to_string(dir.join("v.json")).unwrap();
    assert!(json.contains("\"bplayout\": \"vector\""), "{json}");

    // A minimum flux no frame reaches: every sub-aperture invalid.
    let dark = dir.join("dark.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(&dark, text + "[centroid]\nmin_flux_counts = 1e12\n").unwrap();
    let d = dark.to_str().unwrap();
    for command in ["process", "stream"] {
        let out = dir.join(format!("dark-{command}.npy"));
        let mut args = vec![command];
        if command == "stream" {
            args.extend(["--port", device.port()]);
        }
        args.extend(["--config", d, "--frames", f, "--out", out.to_str().unwrap()]);
        let (ok, text) = run(&args);
        assert!(ok, "{command}: {text}");
        assert!(
            text.contains("warning: in 6 of 6 frames every sub-aperture is invalid"),
            "{command}: {text}"
        );
    }
    drop(device);
    let _ = std::fs::remove_dir_all(dir);
}

/// A new `stream --out x.npy` removes an earlier run's `x.flux.npy`,
/// `x.valid.npy` and `x.json` before its first frame, so a run killed
/// part-way never leaves its slopes beside another run's flux and
/// provenance (issue 27 item 8).
#[test]
fn a_killed_stream_leaves_no_other_runs_companions() {
    let dir = scratch("killed");
    let config = config(&dir, 5);
    let frames = frames(&dir, 20_000);
    let out = dir.join("s.npy");
    let companions = ["s.flux.npy", "s.valid.npy", "s.json"].map(|n| dir.join(n));
    for c in &companions {
        std::fs::write(c, b"an earlier run's file").unwrap();
    }
    let device = InProcessDevice::start_pty().unwrap();
    let mut child = common::brightpix()
        .args(["stream", "--port", device.port(), "--config"])
        .arg(&config)
        .arg("--frames")
        .arg(&frames)
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Killed once some frames are in the slopes file.
    let started = std::time::Instant::now();
    while std::fs::metadata(&out).map_or(0, |m| m.len()) < 64 * 1024 {
        assert!(started.elapsed().as_secs() < 60, "no slopes written");
        assert!(
            child.try_wait().unwrap().is_none(),
            "the stream ended before it could be killed"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success(), "killed");
    for c in &companions {
        assert!(
            !c.exists(),
            "{} of the earlier run is still there",
            c.display()
        );
    }
    // What is there is this run's slopes, readable.
    let slopes = brightpix::io::read_array(&out).unwrap();
    assert!(slopes.shape[0] > 0, "{:?}", slopes.shape);
    drop(device);
    let _ = std::fs::remove_dir_all(dir);
}

/// Another program that does not take the port's lock (pyserial does not;
/// here a raw open of the pseudo-terminal, as root may) starts a session
/// and uploads another configuration mid-stream: `stream` must not exit 0
/// with the other configuration's slopes (issue 27 item 9).
#[test]
fn a_takeover_mid_stream_fails_the_stream() {
    use brightpix_protocol::wire::{encode, tables::UploadPlan, HostMessage, MAX_FRAME_LEN};
    use std::io::Write;
    let dir = scratch("takeover");
    let five = config(&dir, 5);
    let six = brightpix::config_file::ProcessingConfig::load(config(&dir, 6)).unwrap();
    let frames = frames(&dir, 20_000);
    let out = dir.join("s.npy");
    let device = InProcessDevice::start_pty().unwrap();
    let mut child = common::brightpix()
        .args(["stream", "--port", device.port(), "--config"])
        .arg(&five)
        .arg("--frames")
        .arg(&frames)
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while std::fs::metadata(&out).map_or(0, |m| m.len()) < 64 * 1024 {
        assert!(started.elapsed().as_secs() < 60, "no slopes written");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // The intruder writes only: its replies go to whoever reads.
    let Ok(mut intruder) = std::fs::OpenOptions::new().write(true).open(device.port()) else {
        eprintln!("cannot open the pseudo-terminal past its lock (not root): not tested");
        let _ = child.kill();
        let _ = child.wait();
        return;
    };
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    // A 0x00 first ends whatever frame the link was in (PROTOCOL.md §2).
    intruder.write_all(&[0]).unwrap();
    let mut send = |m: &HostMessage<'_>| {
        let n = encode(m, &mut buf).unwrap().len();
        intruder.write_all(&buf[..n]).unwrap();
    };
    send(&HostMessage::hello(0x5eed));
    let mut plan = UploadPlan::new(six.view(), 77, 256);
    let mut scratch = vec![0u8; 4096];
    while let Some(m) = plan.next(&mut scratch) {
        send(&m);
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    drop(intruder);
    let output = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&output.stdout).into_owned()
        + &String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "exit 0 after a takeover:\n{text}");
    assert!(
        text.contains("another client took the device over"),
        "{text}"
    );
    // The set says how many of its frames are the first configuration's.
    let provenance = std::fs::read_to_string(dir.join("s.json")).unwrap();
    assert!(provenance.contains("\"bptrust\""), "{provenance}");
    drop(device);
    let _ = std::fs::remove_dir_all(dir);
}
