//! `brightpix simulate-device`: the firmware as a device on this machine.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};

use crate::sim_device::camera::{IN_PROCESS_FPS, QEMU_FPS};
use crate::sim_device::{
    catch_interrupts, interrupted, temp_dir, CameraOptions, CameraSpec, InProcessDevice,
    InProcessOptions, QemuCpu, QemuDevice, QemuOptions, SimLinkKind,
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
    after_help = "Examples:\n  brightpix simulate-device                 # the firmware's device loop in-process, on /dev/pts/N\n  brightpix simulate-device --qemu          # the real firmware ELF in qemu-system-arm (mps2-an386)\n  brightpix simulate-device --qemu --pixels-fifo   # pixels also through a FIFO (much faster than QEMU's UART)\n  brightpix simulate-device --qemu --cpu m7 # the Cortex-M7 build in mps2-an500\n  brightpix simulate-device --qemu --icount 6   # instructions counted: for `brightpix bench --port`\n  brightpix simulate-device --camera sim:7  # its own camera: simulated Shack-Hartmann frames, seed 7\n  brightpix simulate-device --qemu --camera sim --camera-fps 5\n  brightpix simulate-device --link unix --socket /tmp/bp.sock\n  \
brightpix simulate-device --camera sim:7 --boards 3 --start-delays 0,3  # a rig's boards on one camera\n\n\
The first line on stdout is the port (/dev/pts/N or unix:PATH). Then, in another terminal:\n  brightpix status --port /dev/pts/N\n  brightpix stream --port /dev/pts/N --config examples/canary.toml --frames f.npy --verify\n\
or from Python: serial.Serial('/dev/pts/N', timeout=1) and the wire format of shared/PROTOCOL.md.\n\
With --camera the device has a camera of its own (for `capture`): the paper's CANARY NGS spots,\n\
16x16 pixels each, tiled over the configured camera, made on the host from SEED and written into\n\
the firmware's camera ring at --camera-fps (the device's frame clock; a device that falls behind\n\
drops frames). Each capture starts at frame 0, so `capture --verify --seed SEED` checks it\n\
(with --boards, the boards share one free-running camera and sync line instead):\n  \
brightpix capture --port /dev/pts/N --config examples/canary.toml --count 100 --verify --seed 7\n\
Without --camera, Capture is answered NoCamera (pixels come from the host: `stream`).\n\
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
    /// Give the device its own simulated camera: sim or sim:SEED (seed of the turbulence and noise,
    /// default 1).
    #[arg(long, value_name = "sim[:SEED]", conflicts_with = "pixels_fifo")]
    camera: Option<CameraSpec>,
    /// Frame rate of --camera, frames per second (default 100 in-process, 10 under --qemu, an emulated
    /// core whose results leave on an emulated UART, 0.1-0.3 MB/s).
    #[arg(long, value_name = "HZ", requires = "camera", value_parser = clap::value_parser!(u32).range(1..=100_000))]
    camera_fps: Option<u32>,
    /// Keep QEMU's raw defmt log in this file.
    #[arg(long, value_name = "PATH")]
    log: Option<PathBuf>,
    /// With --qemu: count instructions (-icount shift=SHIFT; 6 is the QEMU bench's), so that
    /// `brightpix bench --port` gets instruction counts from the board's bench mode.
    #[arg(long, value_name = "SHIFT", requires = "qemu", value_parser = clap::value_parser!(u32).range(0..=10))]
    icount: Option<u32>,
    /// With --camera: N boards on that one camera (a rig): one timeline of frames, so camera frame
    /// k is the same pixels on every board and each begins on the frame after its own start, and
    /// one sync line (`rig capture` with [sync] in rig.toml). Prints the N ports, one a line.
    #[arg(long, value_name = "N", requires = "camera", value_parser = super::at_least_one,
          conflicts_with_all = ["pixels_fifo", "socket", "log", "icount"])]
    boards: Option<usize>,
    /// With --boards: board K's start comes D_K frame periods late (USB latency, as a test knob:
    /// without the sync line `rig capture --verify` then finds the merge misaligned).
    #[arg(
        long,
        value_name = "D0,D1,..",
        value_delimiter = ',',
        requires = "boards"
    )]
    start_delays: Vec<u32>,
}

pub fn run(args: SimulateDeviceArgs) -> Result<()> {
    if let (Some(boards), Some(spec)) = (args.boards, args.camera) {
        if args.link != LinkArg::Pty {
            bail!("--boards: each board is on a pseudo-terminal (--link pty)");
        }
        if args.start_delays.len() > boards {
            bail!(
                "--start-delays: {} delays for {boards} boards",
                args.start_delays.len()
            );
        }
        let cpu = match args.cpu {
            CpuArg::M4 => QemuCpu::M4,
            CpuArg::M7 => QemuCpu::M7,
        };
        let board = super::simulate_rig::Boards {
            count: boards,
            spec,
            fps: args
                .camera_fps
                .unwrap_or(if args.qemu { QEMU_FPS } else { IN_PROCESS_FPS }),
            delays: args.start_delays.clone(),
            qemu: args.qemu.then_some((cpu, args.elf.clone())),
        };
        return super::simulate_rig::run(board);
    }
    let dir = temp_dir("brightpix-sim")?;
    let link = match args.link {
        LinkArg::Pty => SimLinkKind::Pty,
        LinkArg::Unix => {
            SimLinkKind::Unix(args.socket.clone().unwrap_or_else(|| dir.join("uart.sock")))
        }
    };
    catch_interrupts();
    let camera = args.camera.map(|spec| {
        let fps = args
            .camera_fps
            .unwrap_or(if args.qemu { QEMU_FPS } else { IN_PROCESS_FPS });
        CameraOptions::own(spec, fps)
    });
    let describe_camera = |camera: &CameraOptions| {
        eprintln!(
            "brightpix: camera: simulated ({}), {} frames/s; `capture --verify --seed {}` checks it",
            camera.spec, camera.fps, camera.spec.seed
        );
    };
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
            camera: camera.clone(),
            board_args: Vec::new(),
            icount: args.icount,
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
        if let Some(camera) = &camera {
            describe_camera(camera);
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
            camera: camera.clone(),
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
        if let Some(camera) = &camera {
            describe_camera(camera);
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
