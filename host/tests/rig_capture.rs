//! `rig capture`: several in-process boards on one simulated camera (one
//! timeline of frames, one sync line: `SharedCamera`), one of them started
//! late. Without the sync line the boards begin on different camera frames
//! and the capture says so (`--verify`, the shared rows' checksums); on
//! the line every board begins on the same frame, bit for bit.

mod common;
use common::run;

use std::sync::Arc;

use brightpix::link::Client;
use brightpix::rig::{self, Rig};
use brightpix::sim_device::{
    CameraOptions, CameraSpec, InProcessDevice, InProcessOptions, SharedCamera,
};

/// `rig capture`: three in-process boards on one simulated camera (one
/// timeline of frames and one sync line, `SharedCamera`), each configured
/// with its rectangle as its crop: the camera makes the whole 48x48 sensor
/// and each keeps its band of rows. Board 1's start comes three frame
/// periods late (the shared camera's test knob: USB latency). Without a
/// sync line in rig.toml the capture warns, the boards begin on different
/// camera frames, and `--verify` finds the merge differs from the
/// whole-camera reference; with `[sync]` the followers are armed first,
/// the leader raises the line after a frame start, every board begins on
/// the frame after it, and the merge equals the reference bit for bit.
/// A board whose pixels come from the host, or whose camera has no sync
/// line, is refused.
#[test]
fn capture_with_three_boards_each_cropping_one_camera() {
    let dir = common::scratch("rig", "capture");
    let config = common::small_wfs_config(&dir);
    let rig_file = dir.join("rig.toml");
    common::plan_three_boards(&config, &["--out", rig_file.to_str().unwrap()]);
    let synced_file = with_sync_line(&rig_file);
    let (devices, ports) = boards_on_one_camera();
    // With --verify --seed 4 unless `extra` gives another seed.
    let capture = |rig: &std::path::Path, extra: &[&str]| {
        let mut args = vec![
            "rig",
            "capture",
            "--rig",
            rig.to_str().unwrap(),
            "--ports",
            &ports,
            "--verify",
        ];
        if !extra.contains(&"--seed") {
            args.extend(["--seed", "4"]);
        }
        args.extend_from_slice(extra);
        run(&args)
    };

    // No sync line: a warning, different first camera frames, a merge
    // that does not verify.
    let (ok, text) = capture(&rig_file, &["--count", "30"]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("start without a sync line")
            && text.contains("began on different camera frames")
            && text.contains("differ from the whole-camera reference"),
        "{text}"
    );
    let (ok, text) = capture(&rig_file, &["--count", "3", "--start", "sync"]);
    assert!(
        !ok && text.contains("the rig declares no sync line"),
        "{text}"
    );

    // On the sync line: aligned, bit for bit.
    let out = dir.join("merged.npy");
    let (ok, text) = capture(
        &synced_file,
        &["--count", "30", "--out", out.to_str().unwrap()],
    );
    assert!(ok, "{text}");
    assert!(
        text.contains("30 complete")
            && text.contains("verified: 30 merged frames, 270 sub-aperture results")
            && text.contains(": 0 mismatches")
            && text.matches("(the first after the sync edge)").count() == 3
            && !text.contains("without a sync line")
            && !text.contains("different camera frames"),
        "{text}"
    );
    assert!(out.exists());
    // Another seed on the boards' camera than --verify's: every frame differs.
    let (ok, text) = capture(&synced_file, &["--count", "3", "--seed", "5"]);
    assert!(!ok && text.contains("differ"), "{text}");
    // `--start immediate` on a rig with a sync line: the same misalignment.
    let (ok, text) = capture(&synced_file, &["--count", "10", "--start", "immediate"]);
    assert!(
        !ok && text.contains("began on different camera frames"),
        "{text}"
    );
    // A board whose camera has no sync line (a camera of its own).
    let lone = InProcessDevice::start(InProcessOptions {
        camera: Some(CameraOptions::own(CameraSpec { seed: 4 }, 100)),
        ..InProcessOptions::default()
    })
    .unwrap();
    let ports_lone = format!(
        "{},{},{}",
        devices[0].port(),
        lone.port(),
        devices[2].port()
    );
    let (ok, text) = run(&[
        "rig",
        "capture",
        "--rig",
        synced_file.to_str().unwrap(),
        "--ports",
        &ports_lone,
        "--count",
        "3",
    ]);
    assert!(
        !ok && text.contains("the device has no sync line"),
        "{text}"
    );
    // A board without a camera of its own.
    let plain = InProcessDevice::start_pty().unwrap();
    let ports = format!(
        "{},{},{}",
        devices[0].port(),
        devices[1].port(),
        plain.port()
    );
    let (ok, text) = run(&[
        "rig",
        "capture",
        "--rig",
        rig_file.to_str().unwrap(),
        "--ports",
        &ports,
        "--count",
        "3",
    ]);
    assert!(!ok && text.contains("has no camera of its own"), "{text}");
}

/// Runs of windows in raster order (a link that bands would overrun: 5 and 4
/// of the 3x3 windows, rectangles overlapping by a row of windows) on two
/// boards of one camera, each cropping its rectangle: on the sync line the
/// merge equals the whole-camera reference bit for bit.
#[test]
fn overlapping_rectangles_capture_bit_for_bit() {
    let dir = common::scratch("rig", "capture-raster");
    let config = common::small_wfs_config(&dir);
    let rig_file = dir.join("rig.toml");
    let (ok, text) =
        common::plan_two_on_a_link(&config, 0.92, &["--out", rig_file.to_str().unwrap()]);
    assert!(
        ok && text.contains("runs of windows in raster order"),
        "{text}"
    );
    let synced_file = with_sync_line(&rig_file);
    let (devices, _) = boards_on_one_camera();
    let ports = format!("{},{}", devices[0].port(), devices[1].port());
    let (ok, text) = capture_twenty_verified(&synced_file, &ports);
    assert!(
        ok && text.contains("verified: 20 merged frames, 180 sub-aperture results")
            && text.contains(": 0 mismatches"),
        "{text}"
    );
}

/// The same from the command line alone: `simulate-device --camera sim:4
/// --boards 3 --start-delays 0,3` puts three boards on one simulated camera
/// with a sync line and prints their ports; `rig capture` on a rig without
/// `[sync]` finds the merge misaligned, with `[sync]` bit-exact.
#[test]
fn simulated_boards_of_one_camera_from_the_command_line() {
    use std::io::BufRead as _;
    let dir = common::scratch("rig", "simulate-boards");
    let config = common::small_wfs_config(&dir);
    let rig_file = dir.join("rig.toml");
    common::plan_three_boards(&config, &["--out", rig_file.to_str().unwrap()]);
    let synced_file = with_sync_line(&rig_file);
    let (ok, text) = run(&["simulate-device", "--boards", "2"]);
    assert!(!ok && text.contains("--camera"), "{text}");
    let mut child = common::brightpix()
        .args([
            "simulate-device",
            "--camera",
            "sim:4",
            "--boards",
            "3",
            "--start-delays",
            "0,3",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
    let ports: Vec<String> = (0..3).map(|_| lines.next().unwrap().unwrap()).collect();
    let ports = ports.join(",");
    let capture = |rig: &std::path::Path| capture_twenty_verified(rig, &ports);
    let (skewed_ok, skewed) = capture(&rig_file);
    let (synced_ok, synced) = capture(&synced_file);
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        !skewed_ok && skewed.contains("began on different camera frames"),
        "{skewed}"
    );
    assert!(synced_ok && synced.contains(": 0 mismatches"), "{synced}");
}

/// The alignment self-check without wiring (`rig plan --shared-rows`):
/// each band reaches one row into the next, both boards send a checksum of
/// that shared camera row every frame (`EdgeRows`), and `rig capture`
/// compares them. Board 1 starting three frames late without the sync line:
/// every merged frame's neighbours disagree and the capture is refused,
/// without `--verify` (no reference needed); on the sync line every frame
/// agrees.
#[test]
fn shared_rows_catch_boards_on_different_frames_without_a_reference() {
    let dir = common::scratch("rig", "shared-rows");
    let config = common::small_wfs_config(&dir);
    let rig_file = dir.join("rig.toml");
    common::plan_three_boards(
        &config,
        &["--shared-rows", "--out", rig_file.to_str().unwrap()],
    );
    let rig = Rig::load(&rig_file).unwrap();
    assert_eq!(rig.shared_rows(), [(0, 1), (1, 2)]);
    let synced_file = with_sync_line(&rig_file);
    let (devices, ports) = boards_on_one_camera();
    let out = dir.join("merged.npy");
    let capture = |rig: &std::path::Path| {
        run(&[
            "rig",
            "capture",
            "--rig",
            rig.to_str().unwrap(),
            "--ports",
            &ports,
            "--count",
            "20",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let (ok, text) = capture(&rig_file);
    assert!(!ok, "{text}");
    assert!(
        text.contains("shared rows (board-0/board-1, board-1/board-2): 20 merged frames checked, 20 with boards on different camera frames")
            && text.contains("saw different pixels there in 20 merged frames"),
        "{text}"
    );
    assert!(!out.exists(), "nothing written from a misaligned capture");
    let (ok, text) = capture(&synced_file);
    assert!(ok, "{text}");
    assert!(
        text.contains("20 merged frames checked, 0 with boards on different camera frames"),
        "{text}"
    );
    assert!(out.exists());
    // The same through the library, with the whole-camera reference too:
    // the rows that disagree are exactly the frames that do not verify.
    let mut clients: Vec<Client> = devices
        .iter()
        .map(|d| Client::open(d.port()).unwrap())
        .collect();
    let frames = brightpix::sim_device::CameraFrames::new(rig.whole.camera, 4);
    let mut stream = rig::RigStream::new(&rig, true);
    stream.capture(
        &mut clients,
        10,
        rig::RigStart::Immediate,
        &mut |k| frames.frames(u64::from(k), 1).pop(),
        &mut |_| {},
    );
    let run = stream.finish(&mut |_| {});
    let v = run.verifier.as_ref().unwrap();
    assert_eq!(run.edge_check.frames_checked, 10);
    assert_eq!(run.edge_check.frames_disagreeing, 10);
    assert!(!v.all_match());
}

/// `rig capture --rig RIG --ports PORTS --count 20 --verify --seed 4` (the
/// seed of [`boards_on_one_camera`]'s camera).
fn capture_twenty_verified(rig: &std::path::Path, ports: &str) -> (bool, String) {
    run(&[
        "rig",
        "capture",
        "--rig",
        rig.to_str().unwrap(),
        "--ports",
        ports,
        "--count",
        "20",
        "--verify",
        "--seed",
        "4",
    ])
}

/// `rig.toml` as `rig plan` wrote it, its commented `[sync]` section
/// (leader: the first board) taken in, as `rig-sync.toml` beside it.
fn with_sync_line(rig_file: &std::path::Path) -> std::path::PathBuf {
    let plain = std::fs::read_to_string(rig_file).unwrap();
    assert!(plain.contains("# [sync]"), "{plain}");
    let synced = rig_file.with_file_name("rig-sync.toml");
    std::fs::write(
        &synced,
        plain.replace("# [sync]\n# leader", "[sync]\nleader"),
    )
    .unwrap();
    synced
}

/// Three in-process boards on one simulated camera (seed 4) with a sync
/// line, board 1 starting three frame periods late; and their ports, a
/// comma-separated list for `--ports`.
fn boards_on_one_camera() -> (Vec<InProcessDevice>, String) {
    let camera = Arc::new(
        SharedCamera::new(CameraSpec { seed: 4 }, 100)
            .with_sync_line()
            .with_start_delays(vec![0, 3, 0]),
    );
    let devices: Vec<InProcessDevice> = (0..3)
        .map(|b| {
            InProcessDevice::start(InProcessOptions {
                camera: Some(camera.board(b)),
                ..InProcessOptions::default()
            })
            .unwrap()
        })
        .collect();
    let ports = devices
        .iter()
        .map(|d| d.port())
        .collect::<Vec<_>>()
        .join(",");
    (devices, ports)
}
