//! The no-selection baseline: what a user who does not select pixels runs
//! instead of the engine. Every pixel of a window is calibrated (SPEC.md
//! §2) and weighs its calibrated value in the centre of gravity (§5), which
//! is exactly what the engine computes when N is at least the window's
//! pixel count (§3, "no selection"); so its results must equal that
//! engine's bit for bit (the bench checks every frame), and its time is the
//! price of the pixel path without selection.
//!
//! Written as tightly as we could, independently of the engine:
//! - one pass per window row, no copy: the calibrated values are summed
//!   into per-column sums `C_i` (`i32`: `|p| < 2^25` and `h <= 64`), and
//!   those into a running total of the column sums after each row, `D_i`,
//!   which ends as `sum_j (h - j) p_ij`; so `sum w = sum C_i`,
//!   `sum w i = sum i C_i` and `sum w j = h sum w - sum D_i`, all taken
//!   once per window. Both updates are plain lane-wise adds that the
//!   compiler vectorises; no multiply by a coordinate per pixel.
//! - `D_i` in `i32` when the configuration's largest `|p|` times
//!   `h (h + 1) / 2` fits (any 16x16 window with a background map), else in
//!   `i64`;
//! - the calibration's steps as compile-time variants (none, background
//!   only, all three: an absent gain is a gain of 4096 and an absent
//!   threshold `i32::MIN`, which change no value), the common window widths
//!   (8, 16, 32) as compile-time widths so that a row is whole vectors;
//! - on x86-64 with AVX2, the same code compiled for AVX2 (chosen at run
//!   time: the C version this replaces was built with `-march=native`);
//!   [`NoSelectionPeer::portable`] is the build for baseline x86-64 (SSE2),
//!   as the engine is built, and the bench times both.

use brightpix_firmware::engine::SubapertureResult;
use brightpix_protocol::{Config, SubapertureWindow};

use super::peers::{Peer, PeerSlope};

/// The widest window (SPEC.md §1).
const MAX_SIDE: usize = 64;

/// The no-selection baseline on a configuration's windows and calibration.
pub struct NoSelectionPeer {
    plan: Plan,
    kernel: Kernel,
    /// The kernel is compiled for AVX2.
    avx2: bool,
    /// The running totals are `i32`.
    narrow: bool,
    sums: Vec<Sums>,
    min_flux: i64,
    reference: Option<Vec<[i32; 2]>>,
    /// The last frame's exact results (for the agreement check).
    pub results: Vec<SubapertureResult>,
}

/// What the kernels read besides the frame.
struct Plan {
    windows: Vec<SubapertureWindow>,
    /// Camera width (the frame's row stride).
    stride: usize,
    /// Background per camera pixel (zeros where the configuration has none
    /// but has a gain or threshold).
    background: Vec<i32>,
    /// Gain per camera pixel, 1/4096 (4096 where there is none).
    gain: Vec<u16>,
    threshold: i32,
}

/// A window's sums: `sum w`, `sum w i`, `sum w j`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Sums {
    flux: i64,
    wi: i64,
    wj: i64,
}

type Kernel = fn(&Plan, &[u16], &mut [Sums]);

/// The calibration steps a kernel applies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Steps {
    None,
    Background,
    All,
}

impl NoSelectionPeer {
    /// The baseline at its fastest: compiled for AVX2 if this machine has
    /// it.
    pub fn new(config: &Config<'_>) -> Self {
        Self::build(config, true)
    }

    /// The baseline compiled for baseline x86-64 (SSE2), as the engine is
    /// (on other machines the same as [`NoSelectionPeer::new`]).
    pub fn portable(config: &Config<'_>) -> Self {
        Self::build(config, false)
    }

    fn build(config: &Config<'_>, allow_avx2: bool) -> Self {
        let calibration = &config.calibration;
        let pixels = config.camera.pixel_count();
        let steps = match (
            calibration.background,
            calibration.gain,
            calibration.threshold,
        ) {
            (None, None, None) => Steps::None,
            (Some(_), None, None) => Steps::Background,
            _ => Steps::All,
        };
        let background = match (steps, calibration.background) {
            (Steps::None, _) => Vec::new(),
            (_, Some(b)) => b.to_vec(),
            (_, None) => vec![0; pixels],
        };
        let gain = match (steps, calibration.gain) {
            (Steps::All, Some(g)) => g.to_vec(),
            (Steps::All, None) => vec![4096; pixels],
            _ => Vec::new(),
        };
        // The largest |p| (SPEC.md §2): |16 r - B|, then scaled by the
        // gain (a threshold only zeroes values).
        let largest_background = background.iter().map(|b| b.unsigned_abs()).max();
        let mut largest =
            16 * config.camera.max_raw() as u64 + largest_background.unwrap_or(0) as u64;
        if let Some(g) = gain.iter().max() {
            largest = (largest * *g as u64) / 4096 + 1;
        }
        let tallest = config.windows.iter().map(|w| w.height).max().unwrap_or(1) as u64;
        let narrow = largest * tallest * (tallest + 1) / 2 < 1 << 31;
        let (kernel, avx2) = kernel(steps, narrow, allow_avx2);
        NoSelectionPeer {
            kernel,
            avx2,
            narrow,
            sums: vec![Sums::default(); config.windows.len()],
            min_flux: config.centroid.min_flux,
            reference: config.centroid.reference_slopes.map(<[[i32; 2]]>::to_vec),
            results: Vec::with_capacity(config.windows.len()),
            plan: Plan {
                windows: config.windows.to_vec(),
                stride: config.camera.width as usize,
                background,
                gain,
                threshold: calibration.threshold.unwrap_or(i32::MIN),
            },
        }
    }

    /// Whether the running totals are `i32` (else `i64`: a large map or
    /// gain, or tall windows).
    pub fn narrow_totals(&self) -> bool {
        self.narrow
    }

    /// SPEC.md §5 on a window's sums.
    fn result(&self, k: usize, sums: Sums) -> SubapertureResult {
        let w = self.plan.windows[k];
        let flux = sums.flux;
        let mut result = SubapertureResult {
            index: k as u16,
            slope_x: 0,
            slope_y: 0,
            flux,
            valid: flux > self.min_flux,
        };
        if result.valid {
            let reference = self.reference.as_ref().map_or([0, 0], |r| r[k]);
            // Centred half-pixel coordinates: sum w (2i - (w - 1)).
            let sx = 2 * sums.wi - (w.width as i64 - 1) * flux;
            let sy = 2 * sums.wj - (w.height as i64 - 1) * flux;
            let slope = |s: i64, r: i32| {
                let q = ((s << 16) + flux).div_euclid(2 * flux) - r as i64;
                q.clamp(i32::MIN as i64, i32::MAX as i64) as i32
            };
            result.slope_x = slope(sx, reference[0]);
            result.slope_y = slope(sy, reference[1]);
        }
        result
    }
}

impl Peer for NoSelectionPeer {
    fn name(&self) -> &'static str {
        if self.avx2 {
            "no selection: calibrate + centre of gravity of every pixel (AVX2)"
        } else {
            "no selection: calibrate + centre of gravity of every pixel (portable)"
        }
    }

    fn process(&mut self, frame: &[u16], out: &mut [PeerSlope]) {
        (self.kernel)(&self.plan, frame, &mut self.sums);
        self.results.clear();
        for (k, slot) in out.iter_mut().enumerate().take(self.sums.len()) {
            let result = self.result(k, self.sums[k]);
            *slot = PeerSlope {
                x: result.slope_x as f64 / 65536.0,
                y: result.slope_y as f64 / 65536.0,
                valid: result.valid,
            };
            self.results.push(result);
        }
    }
}

/// The running totals `D_i`: `i32` or `i64`.
trait Total: Copy + Default + std::ops::Add<Output = Self> {
    fn from_i32(value: i32) -> Self;
    fn to_i64(self) -> i64;
}

impl Total for i32 {
    #[inline(always)]
    fn from_i32(value: i32) -> Self {
        value
    }
    #[inline(always)]
    fn to_i64(self) -> i64 {
        self as i64
    }
}

impl Total for i64 {
    #[inline(always)]
    fn from_i32(value: i32) -> Self {
        value as i64
    }
    #[inline(always)]
    fn to_i64(self) -> i64 {
        self
    }
}

/// The kernel for `steps` with `i32` totals if `narrow`, compiled for AVX2
/// if allowed and this machine has it (and whether it is).
fn kernel(steps: Steps, narrow: bool, allow_avx2: bool) -> (Kernel, bool) {
    macro_rules! pick {
        ($b:literal, $g:literal, $t:ident) => {{
            #[cfg(target_arch = "x86_64")]
            if allow_avx2 && std::arch::is_x86_feature_detected!("avx2") {
                let avx2: Kernel = |plan, frame, sums| {
                    // SAFETY: this machine has AVX2 (detected above).
                    unsafe { frame_avx2::<$b, $g, $t>(plan, frame, sums) }
                };
                return (avx2, true);
            }
            (frame_sums::<$b, $g, $t> as Kernel, false)
        }};
    }
    let _ = allow_avx2; // Only x86-64 has a choice.
    match (steps, narrow) {
        (Steps::None, true) => pick!(false, false, i32),
        (Steps::None, false) => pick!(false, false, i64),
        (Steps::Background, true) => pick!(true, false, i32),
        (Steps::Background, false) => pick!(true, false, i64),
        (Steps::All, true) => pick!(true, true, i32),
        (Steps::All, false) => pick!(true, true, i64),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn frame_avx2<const B: bool, const G: bool, T: Total>(
    plan: &Plan,
    frame: &[u16],
    sums: &mut [Sums],
) {
    frame_sums::<B, G, T>(plan, frame, sums)
}

/// Every window's sums: background map if `B`, gain map and threshold if
/// `G`, running totals in `T`.
#[inline(always)]
fn frame_sums<const B: bool, const G: bool, T: Total>(
    plan: &Plan,
    frame: &[u16],
    sums: &mut [Sums],
) {
    for (w, out) in plan.windows.iter().zip(sums.iter_mut()) {
        *out = match w.width {
            8 => window_sums::<B, G, T, 8>(plan, frame, w),
            16 => window_sums::<B, G, T, 16>(plan, frame, w),
            32 => window_sums::<B, G, T, 32>(plan, frame, w),
            _ => window_sums::<B, G, T, 0>(plan, frame, w),
        };
    }
}

/// One window's sums; `W` its width if known at compile time, else 0.
#[inline(always)]
fn window_sums<const B: bool, const G: bool, T: Total, const W: usize>(
    plan: &Plan,
    frame: &[u16],
    w: &SubapertureWindow,
) -> Sums {
    let width = if W == 0 { w.width as usize } else { W };
    let height = w.height as usize;
    let mut columns = [0i32; MAX_SIDE];
    let mut totals = [T::default(); MAX_SIDE];
    let columns = &mut columns[..width];
    let totals = &mut totals[..width];
    for j in 0..height {
        let at = (w.y as usize + j) * plan.stride + w.x as usize;
        let raw = &frame[at..at + width];
        let background = if B {
            &plan.background[at..at + width]
        } else {
            &[][..]
        };
        let gain = if G {
            &plan.gain[at..at + width]
        } else {
            &[][..]
        };
        for i in 0..width {
            let mut p = (raw[i] as i32) << 4;
            if B {
                p -= background[i];
            }
            if G {
                p = ((p as i64 * gain[i] as i64) >> 12) as i32;
                if p < plan.threshold {
                    p = 0;
                }
            }
            let column = columns[i] + p;
            columns[i] = column;
            totals[i] = totals[i] + T::from_i32(column);
        }
    }
    let mut sums = Sums::default();
    let mut total = 0i64;
    for (i, (&c, &d)) in columns.iter().zip(totals.iter()).enumerate() {
        sums.flux += c as i64;
        sums.wi += i as i64 * c as i64;
        total += d.to_i64();
    }
    sums.wj = height as i64 * sums.flux - total;
    sums
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config_file::PixelCounts;
    use crate::engine_runner::HostEngine;
    use crate::sil::canary_config;

    /// The baseline against the engine with N = the window's pixel count,
    /// on spot frames of CANARY with the given calibration.
    fn agrees_with_the_engine(config: crate::config_file::ProcessingConfig) {
        let mut config = config;
        config.pixels = PixelCounts::All(256);
        let pixels = crate::bench::workloads::spot_frames(&config, 3, 11);
        let frames: Vec<&[u16]> = pixels.chunks(112 * 112).collect();
        let view = config.view();
        let want = HostEngine::new(view)
            .unwrap()
            .process(frames.iter().copied(), usize::MAX)
            .unwrap();
        for mut peer in [
            NoSelectionPeer::new(&view),
            NoSelectionPeer::portable(&view),
        ] {
            let mut slopes = vec![PeerSlope::default(); view.windows.len()];
            for (frame, want) in frames.iter().zip(&want) {
                peer.process(frame, &mut slopes);
                let mut want = want.clone();
                want.sort_by_key(|r| r.index);
                assert_eq!(peer.results, want, "{}", peer.name());
                assert!(peer.results.iter().any(|r| r.valid));
            }
        }
    }

    #[test]
    fn equals_the_engine_without_calibration() {
        let mut config = canary_config();
        config.background = None;
        agrees_with_the_engine(config);
    }

    #[test]
    fn equals_the_engine_with_a_background_map() {
        let config = canary_config();
        assert!(NoSelectionPeer::new(&config.view()).narrow_totals());
        agrees_with_the_engine(config);
    }

    #[test]
    fn equals_the_engine_with_background_gain_and_threshold() {
        let mut config = canary_config();
        let count = config.camera.pixel_count();
        config.background = Some((0..count).map(|k| 700 + (k % 37) as i32 * 9).collect());
        config.gain = Some((0..count).map(|k| 3000 + (k % 53) as u16 * 40).collect());
        config.threshold = Some(24);
        config.min_flux = 100;
        config.reference_slopes = Some((0..49).map(|k| [k * 1000 - 7, 3 - k * 500]).collect());
        agrees_with_the_engine(config);
    }

    #[test]
    fn equals_the_engine_with_wide_totals_and_odd_widths() {
        // A full-range background and gain force i64 totals; 13-pixel
        // windows take the kernel of any width.
        let mut config = canary_config();
        let count = config.camera.pixel_count();
        config.background = Some((0..count).map(|k| (k as i32 % 3 - 1) << 20).collect());
        config.gain = Some(vec![65535; count]);
        for w in &mut config.windows {
            w.width = 13;
        }
        config.grid = None;
        assert!(!NoSelectionPeer::new(&config.view()).narrow_totals());
        agrees_with_the_engine(config);
    }
}
