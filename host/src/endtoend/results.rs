//! What an end-to-end run measures, and its statistics.

use crate::evaluation::{Estimate, Method};

/// How long and with what an end-to-end run goes.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub seed: u64,
    /// Independent episodes scored.
    pub episodes: usize,
    pub frames_per_episode: usize,
    /// Episodes (independent of the scored ones) on which the matched
    /// reconstructors' noise is measured.
    pub calibration_episodes: usize,
    pub methods: Vec<Method>,
    /// N values (N at or above the window's pixel count: all pixels).
    pub pixels: Vec<usize>,
}

/// One rule and N.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Combo {
    pub method: Method,
    /// N, at most the window's pixel count.
    pub pixels: usize,
    /// No selection.
    pub all_pixels: bool,
}

/// Which reconstructor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reconstruction {
    Matched,
    Fixed,
}

impl Reconstruction {
    pub fn name(&self) -> &'static str {
        match self {
            Reconstruction::Matched => "matched",
            Reconstruction::Fixed => "fixed",
        }
    }
}

/// Per-episode means (m^2 for variances) of one reconstructor's terms.
#[derive(Clone, Debug, Default)]
pub struct Terms {
    /// The residual's variance.
    pub total: Vec<f64>,
    /// On-axis intensity of the PSF over the perfect one.
    pub strehl: Vec<f64>,
    pub noise: Vec<f64>,
    pub spot_bias: Vec<f64>,
    pub aliasing: Vec<f64>,
    pub tomography: Vec<f64>,
}

/// The results of one rule and N.
#[derive(Clone, Debug)]
pub struct ComboResult {
    pub combo: Combo,
    /// The matched reconstructor's slope-noise variance (px^2), from the
    /// calibration episodes.
    pub calibration_noise_px2: f64,
    /// Per episode, the mean squared difference between the engine's slopes
    /// and the noiseless centres of gravity (px^2, per axis): the paper's
    /// R^2 over every sub-aperture of every sensor.
    pub slope_noise_px2: Vec<f64>,
    pub matched: Terms,
    pub fixed: Terms,
    /// The fixed reconstructor's `sigma^2` (px^2).
    pub fixed_sigma2_px2: f64,
}

impl ComboResult {
    pub fn terms(&self, r: Reconstruction) -> &Terms {
        match r {
            Reconstruction::Matched => &self.matched,
            Reconstruction::Fixed => &self.fixed,
        }
    }

    /// The reconstructor's assumed noise (px^2).
    pub fn sigma2_px2(&self, r: Reconstruction) -> f64 {
        match r {
            Reconstruction::Matched => self.calibration_noise_px2,
            Reconstruction::Fixed => self.fixed_sigma2_px2,
        }
    }
}

/// A whole run's results.
#[derive(Clone, Debug)]
pub struct EndToEndResult {
    pub combos: Vec<ComboResult>,
    pub frames_per_episode: usize,
    /// Per episode (m^2): the DM's fitting error, the delay's error, and the
    /// uncorrected on-axis phase variance (piston removed).
    pub fitting: Vec<f64>,
    pub temporal: Vec<f64>,
    pub uncorrected: Vec<f64>,
    pub science_wavelength_m: f64,
    /// The second reconstructor's name: `fixed` (MMSE, one assumed noise)
    /// or the least-squares one's label.
    pub fixed_label: String,
    /// For a least-squares second reconstructor: the singular modes of `G`
    /// kept (at or above the truncation) and their total.
    pub modes_kept: Option<(usize, usize)>,
    pub timing: Timing,
}

/// Mean and standard error of per-episode means.
pub fn estimate(values: &[f64]) -> Estimate {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let se = if values.len() > 1 {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt()
    } else {
        f64::NAN
    };
    Estimate { value: mean, se }
}

/// The root of an estimated mean square, in nm (delta method).
pub fn rms_nm(ms: Estimate) -> Estimate {
    let v = ms.value.max(0.0).sqrt();
    Estimate {
        value: v * 1e9,
        se: if v > 0.0 {
            ms.se / (2.0 * v) * 1e9
        } else {
            f64::NAN
        },
    }
}

impl EndToEndResult {
    /// The name of reconstructor `r` in this run's outputs.
    pub fn label(&self, r: Reconstruction) -> &str {
        match r {
            Reconstruction::Matched => r.name(),
            Reconstruction::Fixed => &self.fixed_label,
        }
    }

    pub fn find(&self, method: Method, pixels: usize) -> Option<&ComboResult> {
        self.combos
            .iter()
            .find(|c| c.combo.method == method && c.combo.pixels == pixels)
    }

    /// Residual wavefront error (nm rms).
    pub fn wfe_nm(&self, c: &ComboResult, r: Reconstruction) -> Estimate {
        rms_nm(estimate(&c.terms(r).total))
    }

    pub fn strehl(&self, c: &ComboResult, r: Reconstruction) -> Estimate {
        estimate(&c.terms(r).strehl)
    }

    /// `exp(-sigma^2)` at the science wavelength (Maréchal).
    pub fn marechal(&self, c: &ComboResult, r: Reconstruction) -> f64 {
        let k = 2.0 * std::f64::consts::PI / self.science_wavelength_m;
        (-estimate(&c.terms(r).total).value * k * k).exp()
    }

    /// `WFE(a) - WFE(b)` (nm) on the same frames, with the standard error of
    /// the per-episode paired differences of the mean squares.
    pub fn paired_difference_nm(
        &self,
        a: &ComboResult,
        b: &ComboResult,
        r: Reconstruction,
    ) -> Estimate {
        let (ta, tb) = (&a.terms(r).total, &b.terms(r).total);
        let d: Vec<f64> = ta.iter().zip(tb).map(|(x, y)| x - y).collect();
        let dm = estimate(&d);
        let (wa, wb) = (self.wfe_nm(a, r).value, self.wfe_nm(b, r).value);
        // sigma_a^2 - sigma_b^2 = (sigma_a - sigma_b)(sigma_a + sigma_b)
        Estimate {
            value: wa - wb,
            se: dm.se * 1e18 / (wa + wb),
        }
    }

    /// The combination with the lowest residual of `method` (any N).
    pub fn best(&self, method: Method, r: Reconstruction) -> Option<&ComboResult> {
        self.combos
            .iter()
            .filter(|c| c.combo.method == method)
            .min_by(|a, b| {
                estimate(&a.terms(r).total)
                    .value
                    .total_cmp(&estimate(&b.terms(r).total).value)
            })
    }
}

/// Where a run's time went (seconds).
#[derive(Clone, Debug, Default)]
pub struct Timing {
    /// Wall time drawing the layers' screens.
    pub screens: f64,
    /// Wall time making the sensors' camera frames (ray tracing, spots,
    /// noise).
    pub wfs_frames: f64,
    /// Wall time sampling the science path.
    pub science: f64,
    /// Wall time of the scoring (engine, reconstruction, residuals).
    pub scoring: f64,
    /// Thread time (summed over threads) in the engine.
    pub engine_cpu: f64,
    /// Thread time in reconstruction, residuals and Strehl.
    pub reconstruction_cpu: f64,
    /// Wall time of the whole run.
    pub total: f64,
}
