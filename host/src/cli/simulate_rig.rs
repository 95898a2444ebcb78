//! `brightpix simulate-device --camera sim:SEED --boards N`: N simulated
//! boards on one simulated camera (`SharedCamera`: one timeline of frames,
//! one sync line), for `rig capture` from the command line.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};

use crate::sim_device::{
    catch_interrupts, interrupted, CameraSpec, InProcessDevice, InProcessOptions, QemuCpu,
    QemuDevice, QemuOptions, SharedCamera,
};

/// What `--boards` starts.
pub struct Boards {
    pub count: usize,
    pub spec: CameraSpec,
    pub fps: u32,
    /// Board K's start delay in frames (the test knob).
    pub delays: Vec<u32>,
    /// In QEMU on this core (and ELF), else in-process.
    pub qemu: Option<(QemuCpu, Option<PathBuf>)>,
}

enum Board {
    InProcess(InProcessDevice),
    Qemu(QemuDevice),
}

impl Board {
    fn port(&self) -> &str {
        match self {
            Board::InProcess(d) => d.port(),
            Board::Qemu(d) => d.port(),
        }
    }
}

/// Starts the boards, prints their ports (one a line) and runs until
/// Ctrl-C or a QEMU board exits.
pub fn run(boards: Boards) -> Result<()> {
    catch_interrupts();
    let camera = Arc::new(
        SharedCamera::new(boards.spec, boards.fps)
            .with_sync_line()
            .with_start_delays(boards.delays.clone()),
    );
    let mut devices = Vec::with_capacity(boards.count);
    for b in 0..boards.count {
        let options = camera.board(b);
        devices.push(match &boards.qemu {
            Some((cpu, elf)) => Board::Qemu(
                QemuDevice::launch(QemuOptions {
                    elf: elf.clone(),
                    cpu: *cpu,
                    camera: Some(options),
                    ..QemuOptions::default()
                })
                .with_context(|| format!("starting board {b} in QEMU"))?,
            ),
            None => Board::InProcess(
                InProcessDevice::start(InProcessOptions {
                    camera: Some(options),
                    ..InProcessOptions::default()
                })
                .with_context(|| format!("starting board {b}"))?,
            ),
        });
    }
    for d in &devices {
        println!("{}", d.port());
    }
    let ports: Vec<&str> = devices.iter().map(Board::port).collect();
    eprintln!(
        "brightpix: {} boards ({}) on one simulated camera ({}, {} frames/s) with a sync line{}",
        boards.count,
        if boards.qemu.is_some() {
            "firmware ELFs in qemu-system-arm"
        } else {
            "in-process"
        },
        boards.spec,
        boards.fps,
        if boards.delays.iter().any(|&d| d > 0) {
            format!("; start delays {:?} frames", boards.delays)
        } else {
            String::new()
        }
    );
    eprintln!(
        "brightpix: brightpix rig capture --rig rig.toml --ports {} --count 100 --verify --seed {}   ([sync] in rig.toml: the boards start together); Ctrl-C stops",
        ports.join(","),
        boards.spec.seed
    );
    let outcome = loop {
        std::thread::sleep(Duration::from_millis(100));
        if interrupted() {
            break Ok(());
        }
        if let Some((b, status)) = devices.iter_mut().enumerate().find_map(|(b, d)| match d {
            Board::Qemu(q) => q.exit_status().map(|s| (b, s)),
            Board::InProcess(_) => None,
        }) {
            break Err(anyhow::anyhow!(
                "board {b}: the firmware {}",
                QemuDevice::describe_exit(status)
            ));
        }
    };
    drop(devices);
    eprintln!("brightpix: boards stopped");
    outcome
}
