//! `view --replay`: recorded results (the .npy set or the FITS file that
//! `process`, `stream`, `capture` and `rig stream` write) played back at a
//! chosen rate, with the recorded frames beside them when given. A
//! recording of another configuration (other sub-apertures, another
//! digest in its provenance, another camera for the frames) is refused
//! with what differs.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::SlopeEntry;

use super::hub::{Health, Hub, Setup};
use crate::config_file::ProcessingConfig;
use crate::io::{read_array, FrameSource};

/// Recorded results, per frame per sub-aperture.
#[derive(Debug)]
pub struct Recording {
    pub frames: usize,
    pub subapertures: usize,
    /// `[x, y]` pixels per sub-aperture per frame (pairs layout).
    pub slopes: Vec<f64>,
    /// Counts; NaN where not recorded.
    pub flux: Vec<f64>,
    pub valid: Vec<bool>,
    /// `BPCFGDIG` of the provenance, if there is one.
    pub digest: Option<u32>,
}

impl Recording {
    /// Frame `f` as the device sent it (2^-16 pixel, 1/16 count); `None`
    /// for a sub-aperture whose slopes are NaN (dropped when recorded).
    pub fn frame(&self, f: usize) -> Vec<Option<SlopeEntry>> {
        let s = self.subapertures;
        (0..s)
            .map(|k| {
                let at = f * s + k;
                let (x, y) = (self.slopes[2 * at], self.slopes[2 * at + 1]);
                if !(x.is_finite() && y.is_finite()) {
                    return None;
                }
                let flux = self.flux[at];
                Some(SlopeEntry {
                    index: k as u16,
                    slope_x: (x * 65536.0).round() as i32,
                    slope_y: (y * 65536.0).round() as i32,
                    flux: if flux.is_finite() {
                        (flux * 16.0).round() as i64
                    } else {
                        0
                    },
                    valid: self.valid[at],
                })
            })
            .collect()
    }
}

/// The companion files of an .npy set: `x.flux.npy`, `x.valid.npy`, `x.json`.
fn companions(path: &Path) -> [PathBuf; 3] {
    let stem = path.with_extension("");
    let name = |suffix: &str| {
        let mut s = stem.clone().into_os_string();
        s.push(suffix);
        PathBuf::from(s)
    };
    [name(".flux.npy"), name(".valid.npy"), name(".json")]
}

/// Reads a recording and checks it against `config`.
pub fn load(path: &Path, config: &ProcessingConfig, config_name: &str) -> Result<Recording> {
    let is_fits = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "fits" | "fit" | "fts"));
    let (slopes, flux, valid, digest) = if is_fits {
        read_fits(path)?
    } else {
        let slopes = read_array(path)
            .with_context(|| format!("reading the recording {}", path.display()))?;
        let [flux_path, valid_path, json_path] = companions(path);
        let flux = flux_path
            .exists()
            .then(|| read_array(&flux_path))
            .transpose()?;
        let valid = valid_path
            .exists()
            .then(|| read_array(&valid_path))
            .transpose()?;
        let digest = std::fs::read_to_string(&json_path)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["bpcfgdig"].as_str().and_then(parse_hex));
        (slopes, flux.map(|a| a.data), valid.map(|a| a.data), digest)
    };
    let s = config.windows.len();
    let (frames, per_frame, pairs) = match slopes.shape.as_slice() {
        [f, k, 2] => (*f, *k, true),
        [f, k] if k % 2 == 0 => (*f, k / 2, false),
        shape => bail!(
            "{}: slopes of shape {} are neither (frames, sub-apertures, 2) nor (frames, 2 x sub-apertures)",
            path.display(),
            crate::io::shape_string(shape)
        ),
    };
    if per_frame != s {
        bail!(
            "{} is a recording of another configuration: {per_frame} sub-apertures a frame, where {config_name} has {s}",
            path.display()
        );
    }
    let expected = brightpix_protocol::wire::tables::config_digest(&config.view());
    if let Some(d) = digest.filter(|d| *d != expected) {
        bail!(
            "{} is a recording of another configuration: its provenance gives digest {d:#010x}, {config_name} has {expected:#010x}",
            path.display()
        );
    }
    let slopes = if pairs {
        slopes.data
    } else {
        // Vector layout: [x_0 .. x_S-1, y_0 .. y_S-1] per frame.
        let mut out = Vec::with_capacity(slopes.data.len());
        for row in slopes.data.chunks(2 * s) {
            for k in 0..s {
                out.extend([row[k], row[s + k]]);
            }
        }
        out
    };
    let count = frames * s;
    let flux = flux
        .filter(|f| f.len() == count)
        .unwrap_or_else(|| vec![f64::NAN; count]);
    let valid = match valid.filter(|v| v.len() == count) {
        Some(v) => v.iter().map(|&x| x != 0.0).collect(),
        None => slopes.chunks(2).map(|p| p[0].is_finite()).collect(),
    };
    Ok(Recording {
        frames,
        subapertures: s,
        slopes,
        flux,
        valid,
        digest,
    })
}

fn parse_hex(text: &str) -> Option<u32> {
    u32::from_str_radix(text.trim().trim_start_matches("0x"), 16).ok()
}

type Arrays = (
    crate::io::Array,
    Option<Vec<f64>>,
    Option<Vec<f64>>,
    Option<u32>,
);

/// The SLOPES, FLUX and VALID extensions and BPCFGDIG of a results FITS
/// file (docs/OUTPUTS.md).
fn read_fits(path: &Path) -> Result<Arrays> {
    use fitsio::hdu::HduInfo;
    let mut file =
        fitsio::FitsFile::open(path).with_context(|| format!("opening {}", path.display()))?;
    let mut image = |name: &str| -> Result<Option<crate::io::Array>> {
        let Ok(hdu) = file.hdu(name) else {
            return Ok(None);
        };
        let shape = match &hdu.info {
            HduInfo::ImageInfo { shape, .. } => shape.clone(),
            _ => bail!("{}: extension {name} is not an image", path.display()),
        };
        let data: Vec<f64> = hdu
            .read_image(&mut file)
            .with_context(|| format!("reading extension {name} of {}", path.display()))?;
        Ok(Some(crate::io::Array { shape, data }))
    };
    let slopes = image("SLOPES")?.with_context(|| {
        format!(
            "{} has no SLOPES extension: not a brightpix results file (docs/OUTPUTS.md)",
            path.display()
        )
    })?;
    let flux = image("FLUX")?.map(|a| a.data);
    let valid = image("VALID")?.map(|a| a.data);
    let digest = file
        .primary_hdu()
        .ok()
        .and_then(|h| h.read_key::<String>(&mut file, "BPCFGDIG").ok())
        .and_then(|t| parse_hex(&t));
    Ok((slopes, flux, valid, digest))
}

/// A replay to run.
pub struct Replay {
    pub recording: Recording,
    pub path: PathBuf,
    pub config: ProcessingConfig,
    pub config_name: String,
    /// The recorded frames, checked against the configuration's camera.
    pub frames: Option<FrameSource>,
    pub rate: f64,
}

/// Opens `frames` for a replay: the configuration's camera, or an error.
pub fn open_frames(
    path: &Path,
    hdu: Option<&str>,
    config: &ProcessingConfig,
) -> Result<FrameSource> {
    let mut source = FrameSource::open_hdu(path, hdu)?;
    source.set_camera(&config.camera).with_context(|| {
        format!(
            "{} does not hold frames of the configuration's camera",
            path.display()
        )
    })?;
    Ok(source)
}

/// Plays the recording over and over until `stop()`.
pub fn run(replay: &mut Replay, hub: &Hub, stop: &dyn Fn() -> bool) -> Result<()> {
    if !(replay.rate.is_finite() && replay.rate > 0.0) {
        bail!(
            "--rate {}: must be a positive number of frames per second",
            replay.rate
        );
    }
    let r = &replay.recording;
    if r.frames == 0 {
        bail!("{} holds no frames", replay.path.display());
    }
    let mut setup = Setup::new(
        format!(
            "replay of {} at {} frames/s",
            replay.path.display(),
            replay.rate
        ),
        replay.config_name.clone(),
        replay.config.clone(),
    );
    setup.pixels = replay.frames.is_some();
    hub.set_setup(setup);
    let period = Duration::from_secs_f64(1.0 / replay.rate);
    let started = Instant::now();
    let mut pixels = Vec::new();
    let mut k = 0u64;
    let mut health = Health::default();
    while !stop() {
        let f = (k % r.frames as u64) as usize;
        let results = r.frame(f);
        let complete = results.iter().all(Option::is_some);
        // Reading a frame costs a file read: only when a sample is due.
        let frame_pixels = match &mut replay.frames {
            Some(source) if f < source.len() && hub.pixels_due() => {
                source.read_frame_into(f, &mut pixels)?;
                Some(pixels.as_slice())
            }
            _ => None,
        };
        hub.offer(f as u64, !complete, || results, frame_pixels);
        health.frames_processed = Some(k + 1);
        health.config_digest = r.digest;
        if k.is_multiple_of(8) {
            hub.set_health(health.clone());
        }
        k += 1;
        let due = started + period.mul_f64(k as f64);
        if let Some(rest) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(rest);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::{write_results, Layout, Provenance, Raw, Results};

    fn record(dir: &Path, config: &ProcessingConfig, name: &str, layout: Layout) -> PathBuf {
        let s = config.windows.len();
        let mut results = Results::new(s);
        for f in 0..3 {
            for k in 0..s {
                results.push((k != 1 || f != 2).then_some(Raw {
                    slope_x: (k as i32) << 14,
                    slope_y: -(f << 15),
                    flux: 160,
                    valid: k % 7 != 0,
                }));
            }
        }
        let path = dir.join(name);
        let provenance = Provenance::of("test", &config.view(), None);
        write_results(&path, &results, &provenance, layout).unwrap();
        path
    }

    #[test]
    fn a_recording_plays_back_as_recorded() {
        let dir = crate::sim_device::temp_dir("brightpix-replay-test").unwrap();
        let config = crate::sil::canary_config();
        for (name, layout) in [
            ("r.npy", Layout::Pairs),
            ("v.npy", Layout::Vector),
            ("r.fits", Layout::Pairs),
        ] {
            let path = record(&dir, &config, name, layout);
            let r = load(&path, &config, "canary").unwrap();
            assert_eq!((r.frames, r.subapertures), (3, 49), "{name}");
            let frame = r.frame(2);
            assert_eq!(frame[1], None, "{name}: a dropped result stays missing");
            let e = frame[5].unwrap();
            assert_eq!(
                (e.slope_x, e.slope_y, e.flux, e.valid),
                (5 << 14, -(2 << 15), 160, true),
                "{name}"
            );
            assert!(!frame[7].unwrap().valid, "{name}");
        }
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn a_recording_of_another_configuration_is_refused() {
        let dir = crate::sim_device::temp_dir("brightpix-replay-test").unwrap();
        let config = crate::sil::canary_config();
        let path = record(&dir, &config, "r.npy", Layout::Pairs);
        // Fewer sub-apertures.
        let mut other = config.clone();
        other.windows.truncate(36);
        other.grid = None;
        let error = load(&path, &other, "other.toml").unwrap_err().to_string();
        assert!(
            error.contains("another configuration") && error.contains("49 sub-apertures"),
            "{error}"
        );
        // Same geometry, another N: the digest differs.
        let mut other = config.clone();
        other.pixels = crate::config_file::PixelCounts::All(10);
        let error = load(&path, &other, "n10.toml").unwrap_err().to_string();
        assert!(error.contains("digest"), "{error}");
        let _ = std::fs::remove_dir_all(dir);
    }
}
