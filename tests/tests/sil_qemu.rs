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
