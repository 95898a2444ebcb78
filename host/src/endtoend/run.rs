//! The run: calibration episodes (each rule and N's slope noise, for the
//! matched reconstructors), then the scored episodes and each term of the
//! error budget.

use anyhow::{bail, Result};
use nalgebra::DMatrix;
use rayon::prelude::*;

use super::{
    ComboResult, EndToEnd, EndToEndResult, EpisodeData, RunOptions, Terms, Timing,
    CALIBRATION_EPISODE,
};

impl EndToEnd {
    /// Runs the calibration and the scored episodes, calling
    /// `progress(frames)` as frames are simulated and scored.
    pub fn run(
        &self,
        options: &RunOptions,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<EndToEndResult> {
        if options.episodes < 2 {
            bail!("at least 2 episodes are needed for a standard error");
        }
        if options.calibration_episodes == 0 {
            bail!("at least 1 calibration episode is needed");
        }
        if options.methods.is_empty() || options.pixels.is_empty() {
            bail!("no rule or no N to score");
        }
        let combos = self.combos(&options.methods, &options.pixels);
        let f = self.frames_per_episode;
        let half = f / 2;
        let started = std::time::Instant::now();
        let mut timing = Timing::default();
        let account = |data: &EpisodeData, timing: &mut Timing| {
            timing.screens += data.timing[0];
            timing.wfs_frames += data.timing[1];
            timing.science += data.timing[2];
        };
        let thread_time = |t: std::time::Instant| t.elapsed().as_secs_f64();

        // Calibration: each combination's slope noise, per slope (summed
        // over frames) for the per-sub-aperture weights.
        let n_slopes = self.tomography.slopes();
        let mut noise_sums = vec![(vec![0.0; n_slopes], 0usize); combos.len()];
        for c in 0..options.calibration_episodes as u64 {
            let episode = CALIBRATION_EPISODE + c;
            let data = self.simulate_episode(options.seed, episode, episode * f as u64);
            account(&data, &mut timing);
            progress(half);
            let scoring = std::time::Instant::now();
            let sums: Vec<(Vec<f64>, f64)> = combos
                .par_iter()
                .map(|combo| {
                    let t = std::time::Instant::now();
                    let ints = self.engine_slopes(&data, combo.method, combo.pixels)?;
                    let engine = thread_time(t);
                    let s = self.slope_matrix(&ints, f);
                    let d = s - &data.s_cog;
                    let rows = d.row_iter().map(|r| r.norm_squared()).collect();
                    Ok((rows, engine))
                })
                .collect::<Result<_>>()?;
            timing.scoring += scoring.elapsed().as_secs_f64();
            for (acc, (rows, engine)) in noise_sums.iter_mut().zip(sums) {
                acc.0.iter_mut().zip(rows).for_each(|(a, r)| *a += r);
                acc.1 += f;
                timing.engine_cpu += engine;
            }
            progress(f - half);
        }
        let (m_fixed, fixed_sigma2, fixed_label, modes_kept) = match self.scenario.least_squares {
            None => {
                let s2 = self.scenario.fixed_noise_px.powi(2);
                (
                    self.tomography.reconstructor(s2),
                    s2,
                    "fixed".to_string(),
                    None,
                )
            }
            Some(ls) => {
                let r = self
                    .ls_tomography
                    .as_ref()
                    .expect("built with the least-squares option")
                    .least_squares(ls);
                (
                    r.m,
                    f64::NAN,
                    ls.label(),
                    Some((r.modes_kept, r.singular_values.len())),
                )
            }
        };
        let per_slope: Vec<Vec<f64>> = noise_sums
            .iter()
            .map(|(rows, n)| rows.iter().map(|r| r / *n as f64).collect())
            .collect();
        let calibration: Vec<f64> = per_slope
            .iter()
            .map(|v| v.iter().sum::<f64>() / v.len() as f64)
            .collect();
        let weights = self.scenario.noise_weights;
        let m_matched: Vec<DMatrix<f64>> = per_slope
            .par_iter()
            .zip(&calibration)
            .map(|(v, &s2)| {
                if weights {
                    self.tomography
                        .reconstructor_weighted(&self.per_subaperture_noise(v))
                } else {
                    self.tomography.reconstructor(s2)
                }
            })
            .collect();

        let mut results: Vec<ComboResult> = combos
            .iter()
            .zip(&calibration)
            .map(|(&combo, &s2)| ComboResult {
                combo,
                calibration_noise_px2: s2,
                slope_noise_px2: Vec::new(),
                matched: Terms::default(),
                fixed: Terms::default(),
                fixed_sigma2_px2: fixed_sigma2,
            })
            .collect();
        let (mut fitting, mut temporal, mut uncorrected) = (Vec::new(), Vec::new(), Vec::new());
        let k_sci = 2.0 * std::f64::consts::PI / self.scenario.science_wavelength_m;
        for e in 0..options.episodes as u64 {
            let data = self.simulate_episode(options.seed, e, e * f as u64);
            account(&data, &mut timing);
            progress(half);
            let scoring = std::time::Instant::now();
            let sci = &self.science;
            let c_now = &sci.fit * &data.phi_now;
            let c_later = &sci.fit * &data.phi_later;
            let fit_res = &data.phi_later - &sci.h * &c_later;
            fitting.push(fit_res.norm_squared() / fit_res.len() as f64);
            temporal.push(q_norm(&sci.q, &(&c_later - &c_now)) / f as f64);
            uncorrected.push(data.phi_later.norm_squared() / data.phi_later.len() as f64);
            let per: Vec<(f64, [[f64; 6]; 2], [f64; 2])> = combos
                .par_iter()
                .zip(&m_matched)
                .map(|(combo, mm)| {
                    let t = std::time::Instant::now();
                    let ints = self.engine_slopes(&data, combo.method, combo.pixels)?;
                    let engine = thread_time(t);
                    let t = std::time::Instant::now();
                    let s = self.slope_matrix(&ints, f);
                    let noise = &s - &data.s_cog;
                    let slope_noise = noise.norm_squared() / noise.len() as f64;
                    let terms =
                        [mm, &m_fixed].map(|m| self.terms(m, &s, &noise, &data, &c_now, k_sci));
                    Ok((slope_noise, terms, [engine, thread_time(t)]))
                })
                .collect::<Result<_>>()?;
            timing.scoring += scoring.elapsed().as_secs_f64();
            for (r, (slope_noise, terms, cpu)) in results.iter_mut().zip(per) {
                timing.engine_cpu += cpu[0];
                timing.reconstruction_cpu += cpu[1];
                r.slope_noise_px2.push(slope_noise);
                for (t, v) in [&mut r.matched, &mut r.fixed].into_iter().zip(terms) {
                    t.total.push(v[0]);
                    t.strehl.push(v[1]);
                    t.noise.push(v[2]);
                    t.spot_bias.push(v[3]);
                    t.aliasing.push(v[4]);
                    t.tomography.push(v[5]);
                }
            }
            progress(f - half);
        }
        Ok(EndToEndResult {
            combos: results,
            frames_per_episode: f,
            fitting,
            temporal,
            uncorrected,
            science_wavelength_m: self.scenario.science_wavelength_m,
            fixed_label,
            modes_kept,
            timing: Timing {
                total: started.elapsed().as_secs_f64(),
                ..timing
            },
        })
    }

    /// Per-slope noise variances `v` (one calibration episode: 100 frames a
    /// slope, too few for each on its own) pooled per sub-aperture over the
    /// sensors and both axes, which share its photons and lit pupil.
    pub(super) fn per_subaperture_noise(&self, v: &[f64]) -> Vec<f64> {
        let n_sub = self.lenslets.subapertures.len();
        let sensors = v.len() / (2 * n_sub);
        let pooled: Vec<f64> = (0..n_sub)
            .map(|k| {
                (0..sensors)
                    .flat_map(|w| [0, 1].map(|a| v[(w * n_sub + k) * 2 + a]))
                    .sum::<f64>()
                    / (2 * sensors) as f64
            })
            .collect();
        (0..v.len()).map(|i| pooled[(i / 2) % n_sub]).collect()
    }

    /// One reconstructor's per-episode means: total variance, Strehl,
    /// noise, spot bias, aliasing, tomography.
    fn terms(
        &self,
        m: &DMatrix<f64>,
        s: &DMatrix<f64>,
        noise: &DMatrix<f64>,
        data: &EpisodeData,
        c_now: &DMatrix<f64>,
        k_sci: f64,
    ) -> [f64; 6] {
        let sci = &self.science;
        let f = data.frames as f64;
        let c = m * s;
        let residual = &data.phi_later - &sci.h * &c;
        let np = residual.nrows() as f64;
        let total = residual.norm_squared() / residual.len() as f64;
        let strehl = residual
            .column_iter()
            .map(|col| {
                let (mut re, mut im) = (0.0, 0.0);
                for &r in col.iter() {
                    let (sin, cos) = (k_sci * r).sin_cos();
                    re += cos;
                    im += sin;
                }
                (re * re + im * im) / (np * np)
            })
            .sum::<f64>()
            / f;
        let noise_term = q_norm(&sci.q, &(m * noise)) / f;
        let bias = q_norm(&sci.q, &(m * (&data.s_cog - &data.s_gtilt))) / f;
        let aliasing = q_norm(&sci.q, &(m * (&data.s_gtilt - &data.s_low))) / f;
        let tomography = q_norm(&sci.q, &(c_now - m * &data.s_low)) / f;
        [total, strehl, noise_term, bias, aliasing, tomography]
    }
}

/// `sum_f x_f^T Q x_f` over the columns of `x`.
fn q_norm(q: &DMatrix<f64>, x: &DMatrix<f64>) -> f64 {
    (q * x).component_mul(x).sum()
}
