//! `brightpix view`: the live page (host/src/view) on one source: a
//! device's port, a simulated device, or a replay. `stream`, `capture` and
//! `rig stream` open the same page beside their work with `--view`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::sim_device::camera::QEMU_FPS;
use crate::sim_device::{
    catch_interrupts, interrupted, CameraOptions, CameraSpec, InProcessDevice, InProcessOptions,
    QemuDevice, QemuOptions,
};
use crate::view::{address, device, replay, simulated, Hub, Server};

#[derive(Args)]
#[command(
    about = "A live view in the browser (served on 127.0.0.1): slopes over the pupil, flux, N, the selected pixels, slopes over time and the device's health",
    after_help = "Examples:\n  brightpix view --simulate                                   # in-process device fed simulated CANARY frames\n  brightpix view --simulate --config my12bit.toml --drop-every 50   # ...with every 50th frame dropped by the device\n  brightpix view --simulate --camera sim:7                    # a simulated device's own camera (capture)\n  brightpix view --simulate --qemu                            # the firmware in QEMU with its camera\n  brightpix view --port /dev/ttyACM0 --config examples/canary.toml   # a board with its own camera\n  brightpix view --replay slopes.npy --config examples/canary.toml --frames frames.npy --rate 25\n  brightpix view --rig rig.toml --frames frames.npy                # a rig's boards, merged\n  brightpix stream ... --view        # beside a stream (also capture, rig stream)\n\n\
Open the printed address in a browser. The page is read-only, built into this program (no network\n\
needed) and samples the latest results: when it is slower than the data it skips display frames,\n\
never data frames. Another address than loopback needs --allow-remote. A device that disappears is\n\
reported on the page and here, and the view reconnects when it answers again."
)]
pub struct ViewArgs {
    /// TCP port to serve the page on (0: any free one), on 127.0.0.1.
    #[arg(long = "http-port", value_name = "N", default_value_t = address::DEFAULT_PORT)]
    http_port: u16,
    /// Address to serve on instead (ADDR:PORT); not loopback only with --allow-remote.
    #[arg(long, value_name = "ADDR:PORT", conflicts_with = "http_port")]
    listen: Option<String>,
    /// Serve on a non-loopback address: anyone who reaches this machine can watch.
    #[arg(long)]
    allow_remote: bool,
    /// A device with its own camera on this serial port (/dev/ttyACM0, /dev/pts/N, unix:PATH),
    /// as `--port` of the other commands.
    #[arg(long = "port", value_name = "PORT", conflicts_with_all = ["simulate", "replay", "rig"])]
    device: Option<String>,
    /// A rig file (brightpix rig plan): its boards fed --frames over and over, merged.
    #[arg(long, value_name = "rig.toml", conflicts_with_all = ["simulate", "replay", "config"], requires = "frames")]
    rig: Option<PathBuf>,
    /// With --rig: the boards' ports in the file's board order, instead of the file's.
    #[arg(long, value_name = "P1,P2,..", value_delimiter = ',', requires = "rig")]
    ports: Vec<String>,
    /// A simulated device: in-process, fed simulated frames by the host (or, with --camera or
    /// --qemu, with a camera of its own).
    #[arg(long, conflicts_with = "replay")]
    simulate: bool,
    /// With --simulate: the device's own simulated camera, sim or sim:SEED (captured from).
    #[arg(long, value_name = "sim[:SEED]", requires = "simulate")]
    camera: Option<CameraSpec>,
    /// With --simulate: the firmware ELF in qemu-system-arm with its own camera.
    #[arg(long, requires = "simulate")]
    qemu: bool,
    /// Firmware ELF for --qemu (default: firmware/target/thumbv7em-none-eabihf/release/brightpix-qemu,
    /// built if missing).
    #[arg(long, value_name = "PATH", requires = "qemu")]
    elf: Option<PathBuf>,
    /// Recorded results to play back: an .npy set or a results FITS file (docs/OUTPUTS.md).
    #[arg(long, value_name = "PATH")]
    replay: Option<PathBuf>,
    /// With --replay: the recorded frames (.npy or FITS cube), shown with their selected pixels;
    /// with --rig: the frames fed to the boards.
    #[arg(long, value_name = "PATH")]
    frames: Option<PathBuf>,
    /// FITS HDU of --frames.
    #[arg(long, value_name = "HDU", requires = "frames")]
    hdu: Option<String>,
    /// The configuration (default for --simulate: examples/canary.toml's CANARY model).
    #[arg(long, value_name = "C.toml")]
    config: Option<PathBuf>,
    /// With --port: do not upload --config; check that the device runs it.
    #[arg(long, requires = "device")]
    no_configure: bool,
    /// Frames per second of --simulate (fed by the host) or --replay; the camera's for --camera.
    #[arg(long, value_name = "HZ")]
    rate: Option<f64>,
    /// With --simulate (host-fed): every K-th frame carries a pixel above the camera's bit depth,
    /// so the device drops it (needs a camera of fewer than 16 bits).
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(1..), requires = "simulate")]
    drop_every: Option<u32>,
    /// Seed of the simulated frames (--simulate without --camera).
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub fn run(args: ViewArgs) -> Result<()> {
    let addr = match &args.listen {
        Some(text) => address::parse(text)?,
        None => address::parse(&args.http_port.to_string())?,
    };
    if args.device.is_none() && !args.simulate && args.replay.is_none() && args.rig.is_none() {
        bail!(
            "say what to view: --port PORT, --rig FILE, --simulate or --replay PATH (see --help)"
        );
    }
    if args.frames.is_some() && args.replay.is_none() && args.rig.is_none() {
        bail!("--frames goes with --replay or --rig");
    }
    if let Some(rig) = &args.rig {
        let frames = args.frames.as_deref().unwrap_or(rig);
        return serve(addr, args.allow_remote, |hub, stop| {
            super::rig::view_rig(rig, &args.ports, frames, args.hdu.as_deref(), hub, stop)
        });
    }
    let (config, config_name) = match &args.config {
        Some(path) => (ProcessingConfig::load(path)?, path.display().to_string()),
        None if args.simulate => (
            crate::sil::canary_config(),
            "examples/canary.toml (built in)".into(),
        ),
        None => bail!("--config is needed: the view draws the configuration's sub-apertures"),
    };
    // Everything that can be refused is, before the server starts.
    let mut replay_run = match &args.replay {
        Some(path) => {
            let recording = replay::load(path, &config, &config_name)?;
            let frames = match &args.frames {
                Some(f) => Some(replay::open_frames(f, args.hdu.as_deref(), &config)?),
                None => None,
            };
            Some(replay::Replay {
                recording,
                path: path.clone(),
                config: config.clone(),
                config_name: config_name.clone(),
                frames,
                rate: args.rate.unwrap_or(25.0),
            })
        }
        None => None,
    };
    serve(addr, args.allow_remote, |hub, stop| {
        if let Some(replay) = &mut replay_run {
            replay::run(replay, hub, stop)
        } else if let Some(port) = &args.device {
            let source = device::DeviceSource {
                port: port.clone(),
                config: config.clone(),
                config_name: config_name.clone(),
                configure: !args.no_configure,
                chunk: 100,
                sim_seed: None,
                label: format!("device at {port}"),
            };
            device::run(&source, hub, stop)
        } else if args.qemu || args.camera.is_some() {
            simulated_camera(&args, config.clone(), config_name.clone(), hub, stop)
        } else {
            let sim = simulated::Simulated {
                config: config.clone(),
                config_name: config_name.clone(),
                seed: args.seed,
                rate: args.rate.unwrap_or(100.0),
                drop_every: args.drop_every,
            };
            simulated::run(&sim, hub, stop)
        }
    })
}

/// Serves the page on `addr` while `work` feeds the hub, until Ctrl-C or
/// until `work` ends; an error is shown on the page too, briefly.
fn serve(
    addr: std::net::SocketAddr,
    allow_remote: bool,
    work: impl FnOnce(&std::sync::Arc<Hub>, &dyn Fn() -> bool) -> Result<()>,
) -> Result<()> {
    let listener = address::bind(addr, allow_remote)?;
    let hub = Hub::new();
    let server = Server::start(listener, hub.clone())?;
    // The address on stdout, first, for scripts (as simulate-device prints its port).
    println!("{}", server.url());
    eprintln!("brightpix: live view at {} (Ctrl-C stops)", server.url());
    catch_interrupts();
    let result = work(&hub, &interrupted);
    if let Err(e) = &result {
        hub.set_message(Some(format!("{e:#}")));
        std::thread::sleep(Duration::from_millis(300));
    }
    drop(server);
    result
}

/// `--simulate --camera` or `--qemu`: a simulated device with a camera of
/// its own, captured from as a board's would be.
fn simulated_camera(
    args: &ViewArgs,
    config: ProcessingConfig,
    config_name: String,
    hub: &std::sync::Arc<Hub>,
    stop: &dyn Fn() -> bool,
) -> Result<()> {
    if args.drop_every.is_some() {
        bail!(
            "--drop-every is for the host-fed simulation (--simulate without --camera or --qemu)"
        );
    }
    let spec = args.camera.unwrap_or(CameraSpec { seed: args.seed });
    let default_fps = if args.qemu { QEMU_FPS } else { 100 };
    let fps = match args.rate {
        Some(r) if r.is_finite() && r >= 1.0 => r.round() as u32,
        Some(r) => bail!("--rate {r}: must be at least 1 frame per second"),
        None => default_fps,
    };
    let camera = Some(CameraOptions::own(spec, fps));
    let mut qemu = None;
    let mut in_process = None;
    let port = if args.qemu {
        let device = QemuDevice::launch(QemuOptions {
            camera,
            elf: args.elf.clone(),
            ..QemuOptions::default()
        })?;
        let port = device.port().to_string();
        qemu = Some(device);
        port
    } else {
        let device = InProcessDevice::start(InProcessOptions {
            camera,
            ..InProcessOptions::default()
        })?;
        let port = device.port().to_string();
        in_process = Some(device);
        port
    };
    let source = device::DeviceSource {
        port: port.clone(),
        config,
        config_name,
        configure: true,
        // About two seconds of frames per capture: a capture restarts the
        // simulated camera at its frame 0.
        chunk: (2 * fps).max(10),
        sim_seed: Some(spec.seed),
        label: format!(
            "simulated device ({}, {port}) with its camera {spec} at {fps} frames/s",
            if args.qemu {
                "firmware in QEMU"
            } else {
                "in-process"
            }
        ),
    };
    let outcome = device::run(&source, hub, stop);
    if let Some(q) = qemu {
        q.stop();
    }
    drop(in_process);
    outcome
}

/// `--view [ADDR:PORT]` of `stream`, `capture` and `rig stream`: the live
/// page beside their work.
#[derive(Args, Clone, Debug, Default)]
pub(super) struct ViewFlag {
    /// Open the live view in the browser beside this work (default 127.0.0.1:8093; PORT or
    /// ADDR:PORT to choose). It samples the results and never slows them.
    #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1, default_missing_value = "8093")]
    view: Option<String>,
    /// With --view: serve on a non-loopback address (anyone who reaches this machine can watch).
    #[arg(long = "view-allow-remote", requires = "view")]
    allow_remote: bool,
}

impl ViewFlag {
    /// The view, started, if asked for.
    pub fn start(&self) -> Result<Option<crate::view::Attached>> {
        let Some(spec) = self.view.as_deref() else {
            return Ok(None);
        };
        let addr = address::parse(spec)?;
        if !addr.ip().is_loopback() && !self.allow_remote {
            bail!(
                "refusing to serve the view on {addr}: it is not a loopback address, so anyone who can reach this machine could watch; add --view-allow-remote to serve it there anyway, or use 127.0.0.1"
            );
        }
        crate::view::attach(spec, self.allow_remote).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct WithView {
        #[command(flatten)]
        live: ViewFlag,
        #[arg(long)]
        out: Option<String>,
    }

    fn parse(args: &[&str]) -> Result<ViewFlag, clap::Error> {
        WithView::try_parse_from(std::iter::once("x").chain(args.iter().copied())).map(|w| w.live)
    }

    #[test]
    fn view_flag_takes_an_optional_address() {
        assert_eq!(parse(&[]).unwrap().view, None);
        // Bare --view, even before another option: the default port on loopback.
        assert_eq!(
            parse(&["--view", "--out", "s.npy"])
                .unwrap()
                .view
                .as_deref(),
            Some("8093")
        );
        assert_eq!(
            parse(&["--view", "127.0.0.1:9000"])
                .unwrap()
                .view
                .as_deref(),
            Some("127.0.0.1:9000")
        );
        // Another address without the flag is refused when the view starts.
        let remote = parse(&["--view", "0.0.0.0:0"]).unwrap();
        let error = remote.start().err().expect("refused").to_string();
        assert!(error.contains("--view-allow-remote"), "{error}");
        assert!(
            parse(&["--view-allow-remote"]).is_err(),
            "the flag needs --view"
        );
    }
}
