//! `brightpix demo`: a simulated device, the paper's CANARY model,
//! simulated Shack-Hartmann frames, every slope verified bit for bit.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::Status;
use clap::Args;

use crate::link::{Client, PixelSink};
use crate::sil::{canary_config, canary_frames, stream_and_verify_with};
use crate::sim_device::{InProcessDevice, QemuDevice, QemuOptions};

#[derive(Args)]
#[command(
    about = "Start a simulated device, configure it for the paper's CANARY model, stream simulated frames and verify every slope bit for bit",
    after_help = "Examples:\n  cargo run --release -p brightpix -- demo\n  brightpix demo                  # the firmware's device loop in-process, over a pseudo-terminal\n  brightpix demo --qemu           # the real firmware ELF in qemu-system-arm (built if missing)\n  brightpix demo --count 1000 --seed 7\n\n\
The CANARY model is examples/canary.toml: 112x112 camera, 7x7 sub-apertures of 16x16 pixels,\n\
subtract-next N = 20, 50-count background. Each frame tiles 49 independent spots of the\n\
paper's NGS simulation (host/src/simulator). The device's results are compared with the\n\
reference implementation (host/src/reference); the exit status is 0 only if all agree."
)]
pub struct DemoArgs {
    /// Run the real firmware ELF in qemu-system-arm instead of the firmware library in-process.
    #[arg(long)]
    qemu: bool,
    /// Frames to simulate and stream (`--frames` names a file in every command).
    #[arg(long = "count", value_name = "N", default_value_t = 200, value_parser = super::at_least_one)]
    frames: usize,
    /// Seed of the simulated turbulence and noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Firmware ELF for --qemu.
    #[arg(long, value_name = "PATH")]
    elf: Option<PathBuf>,
    /// With --qemu, send pixels over the emulated UART (~8 KB/s, about 3 s per CANARY frame) instead of the FIFO.
    #[arg(long)]
    pixels_over_uart: bool,
    /// Mismatches to print.
    #[arg(long, default_value_t = 10)]
    show: usize,
    /// Split the camera over this many simulated boards (a rig, `brightpix rig`): each computes
    /// its rectangle's sub-apertures; their results are merged by frame number and verified
    /// against the whole-camera reference.
    #[arg(long, value_name = "K", value_parser = super::at_least_one, conflicts_with = "pixels_over_uart")]
    boards: Option<usize>,
}

enum SimDevice {
    InProcess(InProcessDevice),
    Qemu(QemuDevice),
}

pub fn run(args: DemoArgs) -> Result<()> {
    let config = canary_config();
    let view = config.view();
    eprintln!(
        "brightpix demo: simulating {} CANARY frames (49 spots each, seed {})...",
        args.frames, args.seed
    );
    let t = Instant::now();
    let frames = canary_frames(args.frames, args.seed);
    let sim_time = t.elapsed();
    if let Some(boards) = args.boards {
        return super::rig::demo(boards, &frames, args.qemu, args.elf);
    }

    let (device, what) = if args.qemu {
        eprintln!("brightpix demo: starting the firmware in qemu-system-arm...");
        let device = QemuDevice::launch(QemuOptions {
            elf: args.elf.clone(),
            pixels_fifo: !args.pixels_over_uart,
            ..QemuOptions::default()
        })?;
        device.release_fifo(Duration::from_secs(10))?;
        let what =
            format!(
            "the firmware ELF in qemu-system-arm (mps2-an386, Cortex-M4), UART0 on {}, pixels {}",
            device.port(),
            if args.pixels_over_uart { "over UART0" } else { "through a semihosting FIFO" }
        );
        (SimDevice::Qemu(device), what)
    } else {
        let device = InProcessDevice::start_pty().context("starting the in-process device")?;
        let what = format!(
            "the firmware's device loop in-process, on the pseudo-terminal {}",
            device.port()
        );
        (SimDevice::InProcess(device), what)
    };
    let (port, fifo) = match &device {
        SimDevice::InProcess(d) => (d.port().to_string(), None),
        SimDevice::Qemu(d) => (
            d.port().to_string(),
            d.pixels_fifo().map(|p| p.to_path_buf()),
        ),
    };
    let mut client = Client::open(&port)?;
    let configured = client.configure(&view)?;
    if let Some(fifo) = fifo {
        client.set_pixel_sink(PixelSink::Fifo(fifo));
    }
    eprintln!("brightpix demo: streaming...");
    let progress = super::progress::Progress::new(frames.len() as u64, "frames");
    let run = stream_and_verify_with(&mut client, &view, &frames, 0, args.show, || {
        progress.inc(1)
    });
    progress.finish();
    let status = client.status();
    let mut firmware_exit = None;
    let mut device = device;
    if let SimDevice::Qemu(d) = &mut device {
        firmware_exit = d.exit_status().map(QemuDevice::describe_exit);
    }

    let v = &run.verifier;
    println!("brightpix demo: {what}");
    println!("  device:        {}", client.info());
    println!(
        "  configuration: CANARY (examples/canary.toml): {}x{} camera, {} sub-apertures of 16x16, subtract-next N = 20, 50-count background",
        view.camera.width,
        view.camera.height,
        view.windows.len()
    );
    println!(
        "                 uploaded in {} messages ({} table bytes) in {:.1} ms, config id {:#010x}",
        configured.messages,
        configured.table_bytes,
        configured.elapsed.as_secs_f64() * 1e3,
        configured.config_id
    );
    println!(
        "  frames:        {} simulated Shack-Hartmann frames (seed {}) in {:.2} s",
        frames.len(),
        args.seed,
        sim_time.as_secs_f64()
    );
    println!(
        "  streamed:      {} frames, {:.1} MB of pixels, in {:.3} s: {:.0} frames/s, {:.0} us/frame",
        run.report.frames_done,
        run.report.pixel_bytes as f64 / 1e6,
        run.report.elapsed.as_secs_f64(),
        run.frames_per_second(),
        run.per_frame().as_secs_f64() * 1e6
    );
    println!(
        "  verified:      {} frames, {} sub-aperture slopes compared bit for bit with the reference: {} mismatches, {} frames dropped",
        v.frames_verified, v.slopes_compared, v.mismatch_count, v.frames_dropped
    );
    for m in &v.mismatches {
        println!("    mismatch: {m}");
    }
    match &status {
        Ok(s) => {
            println!("  {}", format_status(s));
            println!("  {}", format_engine(s));
        }
        Err(e) => println!("  device status: unavailable ({e})"),
    }
    if let Some(exit) = firmware_exit {
        println!("  firmware:      {exit}");
    }
    if let Some(e) = run.error {
        bail!("streaming failed: {e}");
    }
    if !v.all_match() || v.frames_verified as usize != frames.len() {
        bail!("the device's results differ from the reference");
    }
    println!(
        "PASS: all {} frames bit-identical to the reference",
        v.frames_verified
    );
    drop(client);
    drop(device);
    Ok(())
}

/// The device's counters on one line.
pub fn format_status(s: &Status) -> String {
    format!(
        "device status: config id {}{}, frames processed {}, dropped {}, CRC errors {}, decode errors {}, overruns {}, pixel errors {}{}; last reset: {}; watchdog: {}",
        s.config_id.map_or("none".into(), |c| format!("{c:#010x}")),
        s.config_digest
            .map_or(String::new(), |d| format!(" (digest {d:#010x})")),
        s.frames_processed,
        s.frames_dropped,
        s.crc_errors,
        s.decode_errors,
        s.overruns,
        s.pixel_errors,
        if s.capturing { ", capturing" } else { "" },
        s.reset_reason,
        s.watchdog_ms
            .map_or("none".into(), |ms| format!("{ms} ms, fed by the device loop"))
    )
}

/// The device's engine counters (`Status.engine`, since the device
/// started) on one line: whether the row kernel ran, and the slow paths.
pub fn format_engine(s: &Status) -> String {
    let e = &s.engine;
    let per_window = |n: u64| {
        if e.windows == 0 {
            String::new()
        } else {
            format!(" ({:.1} a window)", n as f64 / e.windows as f64)
        }
    };
    format!(
        "device engine: row kernel ran in {} frames ({} processed, {} dropped){}; windows {}, candidates {}{}, compactions {}, rescans {}, kernel attention stops {}{}",
        e.kernel_frames,
        s.frames_processed,
        s.frames_dropped,
        if e.kernel_frames == 0 && s.frames_processed > 0 {
            ": every pixel took the general path"
        } else {
            ""
        },
        e.windows,
        e.candidates,
        per_window(e.candidates),
        e.compactions,
        e.rescans,
        e.attentions,
        per_window(e.attentions),
    )
}
