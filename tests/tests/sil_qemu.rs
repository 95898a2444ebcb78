//! Simulation in the loop with the real firmware: the QEMU board's ELF
//! (`brightpix-qemu`) in `qemu-system-arm` (mps2-an386, Cortex-M4), UART0
//! on a pseudo-terminal, pixels through a FIFO that the board reads by
//! semihosting (the emulated UART carries only ~20 KB/s). Driven through
//! the host tool's client; every result is checked bit for bit against
//! the reference.
//!
//! Needs `qemu-system-arm` and the thumbv7em-none-eabihf target
//! (`scripts/test` installs both). The ELF is (re)built by
//! `cargo build --release -p brightpix-board-qemu` in `firmware/` first,
//! which is quick when it is up to date.

mod sil_common;

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use brightpix::link::{Client, PixelSink};
use brightpix::sim_device::{build_qemu_elf, QemuDevice, QemuOptions, SimLinkKind};
use brightpix_protocol::wire::PixelSourceKind;
use sil_common::*;

/// Builds the firmware once for all tests of this file.
fn elf() -> std::path::PathBuf {
    static ELF: OnceLock<std::path::PathBuf> = OnceLock::new();
    ELF.get_or_init(|| {
        let t = Instant::now();
        let elf = build_qemu_elf().unwrap_or_else(|e| panic!("{e:#}"));
        eprintln!("  firmware build: {:.1} s", t.elapsed().as_secs_f64());
        elf
    })
    .clone()
}

fn launch(pixels_fifo: bool) -> QemuDevice {
    let device = QemuDevice::launch(QemuOptions {
        elf: Some(elf()),
        pixels_fifo,
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    device.release_fifo(Duration::from_secs(10)).unwrap();
    device
}

fn connect(device: &QemuDevice) -> Client {
    let mut client =
        Client::open(device.port()).unwrap_or_else(|e| panic!("{}: {e}", device.port()));
    if let Some(fifo) = device.pixels_fifo() {
        assert_eq!(client.info().pixel_source, PixelSourceKind::Stream);
        client.set_pixel_sink(PixelSink::Fifo(fifo.to_path_buf()));
    }
    client
}

/// Fails with the firmware's fate and log if QEMU has exited.
fn check_alive(device: &mut QemuDevice) {
    if let Some(status) = device.exit_status() {
        panic!(
            "the firmware {}; log:\n{}",
            QemuDevice::describe_exit(status),
            device.decoded_log().unwrap_or_default()
        );
    }
}

#[test]
fn every_case_bit_exact_in_qemu() {
    let cases = timed("simulating frames", all_cases);
    let mut device = launch(true);
    let mut client = connect(&device);
    eprintln!("  {}", client.info());
    for case in &cases {
        let t = Instant::now();
        let stream = run_case(&mut client, case);
        check_alive(&mut device);
        eprintln!(
            "  {}: {} frames verified, stream {:.0} ms, case {:.0} ms",
            case.name,
            case.frames.len(),
            stream.as_secs_f64() * 1e3,
            t.elapsed().as_secs_f64() * 1e3
        );
    }
}

fn case_with_maps() -> Case {
    edge_cases()
        .into_iter()
        .find(|c| c.config.background.is_some() && c.config.gain.is_some())
        .unwrap()
}

#[test]
fn failed_upload_keeps_the_old_configuration_in_qemu() {
    let mut device = launch(true);
    let case = case_with_maps();
    failed_uploads_keep_old_config(&mut || connect(&device), &case);
    check_alive(&mut device);
}

/// Issue 10, fault 1, as found: in QEMU, over UART0 (a client killed
/// mid-frame, then `stream --count 3 --verify` verified only 2 frames).
#[test]
fn a_dead_clients_leftovers_do_not_reach_the_next_session_in_qemu() {
    let mut device = launch(false);
    dead_client_leaves_nothing_behind(&mut || connect(&device), &edge_cases()[0]);
    check_alive(&mut device);
}

/// `check-config --device qemu` checks against what the firmware reports.
#[test]
fn the_qemu_limits_known_offline_are_the_firmwares() {
    let mut device = launch(false);
    let client = connect(&device);
    let reported = brightpix::link::limits::DeviceLimits::of(client.info());
    assert_eq!(
        Some(reported),
        brightpix::link::limits::DeviceLimits::named("qemu")
    );
    check_alive(&mut device);
}

/// Issue 10, fault 4: `simulate-device --qemu` killed with SIGKILL left
/// `qemu-system-arm` running as an orphan holding the pty. This test runs
/// itself as the parent (a child process of the test binary that launches
/// QEMU and waits), kills that parent with SIGKILL, and checks that QEMU is
/// gone within 3 s.
#[test]
fn qemu_dies_with_its_parent() {
    const ROLE: &str = "BRIGHTPIX_TEST_QEMU_PARENT";
    if std::env::var_os(ROLE).is_some() {
        let device = launch(false);
        println!("qemu-pid {}", device.pid());
        std::io::Write::flush(&mut std::io::stdout()).unwrap();
        std::thread::sleep(Duration::from_secs(60));
        return;
    }
    let mut parent = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "qemu_dies_with_its_parent",
            "--exact",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(ROLE, "1")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let stdout = parent.stdout.take().unwrap();
    let mut pid = None;
    for line in std::io::BufRead::lines(std::io::BufReader::new(stdout)) {
        let line = line.unwrap();
        // The test harness may have printed "test ... " on the same line.
        if let Some(at) = line.find("qemu-pid ") {
            pid = Some(line[at + 9..].trim().parse::<u32>().unwrap());
            break;
        }
    }
    let pid = pid.expect("the parent reports QEMU's pid");
    let alive = |pid: u32| {
        // A zombie (state Z) has exited; only its parent's reaping is due.
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .map(|s| {
                !s.rsplit(')')
                    .next()
                    .unwrap_or("")
                    .trim_start()
                    .starts_with('Z')
            })
            .unwrap_or(false)
    };
    assert!(alive(pid), "QEMU runs while its parent does");
    parent.kill().unwrap(); // SIGKILL: no handler, no destructor runs
    parent.wait().unwrap();
    let t = std::time::Instant::now();
    while alive(pid) && t.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let orphan = alive(pid);
    if orphan {
        // Do not leave it behind for the next test.
        let _ = std::process::Command::new("kill")
            .args(["-KILL", &pid.to_string()])
            .status();
    }
    assert!(!orphan, "qemu-system-arm (pid {pid}) outlived its parent");
}

#[test]
fn corrupted_pixel_frame_is_counted_and_rejected_in_qemu() {
    let mut device = launch(true);
    let mut client = connect(&device);
    // The damaged frame goes over UART0; the others through the FIFO.
    corrupted_pixel_frame_is_rejected(&mut client, &case_with_maps());
    check_alive(&mut device);
}

#[test]
fn pixels_over_the_uart_and_a_unix_socket_in_qemu() {
    // The slow path, briefly: 20 small frames (1.9 KB each) over UART0,
    // which QEMU serves on a Unix socket (every case above runs 100 frames
    // through the FIFO).
    let dir = brightpix::sim_device::temp_dir("brightpix-test-qemu-unix").unwrap();
    let mut device = QemuDevice::launch(QemuOptions {
        elf: Some(elf()),
        link: SimLinkKind::Unix(dir.join("uart0.sock")),
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    let mut client = connect(&device);
    assert_eq!(client.info().pixel_source, PixelSourceKind::Link);
    let first = edge_cases().swap_remove(0);
    let case = &Case {
        frames: first.frames[..20].to_vec(),
        ..first
    };
    let stream = run_case(&mut client, case);
    eprintln!(
        "  over UART0: {} frames in {:.2} s",
        case.frames.len(),
        stream.as_secs_f64()
    );
    check_alive(&mut device);
    drop(client);
    device.stop();
    let _ = std::fs::remove_dir_all(dir);
}
