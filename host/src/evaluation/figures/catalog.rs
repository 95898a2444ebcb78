//! The figures of the paper's §3: their cases, methods and plots.

use super::{Case, Figure, Panel};
use crate::evaluation::{Axis, Method};
use crate::simulator::{SimulationParams, Source};

const MEAN4: Method = Method::subtract_mean(4);
const FILTER4: Method = Method::SUBTRACT_NEXT.with_level_filter(4);

fn canary() -> SimulationParams {
    SimulationParams::canary()
}

fn case(label: impl Into<String>, value: f64, params: SimulationParams) -> Case {
    Case {
        label: label.into(),
        seed_offset: 0,
        value,
        params,
    }
}

fn panel(title: impl Into<String>, methods: &[Method]) -> Panel {
    Panel {
        suffix: "",
        title: title.into(),
        cases: None,
        methods: methods.to_vec(),
    }
}

fn snr(params: &SimulationParams) -> f64 {
    let n = params.photons;
    let npix = (params.pixels_per_subaperture as f64).powi(2);
    n / (n + params.read_noise_e.powi(2) * npix).sqrt()
}

/// The figure called `name` (not `linearity`, see [`run_linearity`]).
pub fn figure(name: &str) -> Option<Figure> {
    const NGS_FRAMES: usize = 20_000;
    let sn = Method::SUBTRACT_NEXT;
    let th = Method::THRESHOLD;
    let f = match name {
        "spot-size" => Figure {
            name: "spot-size",
            title: "Fig. 3c: spot size (Airy diameter)".into(),
            parameter: "airy_diameter_arcsec",
            cases: [0.35, 0.7, 1.4, 2.1]
                .iter()
                .map(|&a| {
                    case(
                        format!("Airy {a}\""),
                        a,
                        SimulationParams {
                            airy_diameter_arcsec: a,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![th, sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 3c: spot size, with (circles) and without (triangles, dashed) subtraction",
                &[th, sn],
            )],
            best_vs_value: None,
        },
        "signal" => Figure {
            name: "signal",
            title: "Fig. 4: signal level".into(),
            parameter: "photons",
            cases: [100.0, 150.0, 200.0, 500.0, 1e6]
                .iter()
                .map(|&n| {
                    // 1e6 photons would saturate a 16-bit camera at 1 e-/count
                    // (peak pixel ~1e5 e-): 16 e-/count keeps every pixel
                    // below 2^16 (the read noise is then below one count,
                    // irrelevant at this flux).
                    let gain = if n > 2e5 { 16.0 } else { 1.0 };
                    let p = SimulationParams {
                        photons: n,
                        gain_e_per_count: gain,
                        ..canary()
                    };
                    case(format!("{n} ph (SNR {:.1})", snr(&p)), n, p)
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel("Fig. 4: signal level (subtract-next)", &[sn])],
            best_vs_value: None,
        },
        "background-error" => Figure {
            name: "background-error",
            title: "Fig. 5: background subtraction error".into(),
            parameter: "background_error_counts",
            cases: [0.0, 1.0, 2.0, 10.0]
                .iter()
                .map(|&b| {
                    case(
                        format!("bg error {b}"),
                        b,
                        SimulationParams {
                            background_error: b,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![th, sn, MEAN4],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 5: background error, with (circles) and without (triangles, dashed) subtraction",
                &[th, sn],
            )],
            best_vs_value: Some("background error (counts)"),
        },
        "read-noise" => {
            // 6, 8, 9 and 12 e- bracket the crossover of the two rules.
            let values = [0.1, 1.0, 2.0, 3.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 12.0];
            let cases: Vec<Case> = values
                .iter()
                .map(|&r| {
                    let p = SimulationParams {
                        read_noise_e: r,
                        ..canary()
                    };
                    case(format!("{r} e- (SNR {:.1})", snr(&p)), r, p)
                })
                .collect();
            Figure {
                name: "read-noise",
                title: "Fig. 6: read noise".into(),
                parameter: "read_noise_e",
                cases,
                methods: vec![th, sn, MEAN4, FILTER4],
                axis: Axis::Both,
                frames: NGS_FRAMES,
                panels: vec![
                    Panel {
                        suffix: "",
                        title: "Fig. 6: read noise, with subtraction (subtract-next)".into(),
                        cases: None,
                        methods: vec![sn],
                    },
                    Panel {
                        suffix: "threshold",
                        title: "Fig. 6: read noise, without subtraction (threshold)".into(),
                        cases: None,
                        methods: vec![th],
                    },
                    Panel {
                        suffix: "ext",
                        title: "Read noise 5 and 10 e-: the paper's suggested fixes (subtract-mean M=4, level filter)".into(),
                        cases: Some(vec![4, 9]),
                        methods: vec![th, sn, MEAN4, FILTER4],
                    },
                ],
                best_vs_value: Some("read noise (e- rms)"),
            }
        }
        "outer-scale" => Figure {
            name: "outer-scale",
            title: "Fig. 7a: outer scale".into(),
            parameter: "outer_scale_m",
            cases: [5.0, 10.0, 30.0, 100.0, f64::INFINITY]
                .iter()
                .map(|&l0| {
                    case(
                        if l0.is_finite() {
                            format!("L0 {l0} m")
                        } else {
                            "L0 inf (Kolmogorov)".into()
                        },
                        l0,
                        SimulationParams {
                            outer_scale_m: l0,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel("Fig. 7a: outer scale (subtract-next)", &[sn])],
            best_vs_value: None,
        },
        "seeing" => Figure {
            name: "seeing",
            title: "Fig. 7b: seeing (d/r0, d = 0.6 m)".into(),
            parameter: "d_over_r0",
            cases: [2.0, 3.0, 4.0, 4.8, 6.0, 8.0, 10.0]
                .iter()
                .map(|&dr| {
                    let r0 = 0.6 / dr;
                    case(
                        format!("d/r0 {dr} (r0 {:.1} cm)", r0 * 100.0),
                        dr,
                        SimulationParams { r0_m: r0, ..canary() },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel("Fig. 7b: seeing (subtract-next)", &[sn])],
            best_vs_value: None,
        },
        "rayleigh" => Figure {
            name: "rayleigh",
            title: "Fig. 8b: Rayleigh LGS, parallel to the elongation".into(),
            parameter: "gate_depth_m",
            cases: [0.0, 500.0, 1000.0, 1500.0]
                .iter()
                .map(|&g| {
                    case(
                        format!("gate {g} m"),
                        g,
                        SimulationParams::canary_rayleigh(g),
                    )
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::Along,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 8b: Rayleigh LGS, 20 km, edge sub-aperture (R parallel to elongation, subtract-next)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "sodium" => Figure {
            name: "sodium",
            title: "Fig. 9b: sodium LGS, parallel to the elongation".into(),
            parameter: "separation_m",
            cases: [0.0, 8e3, 14e3]
                .iter()
                .map(|&s| {
                    case(
                        format!("s = {} km", s / 1e3),
                        s,
                        SimulationParams::sodium(s),
                    )
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::Along,
            frames: 8_000,
            panels: vec![panel(
                "Fig. 9b: sodium LGS, 21 m from launch, 24\" FOV, 1000 ph, 0.28\" beacon (R parallel)",
                &[sn, th],
            )],
            best_vs_value: None,
        },
        "subaperture-size" => Figure {
            name: "subaperture-size",
            title: "Fig. 10: pixels per sub-aperture at a fixed 0.22\"/pixel".into(),
            parameter: "pixels_across",
            cases: [6u32, 8, 10, 12, 16, 20, 24]
                .iter()
                .map(|&n| {
                    case(
                        format!("{n}x{n} ({:.2}\" FOV)", n as f64 * 0.22),
                        n as f64,
                        SimulationParams {
                            pixels_per_subaperture: n,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 10: sub-aperture size at 0.22\"/pixel (subtract-next)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "subaperture-size-fov" => Figure {
            name: "subaperture-size-fov",
            title: "Fig. 10 (variant): pixels per sub-aperture at a fixed 3.52\" field".into(),
            parameter: "pixels_across",
            cases: [6u32, 8, 10, 12, 16, 20, 24]
                .iter()
                .map(|&n| {
                    let scale = 3.52 / n as f64;
                    case(
                        format!("{n}x{n} ({scale:.3}\"/px)"),
                        n as f64,
                        SimulationParams {
                            pixels_per_subaperture: n,
                            pixel_scale_arcsec: scale,
                            ..canary()
                        },
                    )
                })
                .collect(),
            methods: vec![sn],
            axis: Axis::Both,
            frames: NGS_FRAMES,
            panels: vec![panel(
                "Fig. 10 variant: sub-aperture size at a fixed 3.52\" field (R in each case's pixels)",
                &[sn],
            )],
            best_vs_value: None,
        },
        "sodium-paper" => Figure {
            name: "sodium-paper",
            title: format!(
                "Fig. 9b at the paper's optimum: sodium LGS with a {SODIUM_PAPER_SPOT}\" beacon, parallel to the elongation"
            ),
            parameter: "separation_m",
            cases: [0.0, 8e3, 14e3]
                .iter()
                .map(|&s| {
                    case(
                        format!("s = {} km", s / 1e3),
                        s,
                        sodium_paper(s),
                    )
                })
                .collect(),
            methods: vec![sn, th],
            axis: Axis::Along,
            frames: 8_000,
            panels: vec![panel(
                format!("Fig. 9b with a {SODIUM_PAPER_SPOT}\" beacon (the paper's >100 pixels), R parallel"),
                &[sn, th],
            )],
            best_vs_value: None,
        },
        "rules" => {
            let methods = vec![
                th,
                sn,
                Method::SUBTRACT_NEXT_DISTINCT,
                Method::subtract_mean(2),
                MEAN4,
                Method::subtract_mean(8),
                FILTER4,
                MEAN4.with_level_filter(4),
            ];
            // Four seeds: the rules differ by about two standard errors of
            // one seed's frames.
            let cases = (0..4)
                .map(|k| Case {
                    seed_offset: k,
                    ..case(format!("defaults, seed +{k}"), 0.0, canary())
                })
                .collect();
            Figure {
                name: "rules",
                title: "All rules at the paper's defaults (4 seeds)".into(),
                parameter: "defaults",
                cases,
                methods: methods.clone(),
                axis: Axis::Both,
                frames: NGS_FRAMES,
                panels: vec![Panel {
                    cases: Some(vec![0]),
                    ..panel(
                        "All brightpix rules at the paper's defaults (200 ph, 2 e-; first seed)",
                        &methods,
                    )
                }],
                best_vs_value: None,
            }
        }
        _ => return None,
    };
    Some(f)
}

/// The unelongated sodium beacon FWHM (arcsec) at which the paper's Fig. 9b
/// optimum (more than 100 pixels) appears; see PAPER.md.
pub const SODIUM_PAPER_SPOT: f64 = 3.0;

/// The paper's sodium case with a [`SODIUM_PAPER_SPOT`] beacon.
pub fn sodium_paper(separation_m: f64) -> SimulationParams {
    let mut p = SimulationParams::sodium(separation_m);
    if let Source::Sodium {
        spot_fwhm_arcsec, ..
    } = &mut p.source
    {
        *spot_fwhm_arcsec = SODIUM_PAPER_SPOT;
    }
    p
}
