//! `brightpix doctor`: the device's health, one line per thing a bring-up
//! engineer checks first, each with a verdict. Built from `HelloReply` and
//! `Status` (`Status.health`, PROTOCOL.md §5): what the board reads about
//! itself. A reading the board cannot make is `None` on the wire; on a
//! simulated device (QEMU, in-process) that is marked "hardware only".

use std::fmt;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use brightpix_protocol::wire::{
    crs_sync_source_name, ErratumFix, Fault, FaultLog, Health, ResetReason, Status,
};
use clap::Args;

use crate::link::{Client, DeviceInfo};

#[derive(Args)]
#[command(
    about = "Check a device's health: silicon and errata, clocks, USB clock trimming, stack, camera interface, resets, link, the engine's row kernel",
    after_help = "Examples:\n  brightpix doctor --port /dev/ttyACM0\n  brightpix doctor --port /dev/pts/4        # a simulated device: hardware-only lines say so\n\n\
Exit status 1 if any line is FAIL. firmware/boards/stm32h743/README.md (\"Bring-up\") says what each line should read."
)]
pub struct DoctorArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
    /// Seconds between the two status requests over which the CPU's idle
    /// time is measured (boards that report it).
    #[arg(long, default_value_t = 1.0)]
    window: f64,
}

/// A line's verdict.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Ok,
    Warn,
    Fail,
    /// The device cannot read this (a simulated one: hardware only).
    NotRead,
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(match self {
            Verdict::Ok => "ok",
            Verdict::Warn => "WARN",
            Verdict::Fail => "FAIL",
            Verdict::NotRead => "n/a",
        })
    }
}

/// One line of the report.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Check {
    pub name: &'static str,
    pub verdict: Verdict,
    pub detail: String,
}

impl fmt::Display for Check {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:<5} {:<16} {}", self.verdict, self.name, self.detail)
    }
}

/// Whether the device is a simulation (QEMU or in-process), by its board
/// name: its missing readings are hardware-only, not faults.
pub fn is_simulated(board: &str) -> bool {
    board.starts_with("qemu-") || board.starts_with("brightpix-sim")
}

/// The STM32H7 revision letter of a DBGMCU_IDCODE REV_ID (RM0433 §62.5.8).
fn revision_name(revision_id: u16) -> &'static str {
    match revision_id {
        0x1000 => "rev A",
        0x1001 => "rev Z",
        0x1003 => "rev Y",
        0x2001 => "rev X",
        0x2003 => "rev V",
        _ => "unknown revision",
    }
}

fn mhz(hz: u32) -> String {
    format!("{:.1} MHz", f64::from(hz) / 1e6)
}

/// The report's lines for a device's identity and status; `round_trip`
/// is the time the status request took.
pub fn examine(info: &DeviceInfo, status: &Status, round_trip: Duration) -> Vec<Check> {
    let simulated = is_simulated(&info.board);
    let missing = |name: &'static str| Check {
        name,
        verdict: if simulated {
            Verdict::NotRead
        } else {
            Verdict::Warn
        },
        detail: if simulated {
            "hardware only: not read by this simulated device".into()
        } else {
            "not reported by this board's firmware".into()
        },
    };
    let check = |name, verdict, detail: String| Check {
        name,
        verdict,
        detail,
    };
    let Health {
        silicon,
        clocks,
        usb_clock,
        stack,
        camera_interface,
        idle_permille,
        faults,
    } = status.health;
    let mut lines = vec![check(
        "link",
        Verdict::Ok,
        format!(
            "board \"{}\", protocol {} (schema {:#018x}), status round trip {:.1} ms",
            info.board,
            info.version,
            info.schema,
            round_trip.as_secs_f64() * 1e3
        ),
    )];
    lines.push(match silicon {
        None => missing("silicon"),
        Some(s) => {
            let (verdict, fix) = match s.axi_sram_fix {
                ErratumFix::NotNeeded => (Verdict::Ok, "not needed on this revision"),
                ErratumFix::Applied => (Verdict::Ok, "workaround applied and read back"),
                ErratumFix::Failed => (
                    Verdict::Fail,
                    "NEEDED but AXI_TARG7_FN_MOD did not read back: AXI SRAM reads may be corrupted",
                ),
            };
            check(
                "silicon",
                verdict,
                format!(
                    "DEV_ID {:#05x}, REV_ID {:#06x} ({}); AXI SRAM erratum (ES0392): {fix}",
                    s.device_id,
                    s.revision_id,
                    revision_name(s.revision_id)
                ),
            )
        }
    });
    lines.push(match clocks {
        None => missing("clocks"),
        Some(c) => {
            let clock_ok = c.sysclk_configured_hz == c.sysclk_read_hz;
            let scale_ok = c.voltage_scale_configured == c.voltage_scale_read && c.voltage_ready;
            check(
                "clocks",
                if clock_ok && scale_ok {
                    Verdict::Ok
                } else {
                    Verdict::Fail
                },
                format!(
                    "CPU {} configured, {} read back; voltage scale {} configured, {} read back{}",
                    mhz(c.sysclk_configured_hz),
                    mhz(c.sysclk_read_hz),
                    c.voltage_scale_configured,
                    c.voltage_scale_read,
                    if c.voltage_ready {
                        ", ready"
                    } else {
                        ", NOT READY"
                    }
                ),
            )
        }
    });
    lines.push(match usb_clock {
        None => missing("usb clock"),
        Some(u) => {
            // SYNCSRC's codes depend on the silicon revision (rev Y swaps
            // the pin and USB2); without the revision, say so.
            let source = match silicon {
                Some(s) => format!(
                    "{} (SYNCSRC {}, REV_ID {:#06x})",
                    crs_sync_source_name(u.sync_source, s.revision_id),
                    u.sync_source,
                    s.revision_id
                ),
                None => format!("SYNCSRC {} (silicon revision unknown)", u.sync_source),
            };
            let verdict = if !u.synced {
                Verdict::Fail
            } else if u.sync_errors > 0 {
                Verdict::Warn
            } else {
                Verdict::Ok
            };
            check(
                "usb clock",
                verdict,
                format!(
                    "HSI48 trimmed by the CRS from {source}: {}, trim {} (32 = factory middle), {} sync errors since boot (a miss counts whenever SOFs stop: unplugging, suspend, a host reset)",
                    if u.synced {
                        "synchronised"
                    } else {
                        "NEVER synchronised (check SYNCSRC and that USB is configured)"
                    },
                    u.trim,
                    u.sync_errors
                ),
            )
        }
    });
    lines.push(match stack {
        None => missing("stack"),
        Some(s) => {
            let share = f64::from(s.peak) / f64::from(s.size.max(1));
            let verdict = if share > 0.9 {
                Verdict::Fail
            } else if share > 0.75 || !s.guarded {
                Verdict::Warn
            } else {
                Verdict::Ok
            };
            check(
                "stack",
                verdict,
                format!(
                    "{} of {} bytes used at most ({:.1}%), {}",
                    s.peak,
                    s.size,
                    share * 100.0,
                    if s.guarded {
                        "guarded (an overflow faults)"
                    } else {
                        "NOT guarded (an overflow corrupts silently)"
                    }
                ),
            )
        }
    });
    lines.push(match camera_interface {
        None => missing("camera interface"),
        Some(c) => {
            let verdict = if c.dma_transfer_errors > 0 {
                Verdict::Fail
            } else if c.overruns + c.sync_errors + c.dma_fifo_errors + c.fifo_not_drained > 0 {
                Verdict::Warn
            } else {
                Verdict::Ok
            };
            check(
                "camera interface",
                verdict,
                format!(
                    "since boot: overruns {}, sync errors {} (embedded-sync mode only; 0 with HSYNC/VSYNC wires), DMA transfer errors {}, DMA FIFO errors {}, FIFO not drained at frame end {}",
                    c.overruns, c.sync_errors, c.dma_transfer_errors, c.dma_fifo_errors, c.fifo_not_drained
                ),
            )
        }
    });
    lines.push(match idle_permille {
        None => missing("cpu idle"),
        Some(p) => check(
            "cpu idle",
            if p < 100 { Verdict::Warn } else { Verdict::Ok },
            format!(
                "{:.1}% of the time asleep since the previous status request",
                f64::from(p) / 10.0
            ),
        ),
    });
    lines.push(match status.reset_reason {
        ResetReason::Unknown if simulated => missing("last reset"),
        r @ (ResetReason::Watchdog | ResetReason::Brownout | ResetReason::Other) => {
            check("last reset", Verdict::Warn, r.to_string())
        }
        r => check("last reset", Verdict::Ok, r.to_string()),
    });
    lines.push(match faults {
        None => missing("last fault"),
        Some(FaultLog { before_reset: None }) => check(
            "last fault",
            Verdict::Ok,
            if status.reset_reason == ResetReason::Watchdog {
                "none recorded: a watchdog reset without a record is a hang, or a lock-up (a stack overflow into the guard faults while stacking the exception, before any handler runs)".into()
            } else {
                "none recorded before the last reset".into()
            },
        ),
        Some(FaultLog {
            before_reset: Some(f),
        }) => check("last fault", Verdict::Fail, describe_fault(&f)),
    });
    lines.push(match status.watchdog_ms {
        None => missing("watchdog"),
        Some(ms) => check(
            "watchdog",
            Verdict::Ok,
            format!("{ms} ms, fed by the device loop"),
        ),
    });
    let link_errors = status.crc_errors + status.decode_errors;
    lines.push(check(
        "counters",
        if link_errors + status.overruns + status.pixel_errors > 0 {
            Verdict::Warn
        } else {
            Verdict::Ok
        },
        format!(
            "frames processed {}, dropped {}; CRC errors {}, decode errors {}, overruns {}, pixel errors {}",
            status.frames_processed,
            status.frames_dropped,
            status.crc_errors,
            status.decode_errors,
            status.overruns,
            status.pixel_errors
        ),
    ));
    // The engine's row kernel (an assembly routine on Cortex-M) takes
    // word-aligned rows of kernel-ready windows; a board whose pixel
    // buffers are not word-aligned runs every frame on the general path,
    // correct but slower than the bench's figures.
    let e = &status.engine;
    lines.push(check(
        "engine",
        if e.kernel_frames == 0 && status.frames_processed > 0 {
            Verdict::Warn
        } else {
            Verdict::Ok
        },
        if status.frames_processed == 0 {
            "no frame processed yet".into()
        } else if e.kernel_frames == 0 {
            format!(
                "the row kernel ran in none of {} frames: every pixel took the engine's general path, correct but slower than `brightpix bench` says; the cause is the configuration (windows at odd columns or of odd width, no selection, below 16 bits pixels outside every window) or a pixel buffer the board does not word-align (firmware/README.md)",
                status.frames_processed
            )
        } else {
            format!(
                "row kernel in {} frames ({} processed, {} dropped); {} windows, {} rescanned, {} compactions",
                e.kernel_frames,
                status.frames_processed,
                status.frames_dropped,
                e.windows,
                e.rescans,
                e.compactions
            )
        },
    ));
    lines
}

/// Names of the set bits of CFSR (ARMv7-M ARM B3.2.15: MemManage, BusFault
/// and UsageFault status) and HFSR (B3.2.16).
const CFSR_BITS: [(u32, &str); 17] = [
    (0, "IACCVIOL (instruction access violation)"),
    (1, "DACCVIOL (data access violation)"),
    (3, "MUNSTKERR"),
    (4, "MSTKERR (stacking hit the MPU: stack overflow)"),
    (5, "MLSPERR"),
    (8, "IBUSERR (instruction bus error)"),
    (9, "PRECISERR (precise data bus error)"),
    (10, "IMPRECISERR (imprecise data bus error)"),
    (11, "UNSTKERR"),
    (12, "STKERR (stacking bus error: stack overflow)"),
    (13, "LSPERR"),
    (
        16,
        "UNDEFINSTR (undefined instruction: a panic ends in UDF)",
    ),
    (17, "INVSTATE"),
    (18, "INVPC"),
    (19, "NOCP (coprocessor/FPU disabled)"),
    (24, "UNALIGNED"),
    (25, "DIVBYZERO"),
];

/// The `last fault` line: the registers, their causes named, and what to
/// do with the PC.
pub fn describe_fault(f: &Fault) -> String {
    let mut causes: Vec<&str> = CFSR_BITS
        .iter()
        .filter(|(bit, _)| f.cfsr & (1 << bit) != 0)
        .map(|(_, name)| *name)
        .collect();
    if f.hfsr & (1 << 30) != 0 {
        causes.push("FORCED (escalated to HardFault)");
    }
    if f.hfsr & (1 << 1) != 0 {
        causes.push("VECTTBL (vector table read)");
    }
    let mut text = format!(
        "{:?} before the last reset: PC {:#010x}, LR {:#010x}, CFSR {:#010x}, HFSR {:#010x}",
        f.kind, f.pc, f.lr, f.cfsr, f.hfsr
    );
    // The address registers hold something only when CFSR says so.
    if f.cfsr & (1 << 7) != 0 {
        text.push_str(&format!(", MMFAR {:#010x}", f.mmfar));
    }
    if f.cfsr & (1 << 15) != 0 {
        text.push_str(&format!(", BFAR {:#010x}", f.bfar));
    }
    text.push_str(&format!(
        "; {}; find the function: addr2line -e <the flashed ELF> {:#x}",
        if causes.is_empty() {
            "no cause bit set".to_string()
        } else {
            causes.join(", ")
        },
        f.pc
    ));
    text
}

/// Asks the device for its status (twice, `window` apart, when it reports
/// its CPU's idle time, so that the idle share covers that window) and
/// examines it.
pub fn diagnose(client: &mut Client, window: Duration) -> Result<Vec<Check>> {
    let t = Instant::now();
    let mut status = client.status()?;
    let mut round_trip = t.elapsed();
    if status.health.idle_permille.is_some() {
        std::thread::sleep(window);
        let t = Instant::now();
        status = client.status()?;
        round_trip = t.elapsed();
    }
    Ok(examine(client.info(), &status, round_trip))
}

pub fn run(args: DoctorArgs) -> Result<()> {
    if !(args.window.is_finite() && (0.0..=60.0).contains(&args.window)) {
        bail!("--window {} must be between 0 and 60 seconds", args.window);
    }
    let mut client = Client::open(&args.port)?;
    let lines = diagnose(&mut client, Duration::from_secs_f64(args.window))?;
    println!("brightpix doctor: {}", args.port);
    for line in &lines {
        println!("{line}");
    }
    let failed = lines.iter().filter(|l| l.verdict == Verdict::Fail).count();
    let warned = lines.iter().filter(|l| l.verdict == Verdict::Warn).count();
    if failed > 0 {
        bail!("{failed} check(s) failed, {warned} warning(s)");
    }
    println!("{warned} warning(s), no failures");
    Ok(())
}
