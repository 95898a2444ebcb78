//! `brightpix soak`: stream simulated frames to a device for a long time,
//! verifying every slope, and watch the device's counters and memory.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Args;

use crate::link::verify::Verifier;
use crate::link::{Client, FrameOutcome, PixelSink};
use crate::sil::{canary_config, canary_frames, verify_outcomes};
use crate::sim_device::{catch_interrupts, interrupted, InProcessDevice, QemuDevice, QemuOptions};

#[derive(Args)]
#[command(
    about = "Stream and verify simulated CANARY frames for a given time; report frames, mismatches, drops and the device's memory",
    after_help = "Examples:\n  brightpix soak --minutes 60                 # the firmware's device loop in-process\n  brightpix soak --minutes 30 --qemu          # the firmware ELF in qemu-system-arm (pixels through its FIFO)\n  brightpix soak --minutes 0.2 --port /dev/ttyACM0   # a board (its memory is not visible from here)\n\n\
A pool of simulated CANARY frames (examples/canary.toml, 49 NGS spots each) is streamed over and\n\
over, with continuous frame numbers, and every slope, flux and validity flag is compared with the\n\
reference. At the end: frames verified, mismatches, frames dropped or missing, the device's\n\
counters, and the resident memory (VmRSS) of the device's process at the start and the end (the\n\
in-process device is this process; QEMU's is its own). Exit status non-zero on any mismatch,\n\
dropped or missing frame, or link error. Ctrl-C ends the soak early, with the same report."
)]
pub struct SoakArgs {
    /// How long to stream (fractions allowed: 0.5 is 30 s).
    #[arg(long, default_value_t = 1.0)]
    minutes: f64,
    /// Run the real firmware ELF in qemu-system-arm instead of the firmware library in-process.
    #[arg(long, conflicts_with = "port")]
    qemu: bool,
    /// Firmware ELF for --qemu.
    #[arg(long, value_name = "PATH")]
    elf: Option<PathBuf>,
    /// With --qemu, send pixels over the emulated UART (~8 KB/s: a CANARY frame every ~3 s) instead of the FIFO.
    #[arg(long)]
    pixels_over_uart: bool,
    /// Soak a device on this port instead of a simulated one.
    #[arg(long)]
    port: Option<String>,
    /// Distinct simulated frames streamed in turn.
    #[arg(long, default_value_t = 64, value_parser = super::at_least_one)]
    pool: usize,
    /// Seed of the simulated frames.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// The device soaked; kept alive (and stopped when dropped) for the run.
enum Soaked {
    #[allow(dead_code)]
    InProcess(InProcessDevice),
    Qemu(QemuDevice),
    Port,
}

/// Resident memory of a process, kB (`VmRSS` of /proc/PID/status).
fn resident_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
}

pub fn run(args: SoakArgs) -> Result<()> {
    if !(args.minutes.is_finite() && args.minutes > 0.0) {
        bail!("--minutes must be a positive number (got {})", args.minutes);
    }
    let duration = Duration::from_secs_f64(args.minutes * 60.0);
    let config = canary_config();
    let view = config.view();
    let frames = canary_frames(args.pool, args.seed);
    catch_interrupts();
    let (device, port, fifo, what) = if let Some(port) = &args.port {
        (
            Soaked::Port,
            port.clone(),
            None,
            format!("the device on {port}"),
        )
    } else if args.qemu {
        let device = QemuDevice::launch(QemuOptions {
            elf: args.elf.clone(),
            pixels_fifo: !args.pixels_over_uart,
            ..QemuOptions::default()
        })?;
        device.release_fifo(Duration::from_secs(10))?;
        let port = device.port().to_string();
        let fifo = device.pixels_fifo().map(|p| p.to_path_buf());
        let what = format!("the firmware in qemu-system-arm (pid {})", device.pid());
        (Soaked::Qemu(device), port, fifo, what)
    } else {
        let device = InProcessDevice::start_pty().context("starting the in-process device")?;
        let port = device.port().to_string();
        let what = "the firmware's device loop in this process".to_string();
        (Soaked::InProcess(device), port, None, what)
    };
    let pid = match &device {
        Soaked::InProcess(_) => Some(std::process::id()),
        Soaked::Qemu(d) => Some(d.pid()),
        Soaked::Port => None,
    };
    let mut client = Client::open(&port)?;
    client.set_interrupt(Some(interrupted));
    client.configure(&view)?;
    if let Some(fifo) = fifo {
        client.set_pixel_sink(PixelSink::Fifo(fifo));
    }
    let before = client.status()?;
    let memory_start = pid.and_then(resident_kb);
    eprintln!(
        "brightpix soak: {what}, {:.1} min of CANARY frames ({} in the pool), every slope verified",
        args.minutes,
        frames.len()
    );

    let mut verifier = Verifier::new(&view, 10).context("configuration")?;
    let started = Instant::now();
    let mut next = 0u32;
    let mut sent = 0u64;
    let mut error = None;
    let mut last_report = Instant::now();
    while started.elapsed() < duration && !interrupted() {
        let mut outcomes: Vec<FrameOutcome> = Vec::with_capacity(frames.len());
        let result = client.stream_frames(next, &frames, |o| outcomes.push(o));
        if matches!(result, Err(crate::link::LinkError::Interrupted)) {
            // Frames cut off by Ctrl-C are not the device's failures.
            outcomes.retain(|o| !matches!(o, FrameOutcome::Incomplete(_)));
        }
        let batch = match &result {
            Ok(r) => r.frames_sent,
            Err(_) => outcomes.len(),
        };
        verify_outcomes(&mut verifier, &frames[..batch], next, &outcomes);
        sent += batch as u64;
        next = next.wrapping_add(batch as u32);
        if let Err(e) = result {
            error = Some(e);
            break;
        }
        if last_report.elapsed() > Duration::from_secs(60) {
            last_report = Instant::now();
            eprintln!(
                "brightpix soak: {:.1} min: {} frames verified, {} mismatches, {} dropped, {} missing",
                started.elapsed().as_secs_f64() / 60.0,
                verifier.frames_verified,
                verifier.mismatch_count,
                verifier.frames_dropped,
                verifier.frames_missing
            );
        }
    }
    let elapsed = started.elapsed();
    // After Ctrl-C the interrupt hook would refuse the last request too: the
    // report promised by --help needs the device's counters.
    client.set_interrupt(None);
    let after = client.status();
    let memory_end = pid.and_then(resident_kb);
    let mut device = device;
    let exit = match &mut device {
        Soaked::Qemu(d) => d.exit_status().map(QemuDevice::describe_exit),
        _ => None,
    };

    println!("brightpix soak: {what}, {:.1} s", elapsed.as_secs_f64());
    println!(
        "  frames:     {sent} sent, {} verified bit for bit ({:.0} frames/s), {} sub-aperture results compared",
        verifier.frames_verified,
        verifier.frames_verified as f64 / elapsed.as_secs_f64().max(1e-9),
        verifier.slopes_compared
    );
    println!(
        "  failures:   {} mismatches, {} frames dropped, {} missing",
        verifier.mismatch_count, verifier.frames_dropped, verifier.frames_missing
    );
    for m in &verifier.mismatches {
        println!("    mismatch: {m}");
    }
    match &after {
        Ok(s) => println!(
            "  device:     {} frames processed, {} dropped, {} CRC errors, {} decode errors, {} overruns, {} pixel errors (at start: {} processed, {} dropped)",
            s.frames_processed,
            s.frames_dropped,
            s.crc_errors,
            s.decode_errors,
            s.overruns,
            s.pixel_errors,
            before.frames_processed,
            before.frames_dropped
        ),
        Err(e) => println!("  device:     no status at the end: {e}"),
    }
    match (memory_start, memory_end) {
        (Some(a), Some(b)) => println!(
            "  memory:     {a} kB resident at the start, {b} kB at the end ({:+} kB), process {}",
            b as i64 - a as i64,
            pid.unwrap_or(0)
        ),
        _ => println!("  memory:     not visible (a device on a port)"),
    }
    if let Some(exit) = exit {
        bail!("the firmware {exit}");
    }
    if let Some(e) = error {
        if !matches!(e, crate::link::LinkError::Interrupted) {
            bail!("the soak stopped after {sent} frames: {e}");
        }
    }
    let after = after?;
    let device_dropped = after.frames_dropped - before.frames_dropped;
    if !verifier.all_match() || device_dropped > 0 {
        bail!(
            "the soak failed: {} mismatches, {} frames dropped ({} by the device's count), {} missing",
            verifier.mismatch_count,
            verifier.frames_dropped,
            device_dropped,
            verifier.frames_missing
        );
    }
    if verifier.frames_verified == 0 {
        bail!("no frame was verified");
    }
    Ok(())
}
