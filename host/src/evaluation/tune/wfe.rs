//! Tuning on the end-to-end residual wavefront error (`brightpix tune
//! --criterion wfe`, the Python `brightpix.tune(..., criterion="wfe")`).
//!
//! The windows lit below the illumination threshold are dropped; the rest
//! become the sensors of an open-loop MOAO simulation ([`crate::endtoend`])
//! with the request's optics, detector and atmosphere (r0, L0) and the
//! end-to-end [`Conditions`] (asterism, layers, loop, DM). Every candidate
//! rule runs at every N of [`PIXELS`] and with all pixels; the rule and N of
//! least on-axis residual WFE with the matched reconstructor win (one N for
//! every window), and the N of that rule the run cannot tell from the best
//! (2 paired standard errors) are reported beside it.

use anyhow::{anyhow, bail, Result};
use brightpix_protocol::LevelFilter;

use super::{place, Prepared, TuneRequest};
use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::endtoend::{Conditions, EndToEnd, EndToEndResult, Reconstruction, RunOptions, Scenario};
use crate::evaluation::{Estimate, Method};
use crate::io::FrameCube;
use crate::simulator::atmosphere::Atmosphere;

/// The N values scored (all pixels added).
pub const PIXELS: [usize; 23] = [
    1, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 18, 20, 25, 30, 40, 50, 60, 80, 100, 128, 160, 200,
];

/// What the tuned N minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Criterion {
    /// The paper's slope error R, per class of sub-apertures.
    R,
    /// The end-to-end on-axis residual wavefront error, one N for all.
    Wfe,
}

/// Options that only criterion R uses (the Python keywords' names; the
/// command line's `--count` is `frames`), and why criterion wfe has no use
/// for them.
pub const R_ONLY: [(&str, &str); 8] = [
    (
        "frames",
        "it is the frames simulated per class of sub-apertures; the end-to-end run's length is episodes and episode_frames",
    ),
    ("score", "the end-to-end run scores the residual wavefront error, not R"),
    ("classes", "it is the number of distance classes of a laser guide star"),
    ("angle_classes", "it is the number of azimuth classes of a laser guide star"),
    (
        "launch",
        "it is a laser guide star's launch position; the end-to-end simulation models natural guide stars only",
    ),
    (
        "lgs_spot",
        "it is a laser guide star's spot size; the end-to-end simulation models natural guide stars only",
    ),
    (
        "keep_dark",
        "the end-to-end run leaves dark sub-apertures out of the simulation and of the tuned configuration",
    ),
    (
        "max_truncation",
        "the end-to-end run does not check the spots' truncation",
    ),
];

/// Options that only criterion wfe uses: the end-to-end [`Conditions`]
/// (the Python keywords' names, the command line's options in snake case).
pub const WFE_ONLY: [&str; 13] = [
    "asterism",
    "science",
    "layers",
    "wind_scale",
    "frame_rate",
    "delay",
    "science_wavelength",
    "dm_actuators",
    "dm_coupling",
    "fixed_noise",
    "episodes",
    "episode_frames",
    "calibration_episodes",
];

impl Criterion {
    /// `r` or `wfe`.
    pub fn parse(text: &str) -> Result<Criterion> {
        match text {
            "r" => Ok(Criterion::R),
            "wfe" => Ok(Criterion::Wfe),
            other => bail!("criterion {other:?}: one of r, wfe"),
        }
    }

    /// Refuses an option of the other criterion among those a user gave
    /// (`given`: their names), which would otherwise be silently ignored.
    pub fn check_given(self, given: &[&str]) -> Result<()> {
        match self {
            Criterion::Wfe => {
                for (name, why) in R_ONLY {
                    if given.contains(&name) {
                        bail!("criterion wfe has no use for {name}: {why}");
                    }
                }
            }
            Criterion::R => {
                for name in WFE_ONLY {
                    if given.contains(&name) {
                        bail!(
                            "{name} is an end-to-end condition: it applies to criterion wfe only"
                        );
                    }
                }
            }
        }
        Ok(())
    }
}

/// A tuning run on the residual WFE as the user asks for it: the sensor's
/// conditions (those of criterion R; no laser guide star) and the
/// end-to-end ones.
#[derive(Clone, Debug, Default)]
pub struct WfeRequest {
    pub tune: TuneRequest,
    pub endtoend: Conditions,
}

/// Refuses a laser guide star: the end-to-end simulation has none.
fn refuse_lgs(lgs: bool) -> Result<()> {
    if lgs {
        bail!("criterion wfe: the end-to-end simulation models natural guide stars only (no lgs)");
    }
    Ok(())
}

impl WfeRequest {
    /// Refuses a value out of range, before any file is read or written.
    pub fn check(&self) -> Result<()> {
        refuse_lgs(self.tune.lgs.is_some())?;
        self.tune.check()?;
        self.endtoend.check()
    }

    /// Checks, prepares the sensor's conditions for `config` (measured in
    /// `recorded` frames, if any) and plans the run.
    pub fn plan(
        &self,
        config: &ProcessingConfig,
        recorded: Option<&FrameCube>,
    ) -> Result<(Prepared, WfePlan)> {
        self.check()?;
        let prepared = self.tune.prepare(config, recorded)?;
        let plan = WfePlan::new(config, &prepared, &self.endtoend)?;
        Ok((prepared, plan))
    }
}

/// `config` without the windows `dark` (indices): a grid keeps its grid
/// with them skipped; a list loses them (and its per-window N and reference
/// slopes, which tune rewrites anyway).
fn without(config: &ProcessingConfig, dark: &[usize]) -> ProcessingConfig {
    let mut out = config.clone();
    if dark.is_empty() {
        return out;
    }
    if let Some(layout) = &config.grid {
        let mut skip = layout.skip.clone();
        for (k, pos) in layout.positions().enumerate() {
            if dark.contains(&k) {
                skip.push(pos);
            }
        }
        let fresh = ProcessingConfig::from_grid(config.camera, layout.grid, &skip);
        out.windows = fresh.windows;
        out.grid = fresh.grid;
    } else {
        out.windows = config
            .windows
            .iter()
            .enumerate()
            .filter(|(k, _)| !dark.contains(k))
            .map(|(_, w)| *w)
            .collect();
    }
    out.reference_slopes = None;
    out.pixels = PixelCounts::All(20);
    out
}

/// A planned run: the scenario built and checked, nothing simulated yet.
pub struct WfePlan {
    /// The input configuration without its dark windows.
    pub config: ProcessingConfig,
    /// Windows (indices in the input) lit below the illumination threshold.
    pub dark: Vec<usize>,
    pub illumination_threshold: f64,
    pub e2e: EndToEnd,
    pub options: RunOptions,
}

impl WfePlan {
    /// Drops the dark windows of `config` and builds the end-to-end
    /// scenario of its sensor under `prepared` (a NGS) and `conditions`.
    pub fn new(
        config: &ProcessingConfig,
        prepared: &Prepared,
        conditions: &Conditions,
    ) -> Result<WfePlan> {
        refuse_lgs(prepared.conditions.lgs.is_some())?;
        conditions.check()?;
        let p = &prepared.conditions.params;
        let threshold = prepared.conditions.pupil.illumination_threshold;
        let dark: Vec<usize> = place(config, &prepared.conditions)
            .iter()
            .enumerate()
            .filter(|(_, pl)| pl.lit_fraction < threshold)
            .map(|(k, _)| k)
            .collect();
        if dark.len() == config.windows.len() {
            bail!(
                "no sub-aperture is lit above the illumination threshold {threshold} (telescope {} m, obscuration {} m)",
                p.telescope_diameter_m,
                prepared.conditions.pupil.obscuration_m
            );
        }
        let lit = without(config, &dark);
        let mut scenario = Scenario {
            config: lit.clone(),
            across: Some(p.subapertures_across as usize),
            wfs: p.clone(),
            obscuration_m: prepared.conditions.pupil.obscuration_m,
            atmosphere: Atmosphere {
                r0_m: p.r0_m,
                r0_wavelength_m: p.r0_wavelength_m,
                outer_scale_m: p.outer_scale_m,
                ..Atmosphere::canary()
            },
            ..Scenario::canary()
        };
        conditions.apply(&mut scenario)?;
        let e2e = EndToEnd::new(scenario, conditions.episode_frames)?;
        let mut pixels = PIXELS.to_vec();
        pixels.push(e2e.window_pixels());
        let options = RunOptions {
            seed: prepared.options.seed,
            episodes: conditions.episodes,
            frames_per_episode: conditions.episode_frames,
            calibration_episodes: conditions.calibration_episodes,
            methods: prepared.options.methods.clone(),
            pixels,
        };
        Ok(WfePlan {
            config: lit,
            dark,
            illumination_threshold: threshold,
            e2e,
            options,
        })
    }

    /// Frames the run simulates (for progress bars: `run`'s `progress`
    /// adds up to it).
    pub fn frames(&self) -> usize {
        self.options.frames_per_episode
            * (self.options.episodes + self.options.calibration_episodes)
    }

    /// Runs every rule and N, calling `progress(frames)` as frames are
    /// simulated and scored, and picks the best.
    pub fn run(self, progress: &(dyn Fn(usize) + Sync)) -> Result<WfeTuneResult> {
        let result = self.e2e.run(&self.options, progress)?;
        let threads = rayon::current_num_threads();
        let r = Reconstruction::Matched;
        let best = result
            .combos
            .iter()
            .min_by(|a, b| {
                result
                    .wfe_nm(a, r)
                    .value
                    .total_cmp(&result.wfe_nm(b, r).value)
            })
            .ok_or_else(|| anyhow!("nothing was scored"))?;
        let not_resolved: Vec<usize> = result
            .combos
            .iter()
            .filter(|c| c.combo.method == best.combo.method)
            .filter(|c| {
                let d = result.paired_difference_nm(c, best, r);
                d.value <= 2.0 * d.se || std::ptr::eq(*c, best)
            })
            .map(|c| c.combo.pixels)
            .collect();
        let method = best.combo.method;
        let mut tuned = self.config;
        tuned.rule = method.rule;
        tuned.pixels = PixelCounts::All(best.combo.pixels as u16);
        tuned.level_filter = method
            .level_filter
            .map(|gain_shift| LevelFilter { gain_shift });
        if method.clip_negative {
            tuned.threshold = Some(0);
        }
        Ok(WfeTuneResult {
            config: tuned,
            method,
            pixels: best.combo.pixels,
            wfe_nm: result.wfe_nm(best, r),
            strehl: result.strehl(best, r),
            science_wavelength_m: self.e2e.scenario.science_wavelength_m,
            wfe_all_pixels_nm: result
                .combos
                .iter()
                .find(|c| c.combo.all_pixels)
                .map(|c| result.wfe_nm(c, r).value),
            not_resolved,
            dark: self.dark,
            illumination_threshold: self.illumination_threshold,
            scenario: self.e2e.scenario.describe(&self.e2e.lenslets, &self.e2e.dm),
            endtoend: result,
            options: self.options,
            threads,
        })
    }
}

/// One rule and N's score (matched reconstructor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WfeScore {
    pub method: Method,
    pub pixels: usize,
    pub all_pixels: bool,
    /// Residual WFE (nm rms) and its standard error.
    pub wfe_nm: Estimate,
    pub strehl: Estimate,
}

/// What [`WfePlan::run`] found.
#[derive(Clone, Debug)]
pub struct WfeTuneResult {
    /// The input configuration without its dark windows, with the chosen
    /// rule, level filter and N.
    pub config: ProcessingConfig,
    pub method: Method,
    /// The chosen N (the window's pixel count: all pixels).
    pub pixels: usize,
    /// Its residual WFE (nm rms, matched reconstructor) and Strehl ratio.
    pub wfe_nm: Estimate,
    pub strehl: Estimate,
    /// The wavelength of the Strehl ratio (m).
    pub science_wavelength_m: f64,
    /// The first rule's WFE with all pixels (nm rms).
    pub wfe_all_pixels_nm: Option<f64>,
    /// The chosen rule's N whose WFE is within 2 paired standard errors of
    /// the best (the best included).
    pub not_resolved: Vec<usize>,
    /// Windows (indices in the input) lit below the threshold, left out.
    pub dark: Vec<usize>,
    pub illumination_threshold: f64,
    /// What the end-to-end run assumed, one line each.
    pub scenario: Vec<String>,
    pub endtoend: EndToEndResult,
    pub options: RunOptions,
    /// Threads the run used.
    pub threads: usize,
}

impl WfeTuneResult {
    /// Every rule and N with the matched reconstructor, in the run's order.
    pub fn scores(&self) -> Vec<WfeScore> {
        let r = Reconstruction::Matched;
        self.endtoend
            .combos
            .iter()
            .map(|c| WfeScore {
                method: c.combo.method,
                pixels: c.combo.pixels,
                all_pixels: c.combo.all_pixels,
                wfe_nm: self.endtoend.wfe_nm(c, r),
                strehl: self.endtoend.strehl(c, r),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::tune::Lgs;
    use crate::sil::canary_config;

    #[test]
    fn criteria_parse_and_refuse_the_other_criterions_options() {
        assert_eq!(Criterion::parse("r").unwrap(), Criterion::R);
        assert_eq!(Criterion::parse("wfe").unwrap(), Criterion::Wfe);
        let e = Criterion::parse("strehl").unwrap_err().to_string();
        assert!(e.contains("one of r, wfe"), "{e}");
        for (name, _) in R_ONLY {
            let e = Criterion::Wfe.check_given(&[name]).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains("criterion wfe"), "{e}");
            Criterion::R.check_given(&[name]).unwrap();
        }
        for name in WFE_ONLY {
            let e = Criterion::R.check_given(&[name]).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains("criterion wfe only"), "{e}");
            Criterion::Wfe.check_given(&[name]).unwrap();
        }
        // What both use is refused by neither.
        for c in [Criterion::R, Criterion::Wfe] {
            c.check_given(&["seed", "level_filter", "recorded", "obscuration"])
                .unwrap();
        }
    }

    #[test]
    fn a_request_is_checked_whole_before_any_work() {
        WfeRequest::default().check().unwrap();
        let mut lgs = WfeRequest::default();
        lgs.tune.lgs = Some(Lgs::parse("rayleigh:1000").unwrap());
        let e = lgs.check().unwrap_err().to_string();
        assert!(e.contains("natural guide stars"), "{e}");
        // The sensor's conditions and the end-to-end ones are both checked.
        let mut bad = WfeRequest::default();
        bad.tune.pupil.illumination_threshold = 0.0;
        assert!(bad
            .check()
            .unwrap_err()
            .to_string()
            .contains("illumination"));
        let mut bad = WfeRequest::default();
        bad.endtoend.episodes = 1;
        assert!(bad.check().unwrap_err().to_string().contains("at least 2"));
        // So is a plan, before the scenario is built.
        let e = bad.plan(&canary_config(), None).err().unwrap().to_string();
        assert!(e.contains("episodes 1"), "{e}");
    }

    #[test]
    fn dark_windows_are_left_out_of_the_scenario() {
        let config = canary_config();
        let mut request = WfeRequest::default();
        request.tune.frames = crate::evaluation::tune::MIN_FRAMES;
        request.endtoend.episodes = 2;
        request.endtoend.episode_frames = 2;
        let (prepared, plan) = request.plan(&config, None).unwrap();
        // The 4.2 m pupil on the 7x7 grid: 12 windows lit below half.
        assert_eq!(plan.dark.len(), 12);
        assert_eq!(plan.config.windows.len(), 37);
        assert_eq!(plan.e2e.lenslets.subapertures.len(), 37);
        let grid = plan.config.grid.as_ref().unwrap();
        assert_eq!(grid.skip.len(), 12);
        assert_eq!(plan.options.seed, prepared.options.seed);
        assert_eq!(plan.options.methods, prepared.options.methods);
        assert_eq!(plan.options.pixels.last(), Some(&256));
        assert_eq!(plan.frames(), 2 * 3);
        // A pupil that lights nothing is refused.
        request.tune.pupil.obscuration_m = 5.0;
        let e = request.plan(&config, None).err().unwrap().to_string();
        assert!(e.contains("no sub-aperture is lit"), "{e}");
    }
}
