//! What recorded frames say about the conditions (`brightpix tune --frames`):
//! signal per sub-aperture, background, read noise and spot size.
//!
//! - Per camera pixel, the mean and variance over the frames (counts).
//! - **Dark pixels**, in order of preference: camera pixels outside every
//!   window; else the pixels of windows whose signal is below 10% of the
//!   typical lit window (unlit sub-apertures); else, in every window, the
//!   quarter of the pixels with the lowest mean (then the read noise is an
//!   upper bound: some light reaches them).
//! - **Read noise**: the square root of the median variance of the dark
//!   pixels, less the 1/12 count^2 of digitisation, times the gain.
//! - **Background**: the mean of the dark pixels minus the configuration's
//!   background map, i.e. what calibration leaves (`background_error`).
//! - **Signal**: per window, the sum of its pixels' means less the
//!   configuration's background and the residual, times the gain.
//! - **Spot size**: the FWHM (the diameter of a disc with the area above
//!   half maximum, interpolated between pixel centres) of the
//!   shift-and-add image: every frame's window re-centred on its
//!   brightest-pixel centre of gravity (N = 20, next subtracted) to the
//!   nearest pixel and summed ([`shift_and_add_fwhm`]).
//!   The same measure on simulated frames fits r0 (`tune`).

use anyhow::{bail, Result};

use crate::config_file::ProcessingConfig;
use crate::io::FrameCube;

/// What [`measure`] estimated.
#[derive(Clone, Debug)]
pub struct Measured {
    pub frames: usize,
    /// Detected photo-electrons per frame, per window.
    pub photons: Vec<f64>,
    /// Mean of the dark pixels minus the configuration's background (counts).
    pub background_error_counts: f64,
    /// Read noise (e- rms).
    pub read_noise_e: f64,
    /// Number of dark pixels used, and where they came from.
    pub dark_pixels: usize,
    pub dark_source: &'static str,
    /// FWHM of the shift-and-add spot of the lit windows (pixels).
    pub spot_fwhm_px: f64,
}

/// The brightest-pixel centre of gravity (N = 20, the 21st subtracted) of a
/// `size x size` calibrated image, pixels from the corner.
fn bright_centroid(img: &[f64], size: usize) -> Option<[f64; 2]> {
    let mut sorted: Vec<f64> = img.to_vec();
    sorted.sort_by(|a, b| b.total_cmp(a));
    let n = 20.min(sorted.len() - 1);
    let level = sorted[n];
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for (i, &v) in img.iter().enumerate() {
        let w = (v - level).max(0.0);
        sx += w * (i % size) as f64;
        sy += w * (i / size) as f64;
        s += w;
    }
    (s > 0.0).then(|| [sx / s, sy / s])
}

/// FWHM (pixels) of the shift-and-add of `images` (each `size x size`,
/// background-subtracted): each re-centred to the nearest pixel on its
/// brightest-pixel centre of gravity, summed on a grid twice the size; the
/// diameter of the disc whose area is the area above half the peak, the
/// image interpolated bilinearly between pixel centres and sampled 8 x 8
/// times a pixel. (Counting whole pixels above half the peak moved in steps
/// of the spot sizes tune meets, 1-3 pixels: 1.13, 2.26, 2.52, 3.19, so
/// that r0 fitted anywhere within a step.)
pub fn shift_and_add_fwhm<'a>(images: impl Iterator<Item = &'a [f64]>, size: usize) -> f64 {
    let big = 2 * size;
    let mut acc = vec![0.0; big * big];
    for img in images {
        let Some([cx, cy]) = bright_centroid(img, size) else {
            continue;
        };
        let (ox, oy) = (
            size as i64 - cx.round() as i64,
            size as i64 - cy.round() as i64,
        );
        for (i, &v) in img.iter().enumerate() {
            let x = (i % size) as i64 + ox;
            let y = (i / size) as i64 + oy;
            if (0..big as i64).contains(&x) && (0..big as i64).contains(&y) {
                acc[y as usize * big + x as usize] += v;
            }
        }
    }
    let peak = acc.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if peak <= 0.0 {
        return f64::NAN;
    }
    const SAMPLES: usize = 8;
    let half = peak / 2.0;
    let mut above = 0usize;
    for y in 0..big - 1 {
        for x in 0..big - 1 {
            let at = y * big + x;
            let (a, b, c, d) = (acc[at], acc[at + 1], acc[at + big], acc[at + big + 1]);
            if a.max(b).max(c).max(d) < half {
                continue;
            }
            for sy in 0..SAMPLES {
                let fy = (sy as f64 + 0.5) / SAMPLES as f64;
                let (left, right) = (a + (c - a) * fy, b + (d - b) * fy);
                for sx in 0..SAMPLES {
                    let fx = (sx as f64 + 0.5) / SAMPLES as f64;
                    above += (left + (right - left) * fx >= half) as usize;
                }
            }
        }
    }
    let area = above as f64 / (SAMPLES * SAMPLES) as f64;
    2.0 * (area / std::f64::consts::PI).sqrt()
}

/// Estimates the conditions from `cube` under `config` (its windows and
/// background map), with `gain` electrons per count.
pub fn measure(config: &ProcessingConfig, cube: &FrameCube, gain: f64) -> Result<Measured> {
    let (w, h) = (cube.shape.width, cube.shape.height);
    let frames = cube.shape.frames;
    if frames < 2 {
        bail!("recorded frames: need at least 2 frames to estimate noise, the file has {frames}");
    }
    let n = w * h;
    let (mut mean, mut m2) = (vec![0.0f64; n], vec![0.0f64; n]);
    // Sums over the even and the odd frames apart (see `level` below).
    let mut halves = [vec![0.0f64; n], vec![0.0f64; n]];
    for (k, frame) in cube.frames().enumerate() {
        let half = &mut halves[k % 2];
        let k = (k + 1) as f64;
        for i in 0..n {
            let v = frame[i] as f64;
            let d = v - mean[i];
            mean[i] += d / k;
            m2[i] += d * (v - mean[i]);
            half[i] += v;
        }
    }
    let var: Vec<f64> = m2.iter().map(|v| v / (frames - 1) as f64).collect();
    let bg: Vec<f64> = match &config.background {
        Some(b) => b.iter().map(|&v| v as f64 / 16.0).collect(),
        None => vec![0.0; n],
    };
    let cal: Vec<f64> = mean.iter().zip(&bg).map(|(m, b)| m - b).collect();
    let window_pixels = |k: usize| {
        let win = config.windows[k];
        (win.y as usize..(win.y + win.height) as usize).flat_map(move |y| {
            (win.x as usize..(win.x + win.width) as usize).map(move |x| y * w + x)
        })
    };
    let mut in_window = vec![false; n];
    for k in 0..config.windows.len() {
        for i in window_pixels(k) {
            in_window[i] = true;
        }
    }
    // Raw window sums (before the residual background), and a first floor.
    let raw_signal: Vec<f64> = (0..config.windows.len())
        .map(|k| window_pixels(k).map(|i| cal[i]).sum())
        .collect();
    let outside: Vec<usize> = (0..n).filter(|&i| !in_window[i]).collect();
    let typical = {
        let mut s = raw_signal.clone();
        s.sort_by(f64::total_cmp);
        let top = &s[s.len() / 2..];
        top[top.len() / 2]
    };
    let unlit: Vec<usize> = (0..config.windows.len())
        .filter(|&k| raw_signal[k] < 0.1 * typical)
        .collect();
    // `dark` gives the read noise (their temporal variance) and the
    // residual background (their mean). Real dark pixels give both.
    // Without any, each window's faintest quarter stands in: by their mean
    // over all frames for the variance (with Gaussian noise a pixel's
    // sample mean and variance are independent, so the choice does not
    // bias it), but for the level the quarter is chosen on the even frames
    // and its level read on the odd ones, so that the noise that made a
    // pixel look faint does not pull the level down (chosen and read on the
    // same frames, -0.32 counts at 2 e- over 30 frames: 83 photons too
    // many in a 16x16 window).
    let (dark, dark_source, residual): (Vec<usize>, &'static str, Option<f64>) = if outside.len()
        >= 16
    {
        (outside, "camera pixels outside every window", None)
    } else if !unlit.is_empty() {
        (
            unlit.iter().flat_map(|&k| window_pixels(k)).collect(),
            "the pixels of unlit windows (signal below 10% of a typical window)",
            None,
        )
    } else {
        let faintest = |key: &[f64]| -> Vec<usize> {
            let mut v = Vec::new();
            for k in 0..config.windows.len() {
                let mut px: Vec<usize> = window_pixels(k).collect();
                px.sort_by(|&a, &b| key[a].total_cmp(&key[b]));
                v.extend_from_slice(&px[..px.len().div_ceil(4)]);
            }
            v
        };
        let odd = (frames / 2) as f64;
        let level = faintest(&halves[0]);
        let residual = level
            .iter()
            .map(|&i| halves[1][i] / odd - bg[i])
            .sum::<f64>()
            / level.len() as f64;
        (
                faintest(&cal),
                "the faintest quarter of every window's pixels (no dark pixels: the read noise is an upper bound)",
                Some(residual),
            )
    };
    let mut dark_var: Vec<f64> = dark.iter().map(|&i| var[i]).collect();
    dark_var.sort_by(f64::total_cmp);
    let median_var = dark_var[dark_var.len() / 2];
    let read_noise_counts = (median_var - 1.0 / 12.0).max(0.0).sqrt();
    let residual =
        residual.unwrap_or_else(|| dark.iter().map(|&i| cal[i]).sum::<f64>() / dark.len() as f64);
    let photons: Vec<f64> = (0..config.windows.len())
        .map(|k| window_pixels(k).map(|i| cal[i] - residual).sum::<f64>() * gain)
        .collect();

    // Spot size from the lit windows of up to 400 frames.
    let lit: Vec<usize> = (0..config.windows.len())
        .filter(|&k| photons[k] >= 0.5 * typical * gain)
        .collect();
    let mut images = Vec::new();
    let step = (frames / 400).max(1);
    for f in (0..frames).step_by(step) {
        let frame = cube.frame(f);
        for &k in &lit {
            let win = config.windows[k];
            if win.width != config.windows[lit[0]].width {
                continue;
            }
            images.push(
                window_pixels(k)
                    .map(|i| frame[i] as f64 - bg[i] - residual)
                    .collect::<Vec<f64>>(),
            );
        }
    }
    let size = lit.first().map_or(0, |&k| config.windows[k].width as usize);
    let spot_fwhm_px = if size > 0 {
        shift_and_add_fwhm(images.iter().map(|v| v.as_slice()), size)
    } else {
        f64::NAN
    };
    Ok(Measured {
        frames,
        photons,
        background_error_counts: residual,
        read_noise_e: read_noise_counts * gain,
        dark_pixels: dark.len(),
        dark_source,
        spot_fwhm_px,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::FrameShape;
    use crate::simulator::{SimulationParams, Simulator};

    /// A CANARY camera whose 49 windows are all lit and cover it: no dark
    /// pixel anywhere.
    fn all_lit(read_noise_e: f64, frames: usize) -> (ProcessingConfig, FrameCube) {
        let config = ProcessingConfig::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/canary.toml"
        ))
        .unwrap();
        let sim = Simulator::new(SimulationParams {
            read_noise_e,
            ..SimulationParams::canary()
        })
        .unwrap();
        let run = crate::sil::simulate_tiled(&sim, config.camera, 7, 7, frames, 2);
        let cube = FrameCube {
            shape: FrameShape {
                frames,
                height: 112,
                width: 112,
            },
            pixels: run.frames.into_iter().flatten().collect(),
        };
        (config, cube)
    }

    /// The fitted r0's simulated spot has the measured FWHM: the measure
    /// interpolates between pixels, so it does not move in whole-pixel
    /// steps (it did: 2.52 fitted against 2.26 measured here, with r0
    /// anywhere from 0.11 to 0.135 m fitting).
    #[test]
    fn the_spot_size_fits_without_steps() {
        use crate::evaluation::tune::TuneRequest;
        let (config, cube) = all_lit(4.0, 30);
        let request = TuneRequest {
            frames: 20,
            ..TuneRequest::default()
        };
        let prepared = request.prepare(&config, Some(&cube)).unwrap();
        let fit = prepared.fitted_r0.unwrap();
        assert!(
            (fit.fitted_fwhm_px - fit.measured_fwhm_px).abs() < 0.1,
            "{fit:?}"
        );
        // Gaussian spots 0.2 pixel apart in FWHM measure 0.2 apart (within
        // the interpolation's bias), none the same.
        let size = 16;
        let measured: Vec<f64> = [1.6, 1.8, 2.0, 2.2, 2.4]
            .iter()
            .map(|&width: &f64| {
                let sigma = width / 2.3548;
                let image: Vec<f64> = (0..size * size)
                    .map(|i| {
                        let (x, y) = ((i % size) as f64 - 8.0, (i / size) as f64 - 8.0);
                        (-(x * x + y * y) / (2.0 * sigma * sigma)).exp()
                    })
                    .collect();
                shift_and_add_fwhm([image.as_slice()].into_iter(), size)
            })
            .collect();
        for pair in measured.windows(2) {
            let step = pair[1] - pair[0];
            assert!((0.1..0.3).contains(&step), "{measured:?}");
        }
    }

    /// Without dark pixels the level comes from each window's faintest
    /// quarter: chosen on some frames and read on others, it does not
    /// depend on how many frames were recorded (the spot's halo in those
    /// pixels is light, and still counts as background: a few percent of
    /// the photons). Chosen and read on the same frames, 30 frames of 4 e-
    /// read noise gave 397 photons for 200 simulated, 200 frames 261.
    #[test]
    fn without_dark_pixels_the_photons_do_not_depend_on_the_frame_count() {
        let mut residuals = Vec::new();
        for frames in [30, 200] {
            let (config, cube) = all_lit(4.0, frames);
            let m = measure(&config, &cube, 1.0).unwrap();
            assert!(m.dark_source.starts_with("the faintest quarter"));
            assert!((m.read_noise_e - 4.0).abs() < 0.2, "{}", m.read_noise_e);
            let mut p = m.photons.clone();
            p.sort_by(f64::total_cmp);
            let fully_lit = p[p.len() * 3 / 4];
            assert!(
                (160.0..=210.0).contains(&fully_lit),
                "{frames} frames: {fully_lit}"
            );
            residuals.push(m.background_error_counts);
        }
        assert!((residuals[0] - residuals[1]).abs() < 0.1, "{residuals:?}");
    }
}
