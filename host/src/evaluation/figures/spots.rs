//! The paper's spot-image panels: its Fig. 1 (selection on one spot), 3a/3b
//! (NGS spots of four Airy sizes, without and with turbulence), 8a
//! (Rayleigh elongations) and 9a (sodium profiles), at the paper's
//! settings, from the simulator's noiseless images (and one noisy frame for
//! Fig. 1, through the engine's calibration and selection rules).

use std::fmt::Write as _;

use anyhow::{anyhow, Result};

use super::catalog::sodium_paper;
use super::RunOptions;
use crate::evaluation::plot::{write_images, ImagePanel};
use crate::simulator::{SimulationParams, Simulator};

fn noiseless(params: SimulationParams, turbulence: bool, seed: u64) -> Result<ImagePanel> {
    let sim = Simulator::new(SimulationParams {
        turbulence,
        ..params
    })
    .map_err(|e| anyhow!("{e}"))?;
    let f = sim.subaperture_frame(0, seed);
    Ok(ImagePanel {
        title: String::new(),
        size: f.size,
        values: f.noiseless,
    })
}

fn titled(mut p: ImagePanel, title: impl Into<String>) -> ImagePanel {
    p.title = title.into();
    p
}

/// Fig. 1: one default frame, calibrated (background subtracted), then the
/// 20 brightest pixels kept, then the 21st subtracted (negative values 0).
fn selection_panels(seed: u64) -> Result<Vec<ImagePanel>> {
    let sim = Simulator::new(SimulationParams::canary()).map_err(|e| anyhow!("{e}"))?;
    let f = sim.subaperture_frame(0, seed);
    let bg = sim.calibration_background();
    let cal: Vec<f64> = f.raw.iter().map(|&v| v as f64 - bg).collect();
    let mut sorted = cal.clone();
    sorted.sort_by(|a, b| b.total_cmp(a));
    let (v20, v21) = (sorted[19], sorted[20]);
    Ok(vec![
        ImagePanel {
            title: "no selection".into(),
            size: f.size,
            values: cal.iter().map(|&v| v.max(0.0)).collect(),
        },
        ImagePanel {
            title: "20 brightest".into(),
            size: f.size,
            values: cal
                .iter()
                .map(|&v| if v >= v20 { v } else { 0.0 })
                .collect(),
        },
        ImagePanel {
            title: "20 brightest - 21st".into(),
            size: f.size,
            values: cal.iter().map(|&v| (v - v21).max(0.0)).collect(),
        },
    ])
}

/// Writes the spot panels (SVG and PNG) and returns a short summary.
pub fn run_spots(opts: &RunOptions) -> Result<String> {
    let seed = opts.seed;
    let mut written = Vec::new();
    written.extend(write_images(
        &opts.out.join("spots-selection"),
        "Fig. 1: one default frame; N = 20; N = 20 - 21st",
        &selection_panels(seed)?,
        3,
        160,
    )?);
    let mut ngs = Vec::new();
    for turbulence in [false, true] {
        for a in [0.35, 0.7, 1.4, 2.1] {
            let p = SimulationParams {
                airy_diameter_arcsec: a,
                ..SimulationParams::canary()
            };
            ngs.push(titled(
                noiseless(p, turbulence, seed)?,
                format!("{a}\"{}", if turbulence { ", seeing" } else { "" }),
            ));
        }
    }
    written.extend(write_images(
        &opts.out.join("spots-ngs"),
        "Fig. 3a/b: NGS spots, Airy 0.35-2.1\" (top: no turbulence; bottom: d/r0 = 4.8)",
        &ngs,
        4,
        140,
    )?);
    let mut rayleigh = Vec::new();
    for g in [0.0, 500.0, 1000.0, 1500.0] {
        rayleigh.push(titled(
            noiseless(SimulationParams::canary_rayleigh(g), false, seed)?,
            format!("gate {g} m"),
        ));
    }
    written.extend(write_images(
        &opts.out.join("spots-rayleigh"),
        "Fig. 8a: Rayleigh LGS, 20 km, 1.8 m from launch, no turbulence",
        &rayleigh,
        4,
        140,
    )?);
    let mut sodium = Vec::new();
    for s in [0.0, 8e3, 14e3] {
        sodium.push(titled(
            noiseless(SimulationParams::sodium(s), false, seed)?,
            format!("s = {} km, 0.28\"", s / 1e3),
        ));
    }
    for s in [0.0, 8e3, 14e3] {
        sodium.push(titled(
            noiseless(sodium_paper(s), false, seed)?,
            format!(
                "s = {} km, {}\"",
                s / 1e3,
                super::catalog::SODIUM_PAPER_SPOT
            ),
        ));
    }
    for angle in [30.0, 45.0, 90.0] {
        let mut p = SimulationParams::sodium(8e3);
        p.source = p.source.with_elongation_angle(angle);
        sodium.push(titled(
            noiseless(p, false, seed)?,
            format!("s = 8 km, at {angle} deg"),
        ));
    }
    written.extend(write_images(
        &opts.out.join("spots-sodium"),
        "Fig. 9a: sodium LGS, 21 m from launch, 1.5\"/px",
        &sodium,
        3,
        150,
    )?);
    let mut s = String::from("### Spot images (`spots`)\n\n");
    for p in &written {
        let name = p.file_name().map_or(p.display().to_string(), |n| {
            n.to_string_lossy().into_owned()
        });
        let _ = writeln!(s, "- {name}");
    }
    std::fs::write(opts.out.join("spots.md"), &s)?;
    Ok(s)
}
