use super::*;
use crate::simulator::atmosphere::{Atmosphere, Layer};

/// One ground layer, one NGS on axis, science on axis, no delay, no
/// central obscuration (the 7x7 grid without its 4 dark corners: 45
/// sub-apertures). Shared with `variant_tests`.
pub(super) fn single_layer_on_axis() -> Scenario {
    let mut config = canary_config();
    let layout = config.grid.clone().expect("a grid");
    let fresh = ProcessingConfig::from_grid(
        config.camera,
        layout.grid,
        &[[0, 0], [6, 0], [0, 6], [6, 6]],
    );
    config.windows = fresh.windows;
    config.grid = fresh.grid;
    Scenario {
        config,
        obscuration_m: 0.0,
        atmosphere: Atmosphere {
            layers: vec![Layer {
                altitude_m: 0.0,
                fraction: 1.0,
                wind_speed_m_s: 10.0,
                wind_direction_deg: 0.0,
            }],
            ..Atmosphere::canary()
        },
        guide_stars: vec![GuideStar::ON_AXIS],
        delay_frames: 0.0,
        ..Scenario::canary()
    }
}

/// The DM's best fit of `phi` (points x frames), piston free, by its own
/// least squares (SVD of the influence functions and a piston column):
/// the fitting error, computed independently of [`Science`].
fn independent_fitting_error(e2e: &EndToEnd, phi: &DMatrix<f64>) -> f64 {
    let np = e2e.grid.points.len();
    let na = e2e.dm.actuators.len();
    let mut h = DMatrix::<f64>::zeros(np, na + 1);
    for (p, &pt) in e2e.grid.points.iter().enumerate() {
        for a in 0..na {
            h[(p, a)] = e2e.dm.influence(a, pt);
        }
        h[(p, na)] = 1.0;
    }
    let svd = h.clone().svd(true, true);
    let coef = svd.solve(phi, 1e-9).expect("SVD solve");
    let res = phi - h * coef;
    res.norm_squared() / res.len() as f64
}

#[test]
fn noiseless_single_layer_on_axis_is_corrected_to_the_fitting_error() {
    let e2e = EndToEnd::new(single_layer_on_axis(), 6).unwrap();
    assert_eq!(e2e.lenslets.subapertures.len(), 45);
    let m = e2e.tomography.reconstructor(1e-4);
    let (mut residual, mut residual_low, mut fitting, mut uncorrected) = (0.0, 0.0, 0.0, 0.0);
    let episodes = 6;
    for e in 0..episodes {
        let data = e2e.simulate_episode(5, e, e * 6);
        assert_eq!(data.phi_now, data.phi_later, "no delay");
        // Noise-free slopes: the noiseless spots' centres of gravity, and
        // the G-tilts of the turbulence a Shack-Hartmann does not alias.
        let mean_square = |s: &DMatrix<f64>| {
            let r = &data.phi_now - &e2e.science.h * (&m * s);
            r.norm_squared() / r.len() as f64
        };
        residual += mean_square(&data.s_cog);
        residual_low += mean_square(&data.s_low);
        fitting += independent_fitting_error(&e2e, &data.phi_now);
        uncorrected += data.phi_now.norm_squared() / data.phi_now.len() as f64;
    }
    let nm = |v: f64| (v / episodes as f64).sqrt() * 1e9;
    let (residual, residual_low, fitting, uncorrected) =
        (nm(residual), nm(residual_low), nm(fitting), nm(uncorrected));
    let numbers = format!(
        "residual {residual:.1} nm (unaliased slopes {residual_low:.1} nm), fitting {fitting:.1} nm, uncorrected {uncorrected:.1} nm"
    );
    eprintln!("{numbers}");
    // The fitting error of a 0.6 m pitch at r0 = 12.5 cm: 0.2-0.35
    // (pitch/r0)^(5/3) rad^2 at 500 nm for continuous face-sheet DMs
    // (somewhat less with a 30 m outer scale).
    let k = 2.0 * std::f64::consts::PI / 500e-9;
    let coefficient = (fitting * 1e-9 * k).powi(2) / (0.6f64 / 0.125).powf(5.0 / 3.0);
    assert!(
        (0.15..0.4).contains(&coefficient),
        "fitting coefficient {coefficient:.3}: {numbers}"
    );
    // Near perfect: the correction removes all but a few percent of the
    // phase variance; it cannot beat the DM's fit; with unaliased slopes it
    // stays near it, and the Shack-Hartmann's aliasing (about a third of
    // the fitting variance for this geometry) adds the rest.
    assert!(residual < 0.2 * uncorrected, "{numbers}");
    assert!(
        residual_low > fitting && residual_low < 1.15 * fitting,
        "{numbers}"
    );
    assert!(
        residual > residual_low && residual < 1.3 * fitting,
        "{numbers}"
    );
}

#[test]
fn residual_falls_as_photons_rise() {
    let options = RunOptions {
        seed: 3,
        episodes: 2,
        frames_per_episode: 4,
        calibration_episodes: 1,
        methods: vec![Method::SUBTRACT_NEXT],
        pixels: vec![20, 256],
    };
    let wfe: Vec<(f64, f64)> = [50.0, 200.0, 2000.0]
        .iter()
        .map(|&photons| {
            let mut s = Scenario::canary();
            s.wfs.photons = photons;
            let e2e = EndToEnd::new(s, options.frames_per_episode).unwrap();
            let r = e2e.run(&options, &|_| {}).unwrap();
            let n20 = r.find(Method::SUBTRACT_NEXT, 20).unwrap();
            let all = r.find(Method::SUBTRACT_NEXT, 256).unwrap();
            (
                r.wfe_nm(all, Reconstruction::Fixed).value,
                r.wfe_nm(n20, Reconstruction::Fixed).value,
            )
        })
        .collect();
    for w in wfe.windows(2) {
        assert!(w[1].0 < w[0].0 && w[1].1 < w[0].1, "{wfe:?}");
    }
    // And selection helps most where the signal is faint.
    assert!(wfe[0].1 < wfe[0].0, "{wfe:?}");
}

#[test]
fn bad_scenarios_are_refused_before_any_work() {
    let mut s = Scenario::canary();
    s.guide_stars.clear();
    assert!(EndToEnd::new(s, 4)
        .err()
        .unwrap()
        .to_string()
        .contains("guide star"));
    let mut s = Scenario::canary();
    s.delay_frames = -1.0;
    assert!(EndToEnd::new(s, 4)
        .err()
        .unwrap()
        .to_string()
        .contains("delay"));
    let mut s = Scenario::canary();
    s.config = ProcessingConfig::from_toml_str(
        include_str!("../../../examples/canary.toml"),
        std::path::Path::new("canary.toml"),
    )
    .unwrap();
    assert!(EndToEnd::new(s, 4)
        .err()
        .unwrap()
        .to_string()
        .contains("lit"));
    assert!(parse_layers("0:0.6:7.5").is_err());
    assert!(parse_stars("40,").is_err());
    let layers = parse_layers("0:6:7.5:0, 5000:4:15:90").unwrap();
    assert!((layers[0].fraction - 0.6).abs() < 1e-12);
}

/// The reconstructor's geometry and the atmosphere's agree on where an
/// off-axis star looks: with one layer at 5 km and one NGS 20" off axis at a
/// skew angle, the reconstructor built for the star's true direction
/// corrects the science path far better than ones built for its mirror
/// images or its transpose (a sign or axis slip in either would swap them).
#[test]
fn off_axis_star_directions_agree_between_atmosphere_and_reconstructor() {
    let mut s = single_layer_on_axis();
    s.atmosphere.layers[0].altitude_m = 5000.0;
    s.guide_stars = vec![GuideStar {
        radius_arcsec: 20.0,
        angle_deg: 63.0,
    }];
    let e2e = EndToEnd::new(s, 4).unwrap();
    let d = e2e.scenario.guide_stars[0].direction_rad();
    let layers = [(5000.0, 1.0)];
    let reconstructor = |dir: [f64; 2]| {
        Tomography::new(
            &ModelGeometry {
                pupil: &e2e.pupil,
                lenslets: &e2e.lenslets,
                wfs_directions: &[dir],
                science_direction: [0.0, 0.0],
                layers: &layers,
                r0_m: e2e.scenario.atmosphere.r0_m,
                r0_wavelength_m: e2e.scenario.atmosphere.r0_wavelength_m,
                outer_scale_m: e2e.scenario.atmosphere.outer_scale_m,
                pixel_scale_arcsec: e2e.scenario.wfs.pixel_scale_arcsec,
                dm: &e2e.dm,
                science: &e2e.grid,
                nodes_per_subaperture: reconstructor::NODES_PER_SUBAPERTURE,
            },
            &e2e.science,
        )
        .unwrap()
        .reconstructor(1e-4)
    };
    let directions = [d, [-d[0], d[1]], [d[0], -d[1]], [d[1], d[0]]];
    let mut residual = [0.0; 4];
    for e in 0..4 {
        let data = e2e.simulate_episode(2, e, e * 4);
        for (r, &dir) in residual.iter_mut().zip(&directions) {
            let res = &data.phi_now - &e2e.science.h * (reconstructor(dir) * &data.s_cog);
            *r += res.norm_squared() / res.len() as f64;
        }
    }
    let nm = residual.map(|v| (v / 4.0).sqrt() * 1e9);
    for wrong in &nm[1..] {
        assert!(
            nm[0] < 0.7 * wrong,
            "true direction {:.0} nm, others {nm:?}",
            nm[0]
        );
    }
}
