use super::*;
use std::f64::consts::PI;

fn no_turbulence(mut p: SimulationParams) -> SimulationParams {
    p.turbulence = false;
    p
}

fn cog(img: &[f64], n: usize) -> [f64; 2] {
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for y in 0..n {
        for x in 0..n {
            let v = img[y * n + x];
            sx += v * x as f64;
            sy += v * y as f64;
            s += v;
        }
    }
    let c = (n as f64 - 1.0) / 2.0;
    [sx / s - c, sy / s - c]
}

/// Second central moments (x, y) of an image, pixels^2.
fn moments(img: &[f64], n: usize) -> [f64; 2] {
    let [cx, cy] = cog(img, n);
    let c = (n as f64 - 1.0) / 2.0;
    let (mut vx, mut vy, mut s) = (0.0, 0.0, 0.0);
    for y in 0..n {
        for x in 0..n {
            let v = img[y * n + x];
            vx += v * (x as f64 - c - cx).powi(2);
            vy += v * (y as f64 - c - cy).powi(2);
            s += v;
        }
    }
    [vx / s, vy / s]
}

#[test]
fn defaults_match_the_paper_and_toml_overrides() {
    let p: SimulationParams = toml::from_str("").unwrap();
    assert_eq!(p, SimulationParams::default());
    assert_eq!(p.subaperture_diameter_m(), 0.6);
    // r0 = 12.5 cm at 500 nm is d/r0 = 4.8 (paper §2.3)
    assert!((p.subaperture_diameter_m() / p.r0_m - 4.8).abs() < 1e-12);
    let p: SimulationParams = toml::from_str(
        "photons = 150.0\nouter_scale_m = inf\n[source]\nkind = \"rayleigh\"\n\
         altitude_m = 20000.0\ngate_depth_m = 1000.0\nlaunch_offset_m = 1.8\n\
         spot_fwhm_arcsec = 0.28\n[sampling]\noversampling = 3\n",
    )
    .unwrap();
    assert_eq!(p.photons, 150.0);
    assert!(p.outer_scale_m.is_infinite());
    assert_eq!(p.source, Source::rayleigh(1000.0));
    assert_eq!(p.sampling.oversampling, Some(3));
    assert!(toml::from_str::<SimulationParams>("photon = 1.0").is_err());
    let sim = Simulator::new(SimulationParams::default()).unwrap();
    // SNR of about 6 (paper eq. 2)
    assert!((sim.paper_snr() - 5.72).abs() < 0.01);
    let g = sim.geometry();
    assert_eq!(g.oversampling, 2);
    assert_eq!(g.image_fft_size, 64);
    assert!(g.pupil_samples >= 24.0 && g.pupil_samples <= 48.0);
    // lambda_eff = 0.7" * 0.6 m / 2.4393
    assert!((g.effective_wavelength_m - 834.5e-9).abs() < 1e-9);
    assert!(Simulator::new(SimulationParams {
        photons: -1.0,
        ..SimulationParams::default()
    })
    .is_err());
}

#[test]
fn reproducible_and_independent_of_threads() {
    let sim = Simulator::new(SimulationParams::default()).unwrap();
    let a = sim.subaperture_frame(3, 7);
    let b = sim.subaperture_frame(3, 7);
    assert_eq!(a, b);
    let c = sim.subaperture_frame(4, 7);
    assert_ne!(a.raw, c.raw);
    assert_ne!(a.true_slope, c.true_slope);
    let d = sim.subaperture_frame(3, 8);
    assert_ne!(a.true_slope, d.true_slope);
    let par = sim.frames(7, 2, 6);
    assert_eq!(par[1], a);
    for (i, f) in par.iter().enumerate() {
        assert_eq!(*f, sim.subaperture_frame(2 + i as u64, 7));
    }
    // Same turbulence when only the noise parameters change.
    let sim2 = Simulator::new(SimulationParams {
        read_noise_e: 5.0,
        background_error: 2.0,
        ..SimulationParams::default()
    })
    .unwrap();
    let e = sim2.subaperture_frame(3, 7);
    assert_eq!(e.noiseless, a.noiseless);
    assert_ne!(e.raw, a.raw);
}

#[test]
fn airy_first_minimum_has_the_requested_diameter() {
    for airy in [0.35, 0.7, 1.4, 2.1] {
        let sim = Simulator::new(no_turbulence(SimulationParams {
            airy_diameter_arcsec: airy,
            ..SimulationParams::default()
        }))
        .unwrap();
        let g = sim.geometry();
        let ns = g.pupil_array;
        // The PSF at any angle: |sum A exp(-2 pi i theta x / (M delta))|^2.
        let psf = |theta: f64| {
            let mut s = Complex::new(0.0, 0.0);
            for y in 0..ns {
                for x in 0..ns {
                    let ph = -2.0 * PI * theta * x as f64
                        / (g.psf_fft_size as f64 * g.fine_sample_arcsec);
                    s += Complex::new(ph.cos(), ph.sin()) * sim.pupil[y * ns + x];
                }
            }
            s.norm_sqr()
        };
        let peak = psf(0.0);
        let n = 400;
        let (mut best, mut at) = (f64::INFINITY, 0.0);
        for i in 0..=n {
            let r = airy / 2.0 * (0.8 + 0.4 * i as f64 / n as f64);
            let v = psf(r);
            if v < best {
                best = v;
                at = r;
            }
        }
        assert!(
            (2.0 * at / airy - 1.0).abs() < 0.01,
            "airy {airy}: first minimum diameter {}",
            2.0 * at
        );
        assert!(best / peak < 1e-3, "airy {airy}: minimum {}", best / peak);
    }
}

#[test]
fn tilt_ramp_moves_the_noiseless_centroid_proportionally() {
    let sim = Simulator::new(no_turbulence(SimulationParams::default())).unwrap();
    let zero = sim.subaperture_frame_with_tilt(0, 1, [0.0, 0.0]);
    // A centred diffraction spot is symmetric about the sub-aperture centre.
    assert!(zero.true_slope[0].abs() < 1e-9 && zero.true_slope[1].abs() < 1e-9);
    let n = 16;
    for y in 0..n {
        for x in 0..n {
            let v = zero.noiseless[y * n + x];
            assert!((v - zero.noiseless[(n - 1 - y) * n + (n - 1 - x)]).abs() < 1e-9);
            assert!((v - zero.noiseless[x * n + y]).abs() < 1e-9);
        }
    }
    let tilts: Vec<[f64; 2]> = (-12..=12)
        .map(|i| [i as f64 * 0.25, -0.5 * i as f64 * 0.25])
        .collect();
    let frames = sim.frames_with_tilts(1, 0, &tilts);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (t, f) in tilts.iter().zip(&frames) {
        assert!((f.phase_slope[0] - t[0]).abs() < 1e-9);
        assert!((f.phase_slope[1] - t[1]).abs() < 1e-9);
        sxx += t[0] * t[0];
        sxy += t[0] * f.true_slope[0];
    }
    let gain = sxy / sxx;
    // Slightly below 1: the Airy wings are truncated by the 16-pixel field.
    assert!(gain > 0.9 && gain < 1.0, "gain {gain}");
    for (t, f) in tilts.iter().zip(&frames) {
        assert!(
            (f.true_slope[0] - gain * t[0]).abs() < 0.03,
            "{t:?} {:?}",
            f.true_slope
        );
        let gy = f.true_slope[1] / t[1];
        assert!(
            t[1] == 0.0 || (gy - gain).abs() < 0.03,
            "{t:?} {:?}",
            f.true_slope
        );
    }
    // Odd-sized sub-apertures are centred too.
    let odd = Simulator::new(no_turbulence(SimulationParams {
        pixels_per_subaperture: 9,
        ..SimulationParams::default()
    }))
    .unwrap();
    let f = odd.subaperture_frame(0, 1);
    assert!(f.true_slope[0].abs() < 1e-9 && f.true_slope[1].abs() < 1e-9);
    assert!(f.noiseless[4 * 9 + 4] > f.noiseless[4 * 9 + 3]);
    // Sub-pixel shifts are exact: a quarter-pixel tilt moves a big-field
    // spot's centroid by a quarter pixel.
    let big = Simulator::new(no_turbulence(SimulationParams {
        pixels_per_subaperture: 64,
        airy_diameter_arcsec: 2.1,
        ..SimulationParams::default()
    }))
    .unwrap();
    let f = big.subaperture_frame_with_tilt(0, 1, [0.25, 0.0]);
    assert!((f.true_slope[0] - 0.25).abs() < 0.01, "{:?}", f.true_slope);
}

#[test]
fn pixel_integration_is_independent_of_oversampling() {
    let base = no_turbulence(SimulationParams::default());
    let a = Simulator::new(base.clone()).unwrap();
    let mut p6 = base;
    p6.sampling.oversampling = Some(6);
    let b = Simulator::new(p6).unwrap();
    let fa = a.subaperture_frame_with_tilt(0, 0, [0.3, -0.2]);
    let fb = b.subaperture_frame_with_tilt(0, 0, [0.3, -0.2]);
    let peak = fa.noiseless.iter().cloned().fold(0.0, f64::max);
    for (x, y) in fa.noiseless.iter().zip(&fb.noiseless) {
        assert!((x - y).abs() < 2e-3 * peak, "{x} {y}");
    }
}

#[test]
fn photon_counts_and_noise() {
    let p = SimulationParams::default();
    let sim = Simulator::new(p.clone()).unwrap();
    let frames = sim.frames(11, 0, 300);
    let npix = 256.0;
    let mut sums = Vec::new();
    for f in &frames {
        assert!((f.noiseless.iter().sum::<f64>() - p.photons).abs() < 1e-9);
        assert_eq!(f.saturated, 0);
        let s: f64 = f
            .raw
            .iter()
            .map(|&v| v as f64 - sim.calibration_background())
            .sum();
        sums.push(s);
    }
    let n = sums.len() as f64;
    let mean = sums.iter().sum::<f64>() / n;
    let var = sums.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (n - 1.0);
    // photon + read noise + rounding (1/12 per pixel)
    let expect_var = p.photons + npix * (p.read_noise_e.powi(2) + 1.0 / 12.0);
    let se = (expect_var / n).sqrt();
    assert!((mean - p.photons).abs() < 4.0 * se, "mean {mean}");
    assert!(
        (var / expect_var - 1.0).abs() < 0.25,
        "var {var} vs {expect_var}"
    );

    // Background error stays in the calibrated image; integer offsets are
    // exact (common random numbers).
    let e = Simulator::new(SimulationParams {
        background_error: 2.0,
        ..p.clone()
    })
    .unwrap();
    let fe = e.subaperture_frame(0, 11);
    for (a, b) in fe.raw.iter().zip(&frames[0].raw) {
        assert_eq!(*a, b + 2);
    }

    // Read noise alone: per-pixel variance.
    let rn = Simulator::new(SimulationParams {
        photons: 1e-6,
        read_noise_e: 3.0,
        ..p.clone()
    })
    .unwrap();
    let f = rn.frames(5, 0, 20);
    let vals: Vec<f64> = f
        .iter()
        .flat_map(|f| f.raw.iter().map(|&v| v as f64 - 50.0))
        .collect();
    let m = vals.iter().sum::<f64>() / vals.len() as f64;
    let v = vals.iter().map(|x| (x - m).powi(2)).sum::<f64>() / vals.len() as f64;
    assert!(
        m.abs() < 0.15 && (v / (9.0 + 1.0 / 12.0) - 1.0).abs() < 0.1,
        "{m} {v}"
    );

    // Saturation and gain.
    let bright = Simulator::new(SimulationParams {
        photons: 1e6,
        ..p.clone()
    })
    .unwrap();
    assert!(bright.subaperture_frame(0, 1).saturated > 0);
    let geared = Simulator::new(SimulationParams {
        photons: 1e6,
        gain_e_per_count: 8.0,
        ..p
    })
    .unwrap();
    let f = geared.subaperture_frame(0, 1);
    assert_eq!(f.saturated, 0);
    let s: f64 = f.raw.iter().map(|&v| v as f64 - 50.0).sum();
    assert!((s * 8.0 / 1e6 - 1.0).abs() < 0.01, "{s}");
}

#[test]
fn gtilt_theory_matches_known_coefficients() {
    let (r0, lam, d): (f64, f64, f64) = (0.125, 500e-9, 0.6);
    let norm = lam * lam * d.powf(-1.0 / 3.0) * r0.powf(-5.0 / 3.0);
    let kolmo = gtilt_variance_rad2(r0, lam, f64::INFINITY, d) / norm;
    assert!((kolmo - 0.170).abs() < 0.003, "{kolmo}");
    // Achromatic.
    let lam2 = 640e-9;
    let r02 = r0 * (lam2 / lam).powf(1.2);
    let k2 = gtilt_variance_rad2(r02, lam2, 30.0, d);
    let k1 = gtilt_variance_rad2(r0, lam, 30.0, d);
    assert!((k2 / k1 - 1.0).abs() < 1e-9);
    // A 30 m outer scale cuts a 0.6 m sub-aperture's tilt variance by ~40%.
    assert!(
        (k1 / norm / kolmo - 0.59).abs() < 0.03,
        "{}",
        k1 / norm / kolmo
    );
}

#[test]
fn von_karman_tilt_variance_matches_theory() {
    for l0 in [30.0, f64::INFINITY] {
        let sim = Simulator::new(SimulationParams {
            outer_scale_m: l0,
            ..SimulationParams::default()
        })
        .unwrap();
        let theory = sim.theoretical_tilt_variance_px2();
        let mut ws = sim.workspace();
        let n = 600;
        let (mut vp, mut vc) = (0.0, 0.0);
        for i in 0..n {
            let s = sim.pupil_phase(&mut ws, i, 99, [0.0, 0.0]);
            vp += s[0] * s[0] + s[1] * s[1];
            if i < 150 {
                let (img, _) = sim.spot_image(&mut ws);
                let c = cog(&img, 16);
                vc += c[0] * c[0] + c[1] * c[1];
            }
        }
        let vp = vp / (2.0 * n as f64);
        let vc = vc / 300.0;
        // 1200 samples: the variance estimate has a 4% standard error.
        assert!(
            (vp / theory - 1.0).abs() < 0.15,
            "L0 {l0}: phase G-tilt variance {vp} vs theory {theory}"
        );
        // The noiseless spot's centroid follows (truncation lowers it a bit).
        assert!(
            vc / theory > 0.7 && vc / theory < 1.2,
            "L0 {l0}: centroid variance {vc} vs theory {theory}"
        );
    }
}

#[test]
fn rayleigh_spot_is_elongated_along_x() {
    let make = |depth: f64| {
        Simulator::new(no_turbulence(SimulationParams {
            pixels_per_subaperture: 32,
            airy_diameter_arcsec: 0.35,
            ..SimulationParams::canary_rayleigh(depth)
        }))
        .unwrap()
    };
    let base = make(0.0);
    let m0 = moments(&base.subaperture_frame(0, 0).noiseless, 32);
    for depth in [500.0, 1000.0, 1500.0] {
        let sim = make(depth);
        let g = sim.geometry();
        let expect = 1.8 * depth / (20e3f64.powi(2) - depth * depth / 4.0) * ARCSEC_PER_RAD;
        assert!((g.elongation_extent_arcsec - expect).abs() < 1e-12);
        // ~ offset * depth / altitude^2
        assert!((expect / (1.8 * depth / 4e8 * ARCSEC_PER_RAD) - 1.0).abs() < 0.002);
        // A top hat of length L has variance L^2/12 (to 0.1%: 1/z is
        // almost linear over the gate).
        assert!((g.elongation_rms_arcsec / (expect / 12f64.sqrt()) - 1.0).abs() < 2e-3);
        let f = sim.subaperture_frame(0, 0);
        let m = moments(&f.noiseless, 32);
        let added = (m[0] - m0[0]) * 0.22f64.powi(2);
        let want = expect * expect / 12.0;
        assert!(
            (added / want - 1.0).abs() < 0.1,
            "depth {depth}: {added} vs {want}"
        );
        assert!(
            (m[1] / m0[1] - 1.0).abs() < 0.02,
            "y broadened: {m:?} {m0:?}"
        );
        assert!(f.true_slope[0].abs() < 0.05 && f.true_slope[1].abs() < 1e-9);
    }
    // The elongation's transfer function is the top hat's sinc.
    let prof = optics::elongation_profile(&Source::rayleigh(1000.0)).unwrap();
    let l = 1.8 * 1000.0 / (4e8 - 2.5e5) * ARCSEC_PER_RAD;
    for f in [0.2, 0.5, 0.9, 1.5] {
        let t = optics::profile_transfer(&prof, f).norm();
        let sinc = ((PI * f * l).sin() / (PI * f * l)).abs();
        assert!((t - sinc).abs() < 0.01, "{f}: {t} vs {sinc}");
    }
}

#[test]
fn sodium_spot_is_elongated_along_x() {
    for sep in [0.0, 8e3, 14e3] {
        let sim = Simulator::new(no_turbulence(SimulationParams::sodium(sep))).unwrap();
        let g = sim.geometry();
        assert_eq!(sim.size(), 16);
        assert!(g.oversampling >= 11);
        let f = sim.subaperture_frame(0, 0);
        assert!((f.noiseless.iter().sum::<f64>() - 1000.0).abs() < 1e-6);
        assert!(f.true_slope[1].abs() < 1e-9);
        let m = moments(&f.noiseless, 16);
        assert!(m[0] > 2.0 * m[1], "sep {sep}: {m:?}");

        // With pixels fine enough to sample the spot, the elongation adds
        // its variance along x and nothing along y. (At 1.5"/pixel the
        // sampled moments are not additive: the spot is ~1 pixel wide.)
        let fine = |b: f64| {
            let mut p = no_turbulence(SimulationParams::sodium(sep));
            p.pixels_per_subaperture = 64;
            p.pixel_scale_arcsec = 24.0 / 64.0;
            if let Source::Sodium {
                launch_offset_m, ..
            } = &mut p.source
            {
                *launch_offset_m = b;
            }
            Simulator::new(p).unwrap()
        };
        let (el, round) = (fine(21.0), fine(0.0));
        let fe = el.subaperture_frame(0, 0);
        let me = moments(&fe.noiseless, 64);
        let m0 = moments(&round.subaperture_frame(0, 0).noiseless, 64);
        let rms_px = el.geometry().elongation_rms_arcsec / 0.375;
        assert!(
            ((me[0] - m0[0]) / (rms_px * rms_px) - 1.0).abs() < 0.03,
            "sep {sep}: {me:?} {m0:?} rms {rms_px}"
        );
        assert!((me[1] / m0[1] - 1.0).abs() < 1e-3, "{me:?} {m0:?}");
        // The x profile shows the two layers (as in the paper's Fig. 8a).
        let mx: Vec<f64> = (0..64)
            .map(|x| (0..64).map(|y| fe.noiseless[y * 64 + x]).sum::<f64>())
            .collect();
        let peaks = (1..63)
            .filter(|&i| mx[i] > mx[i - 1] && mx[i] > mx[i + 1] && mx[i] > 1.0)
            .count();
        assert_eq!(peaks, if sep > 0.0 { 2 } else { 1 }, "sep {sep}: {mx:?}");
        if sep == 0.0 {
            // Mixture of sigma 2.97 and 1.70 km at 90 km seen from 21 m.
            let s1: f64 = 3.5e3 / 1.177_410_022_515_474_5;
            let s2: f64 = 2.0e3 / 1.177_410_022_515_474_5;
            let (w1, w2) = (0.4 * s1, 0.6 * s2);
            let var_z = (w1 * s1 * s1 + w2 * s2 * s2) / (w1 + w2);
            let expect = 21.0 * var_z.sqrt() / 9e4f64.powi(2) * ARCSEC_PER_RAD;
            assert!((el.geometry().elongation_rms_arcsec / expect - 1.0).abs() < 0.03);
        }
    }
}

#[test]
fn rotated_elongation_is_the_x_elongation_turned() {
    // A sodium spot elongated at 90 degrees is the x-elongated spot with x
    // and y swapped (the rotated 2-D transfer against the separable one).
    let mut p = no_turbulence(SimulationParams::sodium(8e3));
    let a = Simulator::new(p.clone()).unwrap().subaperture_frame(0, 1);
    p.source = p.source.with_elongation_angle(90.0);
    let b = Simulator::new(p).unwrap().subaperture_frame(0, 1);
    let n = a.size;
    let mut worst: f64 = 0.0;
    for y in 0..n {
        for x in 0..n {
            worst = worst.max((a.noiseless[y * n + x] - b.noiseless[x * n + y]).abs());
        }
    }
    let peak = a.noiseless.iter().copied().fold(0.0, f64::max);
    assert!(worst < 0.01 * peak, "{worst} vs peak {peak}");
    let [ma, mb] = [moments(&a.noiseless, n), moments(&b.noiseless, n)];
    assert!(ma[0] > 2.0 * ma[1] && mb[1] > 2.0 * mb[0]);
}

#[test]
fn a_truncated_spot_reports_the_light_it_loses() {
    // The paper's sodium spot at 0.22"/pixel (a 3.5" field) does not fit.
    let small = Simulator::new(SimulationParams {
        pixel_scale_arcsec: 0.22,
        ..no_turbulence(SimulationParams::sodium(14e3))
    })
    .unwrap()
    .subaperture_frame(0, 1);
    assert!(small.field_fraction < 0.6, "{}", small.field_fraction);
    let fits = Simulator::new(no_turbulence(SimulationParams::sodium(14e3)))
        .unwrap()
        .subaperture_frame(0, 1);
    assert!(fits.field_fraction > 0.98, "{}", fits.field_fraction);
    let ngs = Simulator::new(SimulationParams::canary())
        .unwrap()
        .subaperture_frame(0, 1);
    assert!(ngs.field_fraction > 0.95, "{}", ngs.field_fraction);
}

#[test]
fn spot_models_and_partly_lit_pupils() {
    let sim = |model| {
        Simulator::new(SimulationParams {
            spot_model: model,
            ..SimulationParams::canary()
        })
        .unwrap()
    };
    let g = sim(SpotModel::WfsWavelength).geometry().clone();
    assert!((g.effective_wavelength_m - 640e-9).abs() < 1e-15);
    assert!((g.diffraction_airy_arcsec - 0.5367).abs() < 1e-3);
    assert_eq!(g.optics_blur_fwhm_arcsec, 0.0);
    let g = sim(SpotModel::WfsWavelengthBlurred).geometry().clone();
    // FWHM 0.2953" (0.7" Airy) from 0.2264" (0.537" Airy): a 0.19" blur.
    assert!(
        (g.optics_blur_fwhm_arcsec - 0.1896).abs() < 2e-3,
        "{}",
        g.optics_blur_fwhm_arcsec
    );
    assert!(Simulator::new(SimulationParams {
        spot_model: SpotModel::WfsWavelengthBlurred,
        airy_diameter_arcsec: 0.3,
        ..SimulationParams::canary()
    })
    .is_err());
    // A corner sub-aperture half outside a 4.2 m pupil: a wider spot.
    let cut = Simulator::new(SimulationParams {
        pupil: Some(SubaperturePupil {
            centre_m: [1.8, 1.2],
            obscuration_m: 0.0,
        }),
        ..no_turbulence(SimulationParams::canary())
    })
    .unwrap();
    let full = Simulator::new(no_turbulence(SimulationParams::canary())).unwrap();
    let (a, b) = (cut.subaperture_frame(0, 1), full.subaperture_frame(0, 1));
    let (ma, mb) = (moments(&a.noiseless, 16), moments(&b.noiseless, 16));
    assert!(ma[0] > mb[0] * 1.2, "{ma:?} {mb:?}");
    assert!(Simulator::new(SimulationParams {
        pupil: Some(SubaperturePupil {
            centre_m: [5.0, 5.0],
            obscuration_m: 0.0,
        }),
        ..SimulationParams::canary()
    })
    .is_err());
}

#[test]
fn camera_frames_place_every_window_and_are_reproducible() {
    use super::camera::{CameraSimulator, CameraWindow};
    let windows = (0..4)
        .map(|k| CameraWindow {
            x: (k % 2) * 16,
            y: (k / 2) * 16,
            params: SimulationParams::canary(),
        })
        .collect();
    let cam = CameraSimulator::new(40, 32, windows).unwrap();
    let a = cam.frames(3, 0, 2);
    assert_eq!(a, vec![cam.frame(3, 0), cam.frame(3, 1)]);
    assert_eq!(a[0].raw.len(), 40 * 32);
    assert_eq!(a[0].true_slopes.len(), 4);
    assert_ne!(a[0].true_slopes[0], a[0].true_slopes[1]);
    // Outside the windows: background 50 and read noise only.
    let outside: Vec<f64> = (0..32).map(|y| a[0].raw[y * 40 + 35] as f64).collect();
    let mean = outside.iter().sum::<f64>() / 32.0;
    assert!((mean - 50.0).abs() < 2.0, "{mean}");
    assert!(CameraSimulator::new(
        20,
        20,
        vec![CameraWindow {
            x: 10,
            y: 0,
            params: SimulationParams::canary()
        }]
    )
    .is_err());
}

/// The EMCCD's multiplication noise doubles the photon noise's variance
/// (excess noise factor sqrt(2)) and keeps its mean.
#[test]
fn em_register_doubles_the_photon_variance() {
    let mut rng = stream_rng(7, 0, 9);
    for &lambda in &[0.3, 5.0, 60.0] {
        let poisson = Poisson::new(lambda).unwrap();
        let n = 40_000;
        let v: Vec<f64> = (0..n)
            .map(|_| em_register(poisson.sample(&mut rng), &mut rng))
            .collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0);
        assert!((mean / lambda - 1.0).abs() < 0.03, "{lambda}: mean {mean}");
        assert!(
            (var / (2.0 * lambda) - 1.0).abs() < 0.05,
            "{lambda}: var {var}"
        );
    }
    assert_eq!(em_register(0.0, &mut rng), 0.0);
}

/// Through the camera: a sub-aperture's total signal has twice the photon
/// variance with the EMCCD, the read noise's unchanged.
#[test]
fn emccd_camera_has_twice_the_photon_noise() {
    let p = no_turbulence(SimulationParams {
        photons: 400.0,
        read_noise_e: 0.5,
        em_excess_noise: true,
        ..SimulationParams::default()
    });
    let sim = Simulator::new(p.clone()).unwrap();
    let sums: Vec<f64> = (0..1500)
        .map(|f| {
            sim.subaperture_frame(f, 3)
                .raw
                .iter()
                .map(|&v| v as f64 - sim.calibration_background())
                .sum()
        })
        .collect();
    let n = sums.len() as f64;
    let mean = sums.iter().sum::<f64>() / n;
    let var = sums.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let npix = 256.0;
    let expect = 2.0 * p.photons + npix * (p.read_noise_e.powi(2) + 1.0 / 12.0);
    assert!((mean / p.photons - 1.0).abs() < 0.02, "mean {mean}");
    // The variance's own relative error is sqrt(2/1500) = 3.7%.
    assert!((var / expect - 1.0).abs() < 0.15, "var {var} vs {expect}");
}
