//! The simulated devices' own camera (`simulate-device --camera sim:SEED`):
//! `brightpix capture --verify`, run exactly as on the command line
//! (`brightpix::cli::run_from`), against the firmware's device loop
//! in-process and against the firmware ELF in QEMU; every slope, flux and
//! validity bit-exact with the reference on frames regenerated from the
//! seed. Also capture's options (`--count`, `--out` formats, `--layout`)
//! and its refusals.
//!
//! The QEMU test needs `qemu-system-arm` and the thumbv7em-none-eabihf
//! target (`scripts/test` installs both); it is kept short (a few seconds
//! of frames at the board's frame clock).

use std::path::{Path, PathBuf};
use std::time::Instant;

use brightpix::cli::run_from;
use brightpix::io::read_array;
use brightpix::link::Client;
use brightpix::sim_device::{
    build_qemu_elf_for, temp_dir, CameraOptions, CameraSpec, InProcessDevice, InProcessOptions,
    QemuCpu, QemuDevice, QemuOptions,
};
use brightpix_protocol::wire::PixelSourceKind;

fn canary() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/canary.toml")
        .display()
        .to_string()
}

fn camera(seed: u64, fps: u32) -> Option<CameraOptions> {
    Some(CameraOptions::own(CameraSpec { seed }, fps))
}

fn in_process(seed: u64) -> InProcessDevice {
    InProcessDevice::start(InProcessOptions {
        camera: camera(seed, 200),
        ..InProcessOptions::default()
    })
    .unwrap()
}

/// `brightpix capture ARGS...` on `port`.
fn capture(port: &str, args: &[&str]) -> Result<(), String> {
    let mut line = vec!["brightpix", "capture", "--port", port];
    line.extend_from_slice(args);
    run_from(line).map_err(|e| format!("{e:#}"))
}

#[test]
fn capture_verify_in_process() {
    let device = in_process(5);
    assert!(device.has_camera());
    let client = Client::open(device.port()).unwrap();
    assert_eq!(client.info().pixel_source, PixelSourceKind::Camera);
    drop(client);
    let config = canary();
    let t = Instant::now();
    capture(
        device.port(),
        &[
            "--config", &config, "--count", "100", "--verify", "--seed", "5",
        ],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    eprintln!(
        "  in-process: 100 frames captured and verified bit for bit in {:.2} s",
        t.elapsed().as_secs_f64()
    );
    // Each capture starts at the camera's frame 0: again, bit for bit.
    capture(
        device.port(),
        &[
            "--config", &config, "--count", "10", "--verify", "--seed", "5",
        ],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    // The wrong seed: every frame differs, and capture says so.
    let err = capture(
        device.port(),
        &[
            "--config", &config, "--count", "5", "--verify", "--seed", "6",
        ],
    )
    .unwrap_err();
    assert!(
        format!("{err:#}").contains("differ from the reference"),
        "{err:#}"
    );
    own_camera_begins_unnumbered_and_has_no_sync_line(device.port());
}

/// A device's camera of its own (not shared by a rig's boards): its
/// captures say they began without a sync edge on a frame it does not
/// number, and it refuses the sync line (PROTOCOL.md §9).
fn own_camera_begins_unnumbered_and_has_no_sync_line(port: &str) {
    use brightpix::link::{CaptureBegan, LinkError};
    use brightpix_protocol::wire::{CaptureStart, DeviceError, SyncFault};
    let mut client = Client::open(port).unwrap();
    client.start_capture(2, CaptureStart::Immediate).unwrap();
    let frames = client
        .collect_capture(&mut |_| {}, &mut |_| {})
        .unwrap_or_else(|e| panic!("{}", e.error));
    assert_eq!(frames.len(), 2);
    assert_eq!(
        client.capture_began(),
        Some(CaptureBegan {
            synced: false,
            camera_frame: None
        })
    );
    for start in [CaptureStart::OnSync, CaptureStart::DriveSync] {
        match client.start_capture(1, start) {
            Err(LinkError::Device {
                error: DeviceError::Sync(SyncFault::NoSyncLine),
                ..
            }) => {}
            other => panic!("{start:?}: {other:?}"),
        }
    }
}

#[test]
fn capture_options_count_out_and_layout() {
    let device = in_process(2);
    let dir = temp_dir("brightpix-test-capture").unwrap();
    let config = canary();
    let out = |name: &str| dir.join(name).display().to_string();

    let npy = out("pairs.npy");
    capture(
        device.port(),
        &["--config", &config, "--count", "7", "--out", &npy],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    let slopes = read_array(&npy).unwrap();
    assert_eq!(slopes.shape, [7, 49, 2]);
    assert!(slopes.data.iter().all(|v| v.is_finite()));
    assert_eq!(read_array(out("pairs.flux.npy")).unwrap().shape, [7, 49]);
    assert_eq!(read_array(out("pairs.valid.npy")).unwrap().shape, [7, 49]);
    let provenance = std::fs::read_to_string(out("pairs.json")).unwrap();
    assert!(provenance.contains("brightpix capture"), "{provenance}");

    let fits = out("vector.fits");
    capture(
        device.port(),
        &[
            "--config", &config, "--count", "3", "--out", &fits, "--layout", "vector",
        ],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    let vector = read_array(&fits).unwrap();
    assert_eq!(vector.shape, [3, 98]);
    // The vector layout is the pairs layout regrouped, x then y: the same
    // camera frames give the same slopes.
    for s in 0..49 {
        assert_eq!(vector.data[s], slopes.data[2 * s], "x of sub-aperture {s}");
        assert_eq!(
            vector.data[49 + s],
            slopes.data[2 * s + 1],
            "y of sub-aperture {s}"
        );
    }

    let csv = out("rows.csv");
    capture(
        device.port(),
        &["--config", &config, "--count", "2", "--out", &csv],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows[0], "frame,subaperture,slope_x,slope_y,flux,valid");
    assert_eq!(rows.len(), 1 + 2 * 49);
    assert!(rows[1].starts_with("0,0,"), "{}", rows[1]);
    assert!(rows[98].starts_with("1,48,"), "{}", rows[98]);

    // Refusals before any work: --count 0, --verify without --config,
    // neither --out nor --verify.
    assert!(capture(device.port(), &["--count", "0", "--out", &npy]).is_err());
    assert!(capture(device.port(), &["--count", "1", "--verify"]).is_err());
    assert!(capture(device.port(), &["--count", "1"]).is_err());
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_device_without_camera_says_so() {
    let device = InProcessDevice::start_pty().unwrap();
    let dir = temp_dir("brightpix-test-nocamera").unwrap();
    let npy = dir.join("x.npy").display().to_string();
    let err = capture(
        device.port(),
        &["--config", &canary(), "--count", "1", "--out", &npy],
    )
    .unwrap_err();
    let text = format!("{err:#}");
    assert!(text.contains("no camera of its own"), "{text}");
    assert!(text.contains("NoCamera"), "{text}");
    assert!(!Path::new(&npy).exists());
    let _ = std::fs::remove_dir_all(dir);
}

fn qemu_elf() -> PathBuf {
    let t = Instant::now();
    let elf = build_qemu_elf_for(QemuCpu::M4).unwrap_or_else(|e| panic!("{e:#}"));
    eprintln!("  firmware build: {:.1} s", t.elapsed().as_secs_f64());
    elf
}

#[test]
fn capture_verify_in_qemu() {
    let mut device = QemuDevice::launch(QemuOptions {
        elf: Some(qemu_elf()),
        camera: camera(9, 10),
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    let t = Instant::now();
    let result = capture(
        device.port(),
        &[
            "--config",
            &canary(),
            "--count",
            "20",
            "--verify",
            "--seed",
            "9",
        ],
    );
    if let Some(status) = device.exit_status() {
        panic!(
            "the firmware {}; log:\n{}",
            QemuDevice::describe_exit(status),
            device.decoded_log().unwrap_or_default()
        );
    }
    result.unwrap_or_else(|e| {
        panic!(
            "{e:#}\nfirmware log:\n{}",
            device.decoded_log().unwrap_or_default()
        )
    });
    eprintln!(
        "  QEMU: 20 frames captured at the board's 10 frames/s and verified bit for bit in {:.2} s",
        t.elapsed().as_secs_f64()
    );
    // CANARY (16-bit, 112 wide, 16x16 windows) from the camera ring: the
    // engine's row kernel ran (issue 27 item 13: a ring or run buffer that
    // is not word-aligned would keep every row on the general path).
    let status = Client::open(device.port()).unwrap().status().unwrap();
    assert_eq!(status.frames_processed, 20, "{status:?}");
    assert!(
        status.engine.kernel_frames > 0 && status.engine.windows > 0,
        "the row kernel never ran on the camera's frames: {:?}",
        status.engine
    );
    // A second capture (its own request and FIFO) starts at frame 0 again.
    capture(
        device.port(),
        &[
            "--config",
            &canary(),
            "--count",
            "3",
            "--verify",
            "--seed",
            "9",
        ],
    )
    .unwrap_or_else(|e| {
        panic!(
            "second capture: {e}\nfirmware log:\n{}",
            device.decoded_log().unwrap_or_default()
        )
    });
    own_camera_begins_unnumbered_and_has_no_sync_line(device.port());
}
