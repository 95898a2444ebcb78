//! `brightpix demo --boards K`: a rig of simulated devices on one
//! simulated camera, streamed (`rig stream`: the host numbers the frames),
//! merged and verified.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};

use super::print_rig;
use super::stream::run_and_report;
use crate::link::{Client, PixelSink};
use crate::rig::{self, BoardKind, Rig};
use crate::sim_device::{InProcessDevice, QemuCpu, QemuDevice, QemuOptions};

/// A simulated board of `demo --boards`.
enum SimBoard {
    InProcess(InProcessDevice),
    Qemu(QemuDevice),
}

/// `brightpix demo --boards K [--qemu]`: K simulated devices (in-process,
/// or the firmware in QEMU alternating Cortex-M4 and M7) on one simulated
/// CANARY camera, planned, streamed, merged and verified.
pub(in crate::cli) fn demo(
    boards: usize,
    frames: &[Vec<u16>],
    qemu: bool,
    elf: Option<PathBuf>,
) -> Result<()> {
    let whole = crate::sil::canary_config();
    let kind = if qemu {
        BoardKind::QemuM4
    } else {
        BoardKind::Stm32h743
    };
    let model = kind.cost_model();
    let plan = rig::plan(&whole, boards, kind, &model)?;
    let mut rig = Rig::from_plan(whole, kind, None, &plan).map_err(|e| anyhow::anyhow!("{e}"))?;
    let started = Instant::now();
    let mut devices = Vec::new();
    for k in 0..boards {
        devices.push(if qemu {
            let cpu = if k % 2 == 0 { QemuCpu::M4 } else { QemuCpu::M7 };
            let device = QemuDevice::launch(QemuOptions {
                elf: elf.clone().filter(|_| cpu == QemuCpu::M4),
                pixels_fifo: true,
                cpu,
                ..QemuOptions::default()
            })?;
            device.release_fifo(Duration::from_secs(10))?;
            SimBoard::Qemu(device)
        } else {
            SimBoard::InProcess(
                InProcessDevice::start_pty().context("starting an in-process device")?,
            )
        });
    }
    let mut clients = Vec::new();
    for (k, device) in devices.iter().enumerate() {
        let (port, fifo) = match device {
            SimBoard::InProcess(d) => (d.port().to_string(), None),
            SimBoard::Qemu(d) => (d.port().to_string(), d.pixels_fifo().map(Path::to_path_buf)),
        };
        rig.boards[k].port = Some(port.clone());
        let mut client = Client::open(&port)?;
        if let Some(fifo) = fifo {
            client.set_pixel_sink(PixelSink::Fifo(fifo));
        }
        clients.push(client);
    }
    rig::configure(&rig, &mut clients)?;
    println!(
        "brightpix demo: {} {} on one simulated CANARY camera (112x112, 49 sub-apertures), started and configured in {:.2} s",
        boards,
        if qemu {
            "firmware ELFs in qemu-system-arm (Cortex-M4 and M7 alternating), pixels through FIFOs"
        } else {
            "in-process devices"
        },
        started.elapsed().as_secs_f64()
    );
    print_rig(&rig, &rig.cost_model(), None);
    let read = |first: usize, count: usize| Ok(frames[first..first + count].to_vec());
    let outcome = run_and_report(&rig, &mut clients, frames.len(), read, true, 10, None)?;
    outcome.verdict(true, frames.len())?;
    println!(
        "PASS: all {} merged frames bit-identical to the whole-camera reference",
        frames.len()
    );
    drop(devices);
    Ok(())
}
