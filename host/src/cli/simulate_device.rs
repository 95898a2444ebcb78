//! `brightpix simulate-device`: the firmware as a device on this machine.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};

use crate::sim_device::{
    catch_interrupts, interrupted, temp_dir, InProcessDevice, InProcessOptions, QemuCpu,
    QemuDevice, QemuOptions, SimLinkKind,
};

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LinkArg {
    /// A pseudo-terminal (/dev/pts/N): any serial client can open it.
    Pty,
    /// A Unix socket (port name unix:PATH for this tool).
    Unix,
}

/// The core of `--qemu`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum CpuArg {
    /// Cortex-M4F on mps2-an386 (the default build).
    M4,
    /// Cortex-M7 on mps2-an500, built with -C target-cpu=cortex-m7 (the STM32H743's code generation).
    M7,
}

#[derive(Args)]
#[command(
    about = "Run the firmware as a device on this machine and print its serial port, until Ctrl-C",
    after_help = "Examples:\n  brightpix simulate-device                 # the firmware's device loop in-process, on /dev/pts/N\n  brightpix simulate-device --qemu          # the real firmware ELF in qemu-system-arm (mps2-an386)\n  brightpix simulate-device --qemu --pixels-fifo   # pixels also through a FIFO (much faster than QEMU's UART)\n  brightpix simulate-device --qemu --cpu m7 # the Cortex-M7 build in mps2-an500\n  brightpix simulate-device --link unix --socket /tmp/bp.sock\n\n\
The first line on stdout is the port (/dev/pts/N or unix:PATH). Then, in another terminal:\n  brightpix status --port /dev/pts/N\n  brightpix stream --port /dev/pts/N --config examples/canary.toml --frames f.npy --verify\n\
or from Python: serial.Serial('/dev/pts/N', timeout=1) and the wire format of shared/PROTOCOL.md.\n\
The in-process device has the QEMU board's limits (6400 sub-apertures, maps of 256x256 pixels).\n\
--qemu needs qemu-system-arm; the ELF is built (cd firmware && cargo build --release\n\
-p brightpix-board-qemu) if missing. Its defmt log is QEMU's stdout, kept in a file (decoded\n\
with defmt-print if installed)."
)]
pub struct SimulateDeviceArgs {
    /// Run the real firmware ELF in qemu-system-arm instead of the firmware library in-process.
    #[arg(long)]
    qemu: bool,
    /// How clients reach the device.
    #[arg(long, value_enum, default_value_t = LinkArg::Pty)]
    link: LinkArg,
    /// Socket path for --link unix (default: in a temporary directory).
    #[arg(long, value_name = "PATH")]
    socket: Option<PathBuf>,
    /// Also read PixelRows frames from a FIFO (its path is printed); for `stream --pixels-fifo`.
    #[arg(long)]
    pixels_fifo: bool,
    /// Core for --qemu: m4 (mps2-an386) or m7 (mps2-an500; ELF in firmware/target/cortex-m7/).
    #[arg(long, value_enum, default_value_t = CpuArg::M4)]
    cpu: CpuArg,
    /// Firmware ELF for --qemu (default: firmware/target/thumbv7em-none-eabihf/release/brightpix-qemu).
    #[arg(long, value_name = "PATH")]
    elf: Option<PathBuf>,
    /// Keep QEMU's raw defmt log in this file.
    #[arg(long, value_name = "PATH")]
    log: Option<PathBuf>,
}

pub fn run(args: SimulateDeviceArgs) -> Result<()> {
    let dir = temp_dir("brightpix-sim")?;
    let link = match args.link {
        LinkArg::Pty => SimLinkKind::Pty,
        LinkArg::Unix => {
            SimLinkKind::Unix(args.socket.clone().unwrap_or_else(|| dir.join("uart.sock")))
        }
    };
    catch_interrupts();
    let result = if args.qemu {
        let mut device = QemuDevice::launch(QemuOptions {
            elf: args.elf.clone(),
            link,
            pixels_fifo: args.pixels_fifo,
            log: args.log.clone(),
            qemu: None,
            cpu: match args.cpu {
                CpuArg::M4 => QemuCpu::M4,
                CpuArg::M7 => QemuCpu::M7,
            },
        })?;
        device.release_fifo_in_background(Duration::from_secs(3600));
        println!("{}", device.port());
        eprintln!(
            "brightpix: firmware {} running in qemu-system-arm ({}); UART0 on {}",
            device.elf().display(),
            device.cpu().machine(),
            device.port()
        );
        if let Some(fifo) = device.pixels_fifo() {
            eprintln!(
                "brightpix: pixels FIFO: {} (stream --pixels-fifo {})",
                fifo.display(),
                fifo.display()
            );
        }
        eprintln!(
            "brightpix: defmt log (raw): {}; Ctrl-C stops",
            device.log_path().display()
        );
        let outcome = loop {
            std::thread::sleep(Duration::from_millis(100));
            if interrupted() {
                break Ok(());
            }
            if let Some(status) = device.exit_status() {
                break Err(anyhow::anyhow!(
                    "the firmware {} (log: {})",
                    QemuDevice::describe_exit(status),
                    device.log_path().display()
                ));
            }
        };
        if let Some(text) = device.decoded_log() {
            let tail: Vec<&str> = text.lines().rev().take(5).collect();
            for line in tail.into_iter().rev() {
                eprintln!("  firmware: {line}");
            }
        }
        device.stop();
        outcome
    } else {
        let fifo = args.pixels_fifo.then(|| dir.join("pixels.fifo"));
        let device = InProcessDevice::start(InProcessOptions {
            link,
            pixels_fifo: fifo,
            ..InProcessOptions::default()
        })?;
        println!("{}", device.port());
        eprintln!(
            "brightpix: the firmware's device loop (brightpix-firmware) runs in this process on {}",
            device.port()
        );
        if let Some(fifo) = device.pixels_fifo() {
            eprintln!(
                "brightpix: pixels FIFO: {} (stream --pixels-fifo {})",
                fifo.display(),
                fifo.display()
            );
        }
        eprintln!("brightpix: Ctrl-C stops");
        while !interrupted() {
            std::thread::sleep(Duration::from_millis(100));
        }
        device.stop();
        Ok(())
    };
    let _ = std::fs::remove_dir_all(&dir);
    eprintln!("brightpix: device stopped");
    match result {
        Ok(()) => Ok(()),
        Err(e) => bail!(e),
    }
}
