//! What a configuration problem says: [`ConfigFileError`], naming the file
//! and the key to blame, and the messages that turn a `Config::validate`
//! error into the words of the file (which window, from which grid
//! position, table row or list entry).

use std::fmt;
use std::path::{Path, PathBuf};

use brightpix_protocol::{ConfigError, MapKind, MAX_WINDOW_SIDE};

use super::{ArrayValues, ProcessingConfig};
use crate::io::shape_string;

/// What kind of problem a [`ConfigFileError`] is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigFileErrorKind {
    /// The TOML file could not be read.
    Read,
    /// TOML syntax, a value of the wrong type, a missing or unknown key.
    Toml,
    /// A value the format does not allow (out of range, conflicting keys).
    Value,
    /// A referenced data file could not be read or written.
    Data,
    /// A referenced array has the wrong shape.
    Shape,
    /// [`Config::validate`](brightpix_protocol::Config::validate) refused
    /// the configuration.
    Invalid(ConfigError),
}

/// A configuration problem, naming the TOML file and the key.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigFileError {
    /// The TOML file.
    pub file: PathBuf,
    /// The key, dotted (`selection.pixels`), when one is to blame.
    pub field: Option<String>,
    pub kind: ConfigFileErrorKind,
    pub message: String,
}

impl fmt::Display for ConfigFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.field {
            Some(field) => write!(f, "{}: {field}: {}", self.file.display(), self.message),
            None => write!(f, "{}: {}", self.file.display(), self.message),
        }
    }
}

impl std::error::Error for ConfigFileError {}

pub(super) type Result<T, E = ConfigFileError> = std::result::Result<T, E>;

/// Where each validated item came from, to name it in errors.
#[derive(Default)]
pub(super) struct Sources {
    pub windows: &'static str,
    /// The windows' table was given in memory (no file to name).
    pub windows_in_memory: bool,
    pub pixels: &'static str,
    pub background: &'static str,
    pub gain: &'static str,
}

/// Makes the errors of one configuration: each names its file (or, for
/// values given in memory, the origin the caller named).
#[derive(Clone, Debug)]
pub(super) struct ErrorSite {
    file: PathBuf,
}

impl ErrorSite {
    pub(super) fn new(file: &Path) -> Self {
        ErrorSite {
            file: file.to_path_buf(),
        }
    }

    pub(super) fn error(
        &self,
        field: &str,
        kind: ConfigFileErrorKind,
        message: impl Into<String>,
    ) -> ConfigFileError {
        ConfigFileError {
            file: self.file.clone(),
            field: (!field.is_empty()).then(|| field.to_string()),
            kind,
            message: message.into(),
        }
    }

    pub(super) fn value_error(&self, field: &str, message: impl Into<String>) -> ConfigFileError {
        self.error(field, ConfigFileErrorKind::Value, message)
    }

    pub(super) fn shape_error(
        &self,
        field: &str,
        array: &ArrayValues,
        expected: &str,
    ) -> ConfigFileError {
        let found = shape_string(&array.shape);
        let message = match &array.label {
            Some(label) => format!("{label} has shape {found}; expected {expected}"),
            None => format!("shape {found}; expected {expected}"),
        };
        self.error(field, ConfigFileErrorKind::Shape, message)
    }

    fn describe_window(
        &self,
        index: usize,
        config: &ProcessingConfig,
        sources: &Sources,
    ) -> String {
        let Some(w) = config.windows.get(index) else {
            return format!("sub-aperture {index}");
        };
        let origin = match (&config.grid, sources.windows) {
            (Some(layout), "subapertures.grid") => match layout.positions().nth(index) {
                Some([c, r]) => format!("grid column {c}, row {r}: "),
                None => String::new(),
            },
            (_, "subapertures.window") => format!("[[subapertures.window]] entry {index}: "),
            (_, "subapertures.file") if sources.windows_in_memory => format!("row {index}: "),
            (_, "subapertures.file") => format!("row {index} of the file: "),
            _ => String::new(),
        };
        format!(
            "sub-aperture {index} ({origin}x = {}, y = {}, {}x{} pixels)",
            w.x, w.y, w.width, w.height
        )
    }

    /// A `Config::validate` error, named by the key it comes from.
    pub(super) fn explain(
        &self,
        e: ConfigError,
        config: &ProcessingConfig,
        sources: &Sources,
    ) -> ConfigFileError {
        use ConfigError::*;
        let (field, message) = match e {
            CameraSize { .. } | BitDepth { .. } => ("camera", e.to_string()),
            CropOutsideSensor { .. } => ("camera.crop", e.to_string()),
            NoSubapertures | TooManySubapertures { .. } => (sources.windows, e.to_string()),
            EmptyWindow { index } => (
                sources.windows,
                format!(
                    "{} has zero width or height",
                    self.describe_window(index, config, sources)
                ),
            ),
            WindowTooLarge { index, .. } => (
                sources.windows,
                format!(
                    "{} is larger than {MAX_WINDOW_SIDE} pixels per side",
                    self.describe_window(index, config, sources)
                ),
            ),
            WindowOutsideCamera { index } => (
                sources.windows,
                format!(
                    "{} extends outside the {}x{} camera",
                    self.describe_window(index, config, sources),
                    config.camera.width,
                    config.camera.height
                ),
            ),
            PixelCountZero { index } => (
                sources.pixels,
                format!("N is 0 for sub-aperture {index}; it must be at least 1"),
            ),
            PixelCountZeroAll => (
                sources.pixels,
                "N, the number of pixels to select, is 0; it must be at least 1".to_string(),
            ),
            PixelCountListLength { .. } => (sources.pixels, e.to_string()),
            MeanCount { .. } => ("selection.mean_count", e.to_string()),
            LevelFilterGain { .. } => ("selection.level_filter.gain_shift", e.to_string()),
            LevelFilterWithoutSubtraction => ("selection.level_filter", e.to_string()),
            MapSize { map, .. } => (
                match map {
                    MapKind::Background => sources.background,
                    MapKind::Gain => sources.gain,
                    MapKind::ReferenceSlopes => "centroid.reference_slopes",
                },
                e.to_string(),
            ),
            BackgroundOutOfRange { .. } => (sources.background, e.to_string()),
            ThresholdOutOfRange { .. } => ("calibration.threshold_counts", e.to_string()),
            ReferenceSlopeOutOfRange { .. } => ("centroid.reference_slopes", e.to_string()),
            NegativeMinFlux => ("centroid.min_flux_counts", e.to_string()),
            MemoryBudget { .. } => ("", e.to_string()),
        };
        self.error(field, ConfigFileErrorKind::Invalid(e), message)
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use brightpix_protocol::MAX_SUBAPERTURES;

    #[test]
    fn pixel_count_zero() {
        let err = invalid(&format!("{BASE}\n[selection]\npixels = 0\n"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::PixelCountZeroAll)
        );
        assert_eq!(err.field.as_deref(), Some("selection.pixels"));
        assert!(
            err.to_string()
                .contains("selection.pixels: N, the number of pixels to select, is 0"),
            "{err}"
        );

        let list = "pixels = [20, 20, 20, 20, 20, 0, 20, 20, 20, 20, 20, 20]";
        let err = invalid(&format!("{BASE}\n[selection]\n{list}\n"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::PixelCountZero { index: 5 })
        );
        assert!(err.message.contains("sub-aperture 5"), "{err}");

        let err = invalid(&format!("{BASE}\n[selection]\npixels = [20, 20]\n"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::PixelCountListLength {
                expected: 12,
                found: 2
            })
        );
        let err = invalid(&format!("{BASE}\n[selection]\npixels = -3\n"));
        assert_eq!(
            (err.kind, err.field.as_deref()),
            (ConfigFileErrorKind::Value, Some("selection.pixels"))
        );
        let err = invalid(&format!("{BASE}\n[selection]\npixels = [1, 2.5]\n"));
        assert!(err.message.contains("entry 1 is 2.5"), "{err}");
    }

    #[test]
    fn window_outside_camera() {
        let err = invalid(&BASE.replace("columns = 4", "columns = 5"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::WindowOutsideCamera { index: 4 })
        );
        assert_eq!(err.field.as_deref(), Some("subapertures.grid"));
        assert!(err.message.contains("grid column 4, row 0"), "{err}");
        assert!(
            err.message
                .contains("x = 64, y = 0, 16x16 pixels) extends outside the 64x48 camera"),
            "{err}"
        );

        let text = "[camera]\nwidth = 10\nheight = 10\nbit_depth = 8\n[[subapertures.window]]\nx = 0\ny = 0\nwidth = 4\nheight = 4\n[[subapertures.window]]\nx = 8\ny = 8\nwidth = 4\nheight = 1\n";
        let err = invalid(text);
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::WindowOutsideCamera { index: 1 })
        );
        assert!(
            err.message.contains("[[subapertures.window]] entry 1"),
            "{err}"
        );
    }

    #[test]
    fn zero_size_window() {
        let err = invalid(&BASE.replace("height = 16", "height = 0"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::EmptyWindow { index: 0 })
        );
        assert_eq!(err.field.as_deref(), Some("subapertures.grid"));
        assert!(
            err.message
                .contains("sub-aperture 0 (grid column 0, row 0: x = 0, y = 0, 16x0 pixels) has zero width or height"),
            "{err}"
        );
        let err = invalid(
            &BASE
                .replace("width = 64", "width = 400")
                .replace("width = 16", "width = 65"),
        );
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::WindowTooLarge {
                index: 0,
                width: 65,
                height: 16
            })
        );
        assert!(err.message.contains("larger than 64 pixels"), "{err}");
        let err = invalid(&BASE.replace("rows = 3", "rows = 0"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::NoSubapertures)
        );
    }

    #[test]
    fn too_many_subapertures() {
        let err = invalid(
            &BASE
                .replace("columns = 4", "columns = 200")
                .replace("rows = 3", "rows = 100"),
        );
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::TooManySubapertures {
                count: 20000,
                max: MAX_SUBAPERTURES
            })
        );
        assert!(err.message.contains("200 columns x 100 rows"), "{err}");
    }

    #[test]
    fn camera_errors() {
        let err = invalid(&BASE.replace("bit_depth = 12", "bit_depth = 17"));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::BitDepth { bit_depth: 17 })
        );
        assert_eq!(err.field.as_deref(), Some("camera"));
        let err = invalid(&BASE.replace("width = 64", "width = 70000"));
        assert_eq!(err.kind, ConfigFileErrorKind::Toml);
        assert!(err.message.contains("70000"), "{err}");
    }
}
