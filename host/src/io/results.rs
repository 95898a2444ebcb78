//! What the result-writing commands (`process`, `stream`, `capture`) write:
//! slopes, flux and validity of every sub-aperture of every frame, with the
//! provenance that traces them back to a configuration and a build.
//!
//! The format follows the extension of `--out` (docs/OUTPUTS.md):
//!
//! - `.npy`: a set of files, `NAME.npy` (slopes), `NAME.flux.npy`,
//!   `NAME.valid.npy` and `NAME.json` (the provenance);
//! - `.fits` / `.fit` / `.fts`: one file (cfitsio), an empty primary HDU
//!   whose header holds the provenance keywords, and the image extensions
//!   `SLOPES`, `FLUX`, `VALID`, each with `BUNIT`;
//! - `.csv`: one row per frame and sub-aperture, after `#` lines holding
//!   the provenance;
//! - `.aot.fits`: the Adaptive Optics Telemetry standard (AOT), one
//!   Shack-Hartmann sensor with its geometry, measurements and time
//!   ([`super::aot`]).
//!
//! Slopes are float64 pixels, `[x, y]` reference slopes subtracted, in the
//! [`Layout`] asked for; flux is float64 counts (calibrated, above the
//! selection's subtracted level); validity is uint8 0/1. A sub-aperture the
//! device sent nothing for (a dropped frame) has NaN slopes and flux and
//! validity 0.

use std::io::Write;
use std::path::{Path, PathBuf};

use brightpix_protocol::wire::tables::config_digest;
use brightpix_protocol::{Config, PixelCount, SelectionRule, SubapertureWindow};

use super::output::Staged;
use super::{npy, IoError};

/// How the slopes of one frame are laid out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Layout {
    /// Shape (frames, sub-apertures, 2): `[x, y]` per sub-aperture.
    #[default]
    Pairs,
    /// Shape (frames, 2 x sub-apertures): `[x_0 .. x_S-1, y_0 .. y_S-1]`,
    /// the slope vector of AO codes (DARC, COMPASS, soapy).
    Vector,
}

impl Layout {
    /// One frame's slopes, `[x, y]` per sub-aperture, in this layout.
    pub fn arrange(self, frame: &[f64]) -> Vec<f64> {
        match self {
            Layout::Pairs => frame.to_vec(),
            Layout::Vector => {
                let mut out = Vec::with_capacity(frame.len());
                out.extend(frame.iter().step_by(2));
                out.extend(frame.iter().skip(1).step_by(2));
                out
            }
        }
    }

    fn name(self) -> &'static str {
        match self {
            Layout::Pairs => "pairs",
            Layout::Vector => "vector",
        }
    }
}

/// The output formats of results, by the extension of the path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResultsFormat {
    Npy,
    Fits,
    Csv,
    /// A FITS file in the AOT layout: a name ending in `.aot.fits`.
    Aot,
}

impl ResultsFormat {
    pub fn from_path(path: &Path) -> Result<Self, IoError> {
        if super::aot::is_aot_name(path) {
            return Ok(ResultsFormat::Aot);
        }
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("npy") => Ok(ResultsFormat::Npy),
            Some("fits" | "fit" | "fts") => Ok(ResultsFormat::Fits),
            Some("csv") => Ok(ResultsFormat::Csv),
            _ => Err(IoError::unexpected(
                path,
                "an output of unknown type",
                "a .npy (with .flux.npy, .valid.npy and .json beside it), .fits/.fit/.fts, .aot.fits (AOT) or .csv path",
            )),
        }
    }
}

/// What made a set of results: written into every output.
#[derive(Clone, Debug, PartialEq)]
pub struct Provenance {
    /// The command and what computed the slopes, e.g. "process (streaming engine)".
    pub producer: String,
    /// The configuration file, if any (`capture` without `--config` has none).
    pub config_file: Option<PathBuf>,
    /// CRC-32/ISO-HDLC of the configuration file's bytes.
    pub config_file_crc: Option<u32>,
    /// The configuration's digest (PROTOCOL.md §7): what a device reports
    /// in `Status.config_digest` when it runs this configuration.
    pub config_digest: Option<u32>,
    /// The device's id of the configuration (its upload id), if a device ran it.
    pub config_id: Option<u32>,
    /// Selection rule (SPEC.md names: threshold, subtract-next, ...).
    pub rule: Option<String>,
    /// N, or `None` with `per_subaperture` for a list.
    pub pixels: Option<u16>,
    pub per_subaperture: bool,
    /// M of subtract-mean.
    pub mean_count: Option<u16>,
    pub bit_depth: Option<u8>,
    /// Where the frames came from (a file, a device's camera).
    pub frames_source: Option<String>,
    /// Index of the first frame written, in the source.
    pub first_frame: u64,
    /// For a rig's merged results: which board computed which
    /// sub-apertures (`board-0 0-20; board-1 21-34; ...`).
    pub rig: Option<String>,
    /// Frames (from the first written) computed with this configuration
    /// for certain, when the device's configuration changed during the
    /// run (another client took it over): the rest are not.
    pub trusted_frames: Option<u64>,
    /// The calibration applied ("background map; gain map; threshold 3
    /// counts"), if the configuration is known.
    pub calibration: Option<String>,
    /// The sub-aperture windows, in output order (AOT's sensor geometry);
    /// empty when the configuration is not known.
    pub windows: Vec<SubapertureWindow>,
    /// Reference slopes `[x, y]` in 2^-16 pixel, one per window, if any.
    pub reference_slopes: Option<Vec<[i32; 2]>>,
}

impl Provenance {
    /// The provenance of results computed with `config`, loaded from `file`.
    pub fn of(producer: impl Into<String>, config: &Config<'_>, file: Option<&Path>) -> Self {
        let (rule, mean_count) = match config.selection.rule {
            SelectionRule::Threshold => ("threshold", None),
            SelectionRule::SubtractNext => ("subtract-next", None),
            SelectionRule::SubtractNextDistinct => ("subtract-next-distinct", None),
            SelectionRule::SubtractMean { count } => ("subtract-mean", Some(count)),
        };
        let (pixels, per_subaperture) = match config.selection.count {
            PixelCount::All(n) => (Some(n), false),
            PixelCount::PerSubaperture(_) => (None, true),
        };
        Provenance {
            producer: producer.into(),
            config_file: file.map(Path::to_path_buf),
            config_file_crc: file
                .and_then(|f| std::fs::read(f).ok())
                .map(|bytes| brightpix_protocol::wire::CRC32.checksum(&bytes)),
            config_digest: Some(config_digest(config)),
            config_id: None,
            rule: Some(rule.into()),
            pixels,
            per_subaperture,
            mean_count,
            bit_depth: Some(config.camera.bit_depth),
            frames_source: None,
            first_frame: 0,
            rig: None,
            trusted_frames: None,
            calibration: Some(calibration_text(config)),
            windows: config.windows.to_vec(),
            reference_slopes: config.centroid.reference_slopes.map(<[_]>::to_vec),
        }
    }

    /// A configuration the host does not know (`capture` of a device's
    /// active configuration): only what the device reports.
    pub fn unknown_config(producer: impl Into<String>, config_id: Option<u32>) -> Self {
        Provenance {
            producer: producer.into(),
            config_file: None,
            config_file_crc: None,
            config_digest: None,
            config_id,
            rule: None,
            pixels: None,
            per_subaperture: false,
            mean_count: None,
            bit_depth: None,
            frames_source: None,
            first_frame: 0,
            rig: None,
            trusted_frames: None,
            calibration: None,
            windows: Vec::new(),
            reference_slopes: None,
        }
    }

    /// `(FITS keyword, value, comment)`, in the order written; the CSV
    /// header and the `.json` use the same names, lower-cased.
    pub fn keywords(
        &self,
        results: &Results,
        layout: Layout,
    ) -> Vec<(&'static str, Value, &'static str)> {
        let hex = |v: Option<u32>| v.map(|v| Value::Text(format!("{v:#010x}")));
        let mut all = vec![
            (
                "BPVERS",
                Some(Value::Text(env!("CARGO_PKG_VERSION").into())),
                "brightpix version",
            ),
            (
                "BPPROD",
                Some(Value::Text(self.producer.clone())),
                "what computed the slopes",
            ),
            (
                "BPRULE",
                self.rule.clone().map(Value::Text),
                "selection rule (SPEC.md)",
            ),
            (
                "BPNPIX",
                if self.per_subaperture {
                    Some(Value::Text("per sub-aperture".into()))
                } else {
                    self.pixels.map(|n| Value::Int(n.into()))
                },
                "N, pixels kept per sub-aperture",
            ),
            (
                "BPMEANC",
                self.mean_count.map(|m| Value::Int(m.into())),
                "M of subtract-mean",
            ),
            (
                "BPBITS",
                self.bit_depth.map(|b| Value::Int(b.into())),
                "camera bit depth",
            ),
            (
                "BPCALIB",
                self.calibration.clone().map(Value::Text),
                "calibration applied",
            ),
            ("BPCFGID", hex(self.config_id), "device's configuration id"),
            (
                "BPCFGDIG",
                hex(self.config_digest),
                "configuration digest (PROTOCOL.md 7)",
            ),
            (
                "BPCFGFIL",
                self.config_file
                    .as_ref()
                    .map(|p| Value::Text(p.display().to_string())),
                "configuration file",
            ),
            (
                "BPCFGCRC",
                hex(self.config_file_crc),
                "CRC-32 of the configuration file",
            ),
            (
                "BPSOURCE",
                self.frames_source.clone().map(Value::Text),
                "frames from",
            ),
            (
                "BPRIG",
                self.rig.clone().map(Value::Text),
                "rig: board and its sub-apertures",
            ),
            (
                "BPTRUST",
                self.trusted_frames.map(|n| Value::Int(n as i64)),
                "frames of this configuration; later: another's",
            ),
            (
                "BPFIRST",
                Some(Value::Int(self.first_frame as i64)),
                "first frame (0-based)",
            ),
            (
                "BPNFRAME",
                Some(Value::Int(results.frames() as i64)),
                "frames written",
            ),
            (
                "BPNSUB",
                Some(Value::Int(results.subapertures as i64)),
                "sub-apertures",
            ),
            (
                "BPLAYOUT",
                Some(Value::Text(layout.name().into())),
                "slopes layout (pairs or vector)",
            ),
        ];
        all.retain(|(_, v, _)| v.is_some());
        all.into_iter()
            .map(|(k, v, c)| (k, v.unwrap_or(Value::Int(0)), c))
            .collect()
    }
}

/// What the calibration of `config` does, in words and counts.
fn calibration_text(config: &Config<'_>) -> String {
    let c = &config.calibration;
    let mut parts = Vec::new();
    if c.background.is_some() {
        parts.push("background map".to_string());
    }
    if c.gain.is_some() {
        parts.push("gain map".to_string());
    }
    if let Some(t) = c.threshold {
        parts.push(format!("threshold {} counts", f64::from(t) / 16.0));
    }
    if parts.is_empty() {
        "none".into()
    } else {
        parts.join("; ")
    }
}

/// A provenance value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    Int(i64),
    Text(String),
}

impl Value {
    fn json(&self) -> serde_json::Value {
        match self {
            Value::Int(v) => (*v).into(),
            Value::Text(t) => t.clone().into(),
        }
    }
    fn text(&self) -> String {
        match self {
            Value::Int(v) => v.to_string(),
            Value::Text(t) => t.clone(),
        }
    }
}

/// Results of whole frames, in frame order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Results {
    pub subapertures: usize,
    /// `[x, y]` per sub-aperture per frame, pixels.
    pub slopes: Vec<f64>,
    /// Per sub-aperture per frame, counts.
    pub flux: Vec<f64>,
    /// Per sub-aperture per frame, 0 or 1.
    pub valid: Vec<u8>,
}

/// One sub-aperture's result in the engine's integers: slopes in 2^-16
/// pixel, flux in 1/16 count (SPEC.md §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Raw {
    pub slope_x: i32,
    pub slope_y: i32,
    pub flux: i64,
    pub valid: bool,
}

/// A device's result as it came on the wire (its index is its place).
impl From<brightpix_protocol::wire::SlopeEntry> for Raw {
    fn from(e: brightpix_protocol::wire::SlopeEntry) -> Raw {
        Raw {
            slope_x: e.slope_x,
            slope_y: e.slope_y,
            flux: e.flux,
            valid: e.valid,
        }
    }
}

impl Results {
    pub fn new(subapertures: usize) -> Self {
        Results {
            subapertures,
            ..Default::default()
        }
    }

    pub fn frames(&self) -> usize {
        self.valid.len().checked_div(self.subapertures).unwrap_or(0)
    }

    /// Appends one sub-aperture's result (`None`: nothing arrived for it).
    pub fn push(&mut self, raw: Option<Raw>) {
        match raw {
            Some(r) => {
                self.slopes.push(f64::from(r.slope_x) / 65536.0);
                self.slopes.push(f64::from(r.slope_y) / 65536.0);
                self.flux.push(r.flux as f64 / 16.0);
                self.valid.push(u8::from(r.valid));
            }
            None => {
                self.slopes.extend([f64::NAN, f64::NAN]);
                self.flux.push(f64::NAN);
                self.valid.push(0);
            }
        }
    }

    /// The slopes in `layout`, and their shape.
    pub fn slopes_in(&self, layout: Layout) -> (Vec<usize>, Vec<f64>) {
        let (frames, s) = (self.frames(), self.subapertures);
        match layout {
            Layout::Pairs => (vec![frames, s, 2], self.slopes.clone()),
            Layout::Vector => {
                let mut out = Vec::with_capacity(self.slopes.len());
                for frame in self.slopes.chunks_exact(2 * s.max(1)) {
                    out.extend(layout.arrange(frame));
                }
                (vec![frames, 2 * s], out)
            }
        }
    }

    /// Frames in which every sub-aperture is invalid.
    pub fn frames_all_invalid(&self) -> usize {
        self.valid
            .chunks(self.subapertures.max(1))
            .filter(|f| f.iter().all(|&v| v == 0))
            .count()
    }
}

/// The files a `.npy` output is made of: slopes, flux, validity, provenance.
pub fn npy_set(path: &Path) -> [PathBuf; 4] {
    let stem = path.with_extension("");
    let with = |suffix: &str| {
        let mut name = stem.as_os_str().to_owned();
        name.push(suffix);
        PathBuf::from(name)
    };
    [
        path.to_path_buf(),
        with(".flux.npy"),
        with(".valid.npy"),
        with(".json"),
    ]
}

/// Removes the companions of a `.npy` set (flux, validity, provenance) that
/// an earlier run left at `path`: a set being streamed anew must never be
/// read as one run's slopes beside another run's flux and provenance. (The
/// slopes file itself is replaced by the new run.) Other formats are one
/// file: nothing to do.
pub fn remove_stale_companions(path: &Path) -> Result<(), IoError> {
    if ResultsFormat::from_path(path)? != ResultsFormat::Npy {
        return Ok(());
    }
    for companion in &npy_set(path)[1..] {
        match std::fs::remove_file(companion) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(IoError::io(companion, e))
            }
            _ => {}
        }
    }
    Ok(())
}

/// Every file an output path stands for (the `.npy` set, or the path).
pub fn output_files(path: &Path) -> Result<Vec<PathBuf>, IoError> {
    Ok(match ResultsFormat::from_path(path)? {
        ResultsFormat::Npy => npy_set(path).to_vec(),
        _ => vec![path.to_path_buf()],
    })
}

/// [`check_outputs`](super::check_outputs) for results: each path's format
/// is known, and none of the files it stands for (the whole `.npy` set) is
/// an input or another output.
pub fn check_result_outputs(inputs: &[&Path], outputs: &[&Path]) -> Result<(), IoError> {
    // An input named as an output is the worse mistake: say that first.
    super::output::check_paths(inputs, outputs)?;
    let mut files = Vec::new();
    for out in outputs {
        files.extend(output_files(out)?);
    }
    let refs: Vec<&Path> = files.iter().map(PathBuf::as_path).collect();
    super::output::check_paths(inputs, &refs)
}

/// Writes `results` to `path` in the format of its extension, whole or not
/// at all: every file is staged, then all are moved into place.
pub fn write_results(
    path: &Path,
    results: &Results,
    provenance: &Provenance,
    layout: Layout,
) -> Result<Vec<PathBuf>, IoError> {
    let staged = stage_results(path, results, provenance, layout)?;
    let written = staged.iter().map(|s| s.target().to_path_buf()).collect();
    Staged::commit_all(staged)?;
    Ok(written)
}

/// [`write_results`] into temporary files, for the caller to commit with
/// its other outputs. AOT's measurements have one shape, whatever `layout`.
pub fn stage_results(
    path: &Path,
    results: &Results,
    provenance: &Provenance,
    layout: Layout,
) -> Result<Vec<Staged>, IoError> {
    let keywords = provenance.keywords(results, layout);
    let (shape, slopes) = results.slopes_in(layout);
    let frames = results.frames();
    let s = results.subapertures;
    Ok(match ResultsFormat::from_path(path)? {
        ResultsFormat::Npy => {
            let [slopes_path, flux_path, valid_path, json_path] = npy_set(path);
            vec![
                Staged::write(&slopes_path, |t| npy::write(t, &shape, &slopes))?,
                Staged::write(&flux_path, |t| npy::write(t, &[frames, s], &results.flux))?,
                Staged::write(&valid_path, |t| npy::write(t, &[frames, s], &results.valid))?,
                Staged::write(&json_path, |t| write_json(t, &keywords))?,
            ]
        }
        ResultsFormat::Fits => vec![Staged::write(path, |t| {
            super::fits_out::write_results(t, &keywords, &shape, &slopes, results)
        })?],
        ResultsFormat::Csv => vec![Staged::write(path, |t| write_csv(t, &keywords, results))?],
        ResultsFormat::Aot => vec![super::aot::stage(path, results, provenance, None)?],
    })
}

/// Completes the output of `stream --out`, whose slopes were appended
/// frame by frame to `path` (a `.npy`, or the primary image of a FITS
/// file) in `layout` as they arrived: `.npy` gains the rest of its set (flux,
/// validity, provenance); FITS gains the provenance keywords in its primary
/// header and the `FLUX` and `VALID` extensions (cfitsio). A `.csv` is
/// written whole here.
pub fn complete_streamed(
    path: &Path,
    results: &Results,
    provenance: &Provenance,
    layout: Layout,
) -> Result<(), IoError> {
    let keywords = provenance.keywords(results, layout);
    let (frames, s) = (results.frames(), results.subapertures);
    match ResultsFormat::from_path(path)? {
        ResultsFormat::Npy => {
            let [_, flux_path, valid_path, json_path] = npy_set(path);
            Staged::commit_all(vec![
                Staged::write(&flux_path, |t| npy::write(t, &[frames, s], &results.flux))?,
                Staged::write(&valid_path, |t| npy::write(t, &[frames, s], &results.valid))?,
                Staged::write(&json_path, |t| write_json(t, &keywords))?,
            ])
        }
        ResultsFormat::Fits => super::fits_out::add_to_streamed(path, &keywords, results),
        ResultsFormat::Csv | ResultsFormat::Aot => {
            write_results(path, results, provenance, layout).map(drop)
        }
    }
}

fn write_json(path: &Path, keywords: &[(&str, Value, &str)]) -> Result<(), IoError> {
    let mut map = serde_json::Map::new();
    for (k, v, _) in keywords {
        map.insert(k.to_ascii_lowercase(), v.json());
    }
    map.insert(
        "units".into(),
        serde_json::json!({"slopes": "pixel", "flux": "count", "valid": "0/1"}),
    );
    let text = serde_json::to_string_pretty(&serde_json::Value::Object(map)).unwrap_or_default();
    std::fs::write(path, text + "\n").map_err(|e| IoError::io(path, e))
}

/// The CSV header's column names.
pub const CSV_COLUMNS: &str = "frame,subaperture,slope_x,slope_y,flux,valid";

fn write_csv(
    path: &Path,
    keywords: &[(&str, Value, &str)],
    results: &Results,
) -> Result<(), IoError> {
    let file = std::fs::File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut out = std::io::BufWriter::new(file);
    let mut write = || -> std::io::Result<()> {
        for (k, v, comment) in keywords {
            writeln!(
                out,
                "# {}: {} ({comment})",
                k.to_ascii_lowercase(),
                v.text()
            )?;
        }
        writeln!(
            out,
            "# units: slope_x, slope_y pixel; flux count; valid 0/1"
        )?;
        writeln!(out, "{CSV_COLUMNS}")?;
        let s = results.subapertures.max(1);
        for (k, valid) in results.valid.iter().enumerate() {
            writeln!(
                out,
                "{},{},{},{},{},{}",
                provenance_frame(keywords) + (k / s) as u64,
                k % s,
                results.slopes[2 * k],
                results.slopes[2 * k + 1],
                results.flux[k],
                valid
            )?;
        }
        out.flush()
    };
    write().map_err(|e| IoError::io(path, e))
}

fn provenance_frame(keywords: &[(&str, Value, &str)]) -> u64 {
    keywords
        .iter()
        .find_map(|(k, v, _)| match (*k, v) {
            ("BPFIRST", Value::Int(first)) => Some(*first as u64),
            _ => None,
        })
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Results {
        let mut r = Results::new(3);
        for frame in 0..2i32 {
            for s in 0..3i32 {
                r.push(Some(Raw {
                    slope_x: (10 * frame + s) * 65536,
                    slope_y: -(10 * frame + s) * 32768,
                    flux: 16 * i64::from(100 + s),
                    valid: s != 1,
                }));
            }
        }
        r
    }

    #[test]
    fn the_vector_layout_is_all_x_then_all_y() {
        let r = sample();
        let (shape, v) = r.slopes_in(Layout::Vector);
        assert_eq!(shape, [2, 6]);
        assert_eq!(&v[..6], &[0.0, 1.0, 2.0, -0.0, -0.5, -1.0]);
        assert_eq!(&v[6..], &[10.0, 11.0, 12.0, -5.0, -5.5, -6.0]);
        let (shape, p) = r.slopes_in(Layout::Pairs);
        assert_eq!(shape, [2, 3, 2]);
        assert_eq!(&p[..4], &[0.0, -0.0, 1.0, -0.5]);
    }

    #[test]
    fn missing_results_are_nan_and_invalid() {
        let mut r = Results::new(2);
        r.push(None);
        r.push(None);
        assert_eq!(r.frames(), 1);
        assert!(r.slopes.iter().all(|v| v.is_nan()) && r.flux[0].is_nan());
        assert_eq!(r.valid, [0, 0]);
        assert_eq!(r.frames_all_invalid(), 1);
        assert_eq!(sample().frames_all_invalid(), 0);
    }

    #[test]
    fn npy_set_names() {
        let set = npy_set(Path::new("/tmp/run.1/slopes.npy"));
        assert_eq!(set[1], Path::new("/tmp/run.1/slopes.flux.npy"));
        assert_eq!(set[2], Path::new("/tmp/run.1/slopes.valid.npy"));
        assert_eq!(set[3], Path::new("/tmp/run.1/slopes.json"));
    }
}
