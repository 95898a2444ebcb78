//! `brightpix paper sensitivity`: how much the model's own choices move the
//! conclusions. Each choice is a group of probe cases run under every
//! variant of the choice; for each probe the best N and R of subtract-next
//! and threshold, R(all) with negative pixels kept and clipped at 0, and the
//! change from the group's first (default) variant.
//!
//! - **Spot and seeing**: the paper's stated 0.7" spot realised at an
//!   effective wavelength (834 nm, the default); everything at 640 nm (a
//!   0.54" spot); the 640 nm seeing with an optics blur up to the 0.7" spot
//!   ([`SpotModel`]). Probes: the defaults, 100 photons, 5 and 10 e-, d/r0 =
//!   2 and 10 (NGS, x and y pooled).
//! - **Sodium beacon width** 0.28" (the Rayleigh value the paper quotes), 1,
//!   2, 3"; **profile reading** (the 3.5 and 2 km "half-widths" as HWHM, as
//!   Gaussian sigma, as FWHM); **elongation direction** (along x, at 45
//!   degrees). Probes: s = 8 and 14 km, R parallel to the elongation.
//! - **The all-pixel reference** with and without clipping: a column of
//!   every probe.

use std::fmt::Write as _;
use std::time::Instant;

use anyhow::Result;

use super::{
    best_row, frames_for, run_figure, Case, Figure, FigureResult, RunOptions, CLIPPED_ALL,
};
use crate::evaluation::{Axis, Method};
use crate::simulator::{SimulationParams, Source, SpotModel, HWHM_PER_SIGMA};

/// One variant of a choice: a label and how it changes a probe's params.
struct Variant {
    label: &'static str,
    apply: fn(&mut SimulationParams),
}

/// A choice of the model: its variants and the probes they are run on.
struct Group {
    name: &'static str,
    variants: Vec<Variant>,
    probes: Vec<(&'static str, SimulationParams)>,
    axis: Axis,
    frames: usize,
}

fn set_spot(p: &mut SimulationParams, f: impl Fn(&mut f64, &mut [f64; 2], &mut f64)) {
    if let Source::Sodium {
        spot_fwhm_arcsec,
        half_widths_m,
        elongation_angle_deg,
        ..
    } = &mut p.source
    {
        f(spot_fwhm_arcsec, half_widths_m, elongation_angle_deg);
    }
}

fn groups() -> Vec<Group> {
    let c = SimulationParams::canary;
    let ngs_probes = vec![
        ("defaults", c()),
        (
            "100 photons",
            SimulationParams {
                photons: 100.0,
                ..c()
            },
        ),
        (
            "5 e-",
            SimulationParams {
                read_noise_e: 5.0,
                ..c()
            },
        ),
        (
            "10 e-",
            SimulationParams {
                read_noise_e: 10.0,
                ..c()
            },
        ),
        ("d/r0 = 2", SimulationParams { r0_m: 0.3, ..c() }),
        ("d/r0 = 10", SimulationParams { r0_m: 0.06, ..c() }),
    ];
    let sodium_probes = vec![
        ("s = 8 km", SimulationParams::sodium(8e3)),
        ("s = 14 km", SimulationParams::sodium(14e3)),
    ];
    vec![
        Group {
            name: "spot and seeing",
            variants: vec![
                Variant {
                    label: "0.7\" spot at an effective 834 nm (default)",
                    apply: |_| {},
                },
                Variant {
                    label: "everything at 640 nm (0.54\" spot)",
                    apply: |p| p.spot_model = SpotModel::WfsWavelength,
                },
                Variant {
                    label: "640 nm seeing, blurred to the 0.7\" spot",
                    apply: |p| p.spot_model = SpotModel::WfsWavelengthBlurred,
                },
            ],
            probes: ngs_probes,
            axis: Axis::Both,
            frames: 8_000,
        },
        Group {
            name: "sodium beacon width",
            variants: vec![
                Variant {
                    label: "0.28\" (default)",
                    apply: |_| {},
                },
                Variant {
                    label: "1\"",
                    apply: |p| set_spot(p, |w, _, _| *w = 1.0),
                },
                Variant {
                    label: "2\"",
                    apply: |p| set_spot(p, |w, _, _| *w = 2.0),
                },
                Variant {
                    label: "3\"",
                    apply: |p| set_spot(p, |w, _, _| *w = 3.0),
                },
            ],
            probes: sodium_probes.clone(),
            axis: Axis::Along,
            frames: 4_000,
        },
        Group {
            name: "sodium profile reading",
            variants: vec![
                Variant {
                    label: "half-widths as HWHM (default)",
                    apply: |_| {},
                },
                Variant {
                    label: "half-widths as Gaussian sigma",
                    apply: |p| {
                        set_spot(p, |_, h, _| h.iter_mut().for_each(|v| *v *= HWHM_PER_SIGMA))
                    },
                },
                Variant {
                    label: "half-widths as FWHM",
                    apply: |p| set_spot(p, |_, h, _| h.iter_mut().for_each(|v| *v *= 0.5)),
                },
            ],
            probes: sodium_probes.clone(),
            axis: Axis::Along,
            frames: 4_000,
        },
        Group {
            name: "sodium elongation direction",
            variants: vec![
                Variant {
                    label: "along x (default)",
                    apply: |_| {},
                },
                Variant {
                    label: "at 45 degrees",
                    apply: |p| set_spot(p, |_, _, a| *a = 45.0),
                },
            ],
            probes: sodium_probes,
            axis: Axis::Along,
            frames: 4_000,
        },
    ]
}

/// Best N and R of `m` in case `ci`.
fn best(result: &FigureResult, ci: usize, m: Method, axis: Axis) -> (usize, f64, bool) {
    best_row(result, ci, m, axis).map_or((0, f64::NAN, false), |r| {
        (r.score.pixels, r.score.r(axis).value, r.score.all_pixels)
    })
}

fn all_r(result: &FigureResult, ci: usize, m: Method, axis: Axis) -> f64 {
    result
        .rows
        .iter()
        .find(|r| r.case == ci && r.score.method == m && r.score.all_pixels)
        .map_or(f64::NAN, |r| r.score.r(axis).value)
}

/// Runs every group and writes `sensitivity.md` and `sensitivity.csv`.
pub fn run_sensitivity(opts: &RunOptions) -> Result<String> {
    let started = Instant::now();
    let sn = Method::SUBTRACT_NEXT;
    let th = Method::THRESHOLD;
    let mut md = String::new();
    let mut csv = String::from(
        "group,variant,probe,frames,sn_best_N,sn_R_best,sn_R_20,th_best_N,th_R_best,R_all,R_all_clipped,th_minus_sn_best,se\n",
    );
    let _ = writeln!(
        md,
        "## Sensitivity to the model's choices (`sensitivity`)\n\nPer probe: subtract-next and threshold at their best N (R in pixels), R(all pixels) with negative pixels kept and clipped at 0, and the paired difference threshold minus subtract-next at their best N (negative: threshold better). In brackets: the change from the group's default.\n"
    );
    for g in groups() {
        let mut cases = Vec::new();
        for v in &g.variants {
            for (probe, params) in &g.probes {
                let mut p = params.clone();
                (v.apply)(&mut p);
                cases.push(Case {
                    label: format!("{} | {probe}", v.label),
                    seed_offset: 0,
                    value: 0.0,
                    params: p,
                });
            }
        }
        let fig = Figure {
            name: "sensitivity",
            title: g.name.to_string(),
            parameter: "variant",
            cases,
            methods: vec![sn, th],
            axis: g.axis,
            frames: g.frames,
            panels: Vec::new(),
            best_vs_value: None,
        };
        let frames = frames_for(g.frames, opts);
        let result = run_figure(fig, opts)?;
        let _ = writeln!(
            md,
            "### {} ({} frames per case, R {})\n",
            g.name,
            frames,
            g.axis.name()
        );
        let _ = writeln!(
            md,
            "| variant | probe | subtract-next best N, R | R(N = 20) | threshold best N, R | threshold - subtract-next, paired | R(all) | R(all, clipped) |"
        );
        let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
        let np = g.probes.len();
        for (vi, v) in g.variants.iter().enumerate() {
            for (pi, (probe, _)) in g.probes.iter().enumerate() {
                let ci = vi * np + pi;
                let (sn_n, sn_r, sn_all) = best(&result, ci, sn, g.axis);
                let (th_n, th_r, _) = best(&result, ci, th, g.axis);
                let (d_n, d_r, _) = best(&result, pi, sn, g.axis);
                let r20 = result
                    .rows
                    .iter()
                    .find(|r| r.case == ci && r.score.method == sn && r.score.pixels == 20)
                    .map_or(f64::NAN, |r| r.score.r(g.axis).value);
                let diff = match (
                    best_row(&result, ci, th, g.axis),
                    best_row(&result, ci, sn, g.axis),
                ) {
                    (Some(a), Some(b)) => a.score.paired_difference(&b.score, g.axis),
                    _ => crate::evaluation::Estimate {
                        value: f64::NAN,
                        se: f64::NAN,
                    },
                };
                let (ra, rc) = (
                    all_r(&result, ci, sn, g.axis),
                    all_r(&result, ci, CLIPPED_ALL, g.axis),
                );
                let delta = if vi == 0 {
                    String::new()
                } else {
                    format!(
                        " ({:+}, {:+.0}%)",
                        sn_n as i64 - d_n as i64,
                        100.0 * (sn_r / d_r - 1.0)
                    )
                };
                let _ = writeln!(
                    md,
                    "| {} | {} | {}{}, {:.4}{} | {:.4} | {}, {:.4} | {:+.4} ± {:.4} | {:.3} | {:.3} |",
                    v.label,
                    probe,
                    sn_n,
                    if sn_all { " (all)" } else { "" },
                    sn_r,
                    delta,
                    r20,
                    th_n,
                    th_r,
                    diff.value,
                    diff.se,
                    ra,
                    rc
                );
                let _ = writeln!(
                    csv,
                    "\"{}\",\"{}\",\"{}\",{frames},{sn_n},{sn_r:.6},{r20:.6},{th_n},{th_r:.6},{ra:.6},{rc:.6},{:.6},{:.6}",
                    g.name,
                    v.label.replace('"', "\"\""),
                    probe,
                    diff.value,
                    diff.se
                );
            }
        }
        md.push('\n');
    }
    let _ = writeln!(md, "Run time {:.0} s.", started.elapsed().as_secs_f64());
    std::fs::write(opts.out.join("sensitivity.md"), &md)?;
    std::fs::write(opts.out.join("sensitivity.csv"), csv)?;
    Ok(md)
}
