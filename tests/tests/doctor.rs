//! `brightpix doctor`: its verdicts on a board's health as an STM32H743
//! would report it (healthy, and each fault a bring-up meets), and its
//! report against the in-process simulated device (every hardware-only
//! line marked as such). The QEMU device's report is checked in
//! `sil_qemu.rs` (M4 and M7).

use std::time::Duration;

use brightpix::cli::doctor::{diagnose, examine, Check, Verdict};
use brightpix::link::{Client, DeviceInfo};
use brightpix::sim_device::InProcessDevice;
use brightpix_protocol::wire::{
    CameraInterface, Clocks, ErratumFix, Fault, FaultKind, FaultLog, Health, PixelSourceKind,
    ResetReason, Silicon, StackUsage, Status, UsbClockSync, PROTOCOL_VERSION, SCHEMA_HASH,
};

fn board(name: &str) -> DeviceInfo {
    DeviceInfo {
        version: PROTOCOL_VERSION,
        schema: SCHEMA_HASH,
        max_subapertures: 1600,
        max_camera_pixels: 57_600,
        max_open_windows: 128,
        pool_entries: 4096,
        history_pixels: 0,
        scratch_entries: 0,
        max_results_per_row: 64,
        max_frame_bytes: 1034,
        pixel_source: PixelSourceKind::Camera,
        board: name.into(),
        session: 1,
    }
}

/// A rev Y STM32H743 as it should read after bring-up.
fn healthy() -> Status {
    Status {
        session: Some(1),
        reset_reason: ResetReason::PowerOn,
        watchdog_ms: Some(2000),
        health: Health {
            silicon: Some(Silicon {
                device_id: 0x450,
                revision_id: 0x1003,
                axi_sram_fix: ErratumFix::Applied,
            }),
            clocks: Some(Clocks {
                sysclk_configured_hz: 400_000_000,
                sysclk_read_hz: 400_000_000,
                voltage_scale_configured: 1,
                voltage_scale_read: 1,
                voltage_ready: true,
            }),
            usb_clock: Some(UsbClockSync {
                sync_source: 3,
                synced: true,
                trim: 33,
                sync_errors: 0,
            }),
            stack: Some(StackUsage {
                size: 47_000,
                peak: 5_000,
                guarded: true,
            }),
            camera_interface: Some(CameraInterface {
                overruns: 0,
                sync_errors: 0,
                dma_transfer_errors: 0,
                dma_fifo_errors: 0,
                fifo_not_drained: 0,
            }),
            idle_permille: Some(900),
            faults: Some(FaultLog { before_reset: None }),
        },
        ..Status::default()
    }
}

fn verdict_of(status: &Status, name: &str) -> Check {
    examine(&board("stm32h743-nucleo"), status, Duration::from_millis(2))
        .into_iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no line {name}"))
}

#[test]
fn a_healthy_board_is_all_ok() {
    let lines = examine(
        &board("stm32h743-nucleo"),
        &healthy(),
        Duration::from_millis(2),
    );
    assert_eq!(lines.len(), 12);
    for line in &lines {
        assert_eq!(line.verdict, Verdict::Ok, "{line}");
    }
    let silicon = verdict_of(&healthy(), "silicon");
    assert!(silicon.detail.contains("rev Y"), "{silicon}");
}

#[test]
fn each_bring_up_fault_is_named() {
    let mut s = healthy();
    s.health.silicon.as_mut().unwrap().axi_sram_fix = ErratumFix::Failed;
    assert_eq!(verdict_of(&s, "silicon").verdict, Verdict::Fail);

    let mut s = healthy();
    s.health.clocks.as_mut().unwrap().sysclk_read_hz = 64_000_000;
    assert_eq!(verdict_of(&s, "clocks").verdict, Verdict::Fail);
    let mut s = healthy();
    s.health.clocks.as_mut().unwrap().voltage_ready = false;
    assert_eq!(verdict_of(&s, "clocks").verdict, Verdict::Fail);

    let mut s = healthy();
    s.health.usb_clock.as_mut().unwrap().synced = false;
    let l = verdict_of(&s, "usb clock");
    assert_eq!(l.verdict, Verdict::Fail, "{l}");
    assert!(l.detail.contains("NEVER"), "{l}");
    let mut s = healthy();
    s.health.usb_clock.as_mut().unwrap().sync_errors = 3;
    assert_eq!(verdict_of(&s, "usb clock").verdict, Verdict::Warn);

    let mut s = healthy();
    s.health.stack.as_mut().unwrap().peak = 46_000;
    assert_eq!(verdict_of(&s, "stack").verdict, Verdict::Fail);
    let mut s = healthy();
    s.health.stack.as_mut().unwrap().guarded = false;
    assert_eq!(verdict_of(&s, "stack").verdict, Verdict::Warn);

    let mut s = healthy();
    s.health
        .camera_interface
        .as_mut()
        .unwrap()
        .dma_transfer_errors = 1;
    assert_eq!(verdict_of(&s, "camera interface").verdict, Verdict::Fail);
    let mut s = healthy();
    s.health.camera_interface.as_mut().unwrap().overruns = 1;
    assert_eq!(verdict_of(&s, "camera interface").verdict, Verdict::Warn);

    let mut s = healthy();
    s.health.idle_permille = Some(20);
    assert_eq!(verdict_of(&s, "cpu idle").verdict, Verdict::Warn);

    let mut s = healthy();
    s.reset_reason = ResetReason::Watchdog;
    assert_eq!(verdict_of(&s, "last reset").verdict, Verdict::Warn);

    let mut s = healthy();
    s.crc_errors = 1;
    assert_eq!(verdict_of(&s, "counters").verdict, Verdict::Warn);

    let mut s = healthy();
    s.reset_reason = ResetReason::Software;
    s.health.faults = Some(FaultLog {
        before_reset: Some(Fault {
            kind: FaultKind::HardFault,
            pc: 0x0800_1234,
            lr: 0x0800_0f01,
            cfsr: (1 << 15) | (1 << 9),
            hfsr: 1 << 30,
            mmfar: 0,
            bfar: 0x3000_0000,
        }),
    });
    let l = verdict_of(&s, "last fault");
    assert_eq!(l.verdict, Verdict::Fail, "{l}");
    for part in [
        "PC 0x08001234",
        "BFAR 0x30000000",
        "PRECISERR",
        "FORCED",
        "addr2line",
    ] {
        assert!(l.detail.contains(part), "{part}: {l}");
    }
    assert!(!l.detail.contains("MMFAR"), "not valid: {l}");

    let mut s = healthy();
    s.reset_reason = ResetReason::Watchdog;
    let l = verdict_of(&s, "last fault");
    assert!(l.detail.contains("lock-up"), "{l}");

    // Frames processed, the row kernel in none of them: a pixel buffer
    // that is not word-aligned (issue 27 item 13), or the configuration.
    let mut s = healthy();
    s.frames_processed = 100;
    let l = verdict_of(&s, "engine");
    assert_eq!(l.verdict, Verdict::Warn, "{l}");
    assert!(l.detail.contains("general path"), "{l}");
    assert!(l.detail.contains("word-align"), "{l}");
    s.engine.kernel_frames = 100;
    s.engine.windows = 4900;
    let l = verdict_of(&s, "engine");
    assert_eq!(l.verdict, Verdict::Ok, "{l}");
    assert!(l.detail.contains("row kernel in 100 frames"), "{l}");
}

/// On a real board a missing reading is a warning (old firmware), not
/// "hardware only".
#[test]
fn a_real_board_that_does_not_report_is_warned_about() {
    let s = Status {
        health: Health::default(),
        ..healthy()
    };
    let l = verdict_of(&s, "silicon");
    assert_eq!(l.verdict, Verdict::Warn, "{l}");
    assert!(!l.detail.contains("hardware only"), "{l}");
}

#[test]
fn the_in_process_device_marks_what_only_hardware_reads() {
    let device = InProcessDevice::start_pty().unwrap();
    let mut client =
        Client::open(device.port()).unwrap_or_else(|e| panic!("{}: {e}", device.port()));
    let lines = diagnose(&mut client, Duration::ZERO).unwrap();
    for line in &lines {
        match line.name {
            "link" | "counters" | "engine" => assert_eq!(line.verdict, Verdict::Ok, "{line}"),
            _ => {
                assert_eq!(line.verdict, Verdict::NotRead, "{line}");
                assert!(line.detail.contains("hardware only"), "{line}");
            }
        }
    }
}
