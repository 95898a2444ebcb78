//! Where things are in the pupil: the telescope's annulus, the
//! sub-apertures of the wavefront sensors' windows, the science grid on
//! which the residual is measured, and the deformable mirror's actuators.
//!
//! Pupil coordinates are metres from the telescope axis, `x` along the
//! camera's columns and `y` along its rows; a window at grid position
//! `(column, row)` of a `columns x rows` grid looks at the sub-aperture
//! centred on `((column - (columns-1)/2) d, (row - (rows-1)/2) d)`, `d =
//! D / max(columns, rows)`.

use anyhow::{bail, Result};

use crate::config_file::ProcessingConfig;

/// The telescope's pupil: an annulus.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pupil {
    pub diameter_m: f64,
    /// Central obscuration diameter (m).
    pub obscuration_m: f64,
}

impl Pupil {
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let r = x.hypot(y);
        r <= self.diameter_m / 2.0 && r >= self.obscuration_m / 2.0
    }

    /// The fraction of the square of side `d` centred on `c` inside the
    /// annulus.
    pub fn lit_fraction(&self, c: [f64; 2], d: f64) -> f64 {
        crate::evaluation::tune::lit_fraction(c, d, self.diameter_m, self.obscuration_m)
    }
}

/// One wavefront-sensor sub-aperture (one window of the configuration).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Subaperture {
    /// Centre in the pupil (m).
    pub centre_m: [f64; 2],
    /// Fraction of its square inside the pupil.
    pub lit: f64,
}

/// The sub-apertures of a configuration's windows, in window order, and
/// their pitch `d` (m).
#[derive(Clone, Debug, PartialEq)]
pub struct Lenslets {
    pub pitch_m: f64,
    /// Sub-apertures across the pupil (the grid's larger side).
    pub across: usize,
    pub subapertures: Vec<Subaperture>,
}

impl Lenslets {
    /// Where each window of `config` looks: by its grid position when the
    /// windows come from a regular grid (`[subapertures.grid]`, `d = D /
    /// max(columns, rows)`), else as `brightpix tune` places them (window
    /// centres over the window pitch, about the windows' bounding box, `d =
    /// D / across`). Every window must see some light.
    pub fn from_config(
        config: &ProcessingConfig,
        pupil: &Pupil,
        across: Option<usize>,
    ) -> Result<Lenslets> {
        let (across, positions): (usize, Vec<([f64; 2], String)>) = match config.grid.as_ref() {
            Some(layout) => {
                let g = layout.grid;
                let across = across.unwrap_or(g.columns.max(g.rows) as usize);
                let d = pupil.diameter_m / across as f64;
                let positions = layout
                    .positions()
                    .map(|[c, r]| {
                        (
                            [
                                (c as f64 - (g.columns as f64 - 1.0) / 2.0) * d,
                                (r as f64 - (g.rows as f64 - 1.0) / 2.0) * d,
                            ],
                            format!(" (grid column {c}, row {r}: skip it in the grid)"),
                        )
                    })
                    .collect();
                (across, positions)
            }
            None => {
                let Some(across) = across else {
                    bail!(
                        "the configuration's windows are a list, not a grid: give the number of sub-apertures across the pupil"
                    );
                };
                let d = pupil.diameter_m / across as f64;
                let positions = crate::evaluation::tune::pupil_positions(config, d)
                    .into_iter()
                    .map(|c| (c, " (leave it out of the configuration)".to_string()))
                    .collect();
                (across, positions)
            }
        };
        if across == 0 {
            bail!("at least one sub-aperture across the pupil is needed");
        }
        let d = pupil.diameter_m / across as f64;
        let mut subapertures = Vec::with_capacity(positions.len());
        for (k, (centre_m, hint)) in positions.into_iter().enumerate() {
            let lit = pupil.lit_fraction(centre_m, d);
            if lit < 0.05 {
                bail!(
                    "window {k} looks at a sub-aperture {:.0}% lit by the {} m pupil with a {} m obscuration{hint}",
                    100.0 * lit,
                    pupil.diameter_m,
                    pupil.obscuration_m
                );
            }
            subapertures.push(Subaperture { centre_m, lit });
        }
        Ok(Lenslets {
            pitch_m: d,
            across,
            subapertures,
        })
    }
}

/// The points on which the science path's phase is measured: a square
/// lattice of spacing `spacing_m` over the pupil, the points inside the
/// annulus, with equal weights.
#[derive(Clone, Debug, PartialEq)]
pub struct ScienceGrid {
    pub spacing_m: f64,
    pub points: Vec<[f64; 2]>,
}

impl ScienceGrid {
    pub fn new(pupil: &Pupil, spacing_m: f64) -> ScienceGrid {
        let n = (pupil.diameter_m / spacing_m).ceil() as i64 + 1;
        let mut points = Vec::new();
        for j in -n..=n {
            for i in -n..=n {
                let (x, y) = ((i as f64 + 0.5) * spacing_m, (j as f64 + 0.5) * spacing_m);
                if pupil.contains(x, y) {
                    points.push([x, y]);
                }
            }
        }
        ScienceGrid { spacing_m, points }
    }
}

/// A deformable mirror: actuators on a square lattice, Gaussian influence
/// functions.
#[derive(Clone, Debug, PartialEq)]
pub struct DeformableMirror {
    pub pitch_m: f64,
    /// The influence function at the neighbouring actuator, `exp(ln(c)
    /// r^2 / pitch^2)`.
    pub coupling: f64,
    pub actuators: Vec<[f64; 2]>,
}

impl DeformableMirror {
    /// `across x across` actuators of pitch `pitch_m` centred on the axis
    /// (Fried geometry when `across` is one more than the sub-apertures
    /// across and the pitch is theirs), keeping those within `D/2 + pitch/2`
    /// of the axis (CANARY's 8x8 DM: 52 actuators).
    pub fn new(pupil: &Pupil, across: usize, pitch_m: f64, coupling: f64) -> Result<Self> {
        if across < 2 {
            bail!("the DM needs at least 2 actuators across, got {across}");
        }
        if !(coupling > 0.0 && coupling < 1.0) {
            bail!("the DM's coupling must be in (0, 1), got {coupling}");
        }
        let c = (across as f64 - 1.0) / 2.0;
        let limit = pupil.diameter_m / 2.0 + pitch_m / 2.0;
        let mut actuators = Vec::new();
        for j in 0..across {
            for i in 0..across {
                let (x, y) = ((i as f64 - c) * pitch_m, (j as f64 - c) * pitch_m);
                if x.hypot(y) <= limit + 1e-9 {
                    actuators.push([x, y]);
                }
            }
        }
        Ok(DeformableMirror {
            pitch_m,
            coupling,
            actuators,
        })
    }

    /// Influence of actuator `a` at `p` (per unit command).
    pub fn influence(&self, a: usize, p: [f64; 2]) -> f64 {
        let q = self.actuators[a];
        let r2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
        (self.coupling.ln() * r2 / (self.pitch_m * self.pitch_m)).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn canary_geometry() {
        let pupil = Pupil {
            diameter_m: 4.2,
            obscuration_m: 1.0,
        };
        let dm = DeformableMirror::new(&pupil, 8, 0.6, 0.2).unwrap();
        assert_eq!(dm.actuators.len(), 52);
        assert!(
            (dm.influence(0, [dm.actuators[0][0] + 0.6, dm.actuators[0][1]]) - 0.2).abs() < 1e-12
        );
        let sci = ScienceGrid::new(&pupil, 0.075);
        let area = sci.points.len() as f64 * 0.075 * 0.075;
        let exact = std::f64::consts::PI / 4.0 * (4.2f64.powi(2) - 1.0);
        assert!((area / exact - 1.0).abs() < 0.02, "{area} {exact}");
        let config = ProcessingConfig::from_toml_str(
            include_str!("../../../examples/canary-vignetted.toml"),
            std::path::Path::new("canary-vignetted.toml"),
        )
        .unwrap();
        let lenslets = Lenslets::from_config(&config, &pupil, None).unwrap();
        assert_eq!(lenslets.subapertures.len(), 36);
        assert!((lenslets.pitch_m - 0.6).abs() < 1e-12);
        // The full 7x7 grid has a dark window at the centre.
        let full = ProcessingConfig::from_toml_str(
            include_str!("../../../examples/canary.toml"),
            std::path::Path::new("canary.toml"),
        )
        .unwrap();
        let e = Lenslets::from_config(&full, &pupil, None).unwrap_err();
        assert!(e.to_string().contains("skip it"), "{e}");
    }
}
