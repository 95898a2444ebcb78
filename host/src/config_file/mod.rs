//! The processing-configuration file: TOML for AO engineers (every key and
//! unit is documented in `docs/CONFIG.md`), loaded into an owned
//! [`ProcessingConfig`] whose [`ProcessingConfig::view`] is the borrowed
//! [`Config`] the engine and the reference consume.
//!
//! Values in the file are in natural units (counts, pixels, gains as plain
//! numbers); loading converts them to the fixed-point formats of
//! `brightpix_protocol::config`:
//!
//! | file                          | engine                                      |
//! |-------------------------------|---------------------------------------------|
//! | background, counts (float)    | `round(v * 16)` in 1/16 count, i32          |
//! | flat x pixel weight (float)   | `round(g * 4096)` in 1/4096, u16            |
//! | threshold_counts              | `round(v * 16)` in 1/16 count               |
//! | reference slopes, pixels      | `round(v * 65536)` in 2^-16 pixel           |
//! | min_flux_counts               | `round(v * 16)` in 1/16 count               |
//!
//! `round` is half away from zero. A value that does not fit is an error
//! naming the file, the key and (for maps) the pixel.
//!
//! The code is split by concern, each part readable alone:
//!
//! | module      | holds                                                         |
//! |-------------|---------------------------------------------------------------|
//! | (this one)  | [`ProcessingConfig`], the owned configuration, and its entry points |
//! | `schema`    | the TOML file's structure (serde), key by key                 |
//! | `values`    | [`ConfigValues`]: a configuration in natural units, arrays in memory |
//! | `read`      | the TOML text and the data files it names, read into [`ConfigValues`] |
//! | `convert`   | [`ConfigValues`] to the device's integers, range by range     |
//! | `errors`    | [`ConfigFileError`] and the messages naming the key to blame  |
//! | `save`      | the configuration written back as TOML and sibling `.npy` files |

mod convert;
mod errors;
mod read;
mod save;
mod schema;
#[cfg(test)]
mod test_support;
mod values;

use std::path::Path;

use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, ConfigError, Crop, LevelFilter, PixelCount, RegularGrid,
    Selection, SelectionRule, SubapertureWindow,
};

pub use errors::{ConfigFileError, ConfigFileErrorKind};
pub use values::{
    ArrayValues, BackgroundValues, ConfigValues, GridValues, PixelValues, RuleName,
    SubapertureValues,
};

/// The paper's recommended number of brightest pixels.
pub const DEFAULT_PIXELS: u16 = 20;

/// N, the number of brightest pixels kept: one for all sub-apertures, or one
/// per sub-aperture (in window order).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PixelCounts {
    All(u16),
    PerSubaperture(Vec<u16>),
}

/// A regular grid with vignetted positions left out; the windows it yields
/// are numbered row by row, skipping the skipped.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GridLayout {
    pub grid: RegularGrid,
    /// `[column, row]` grid positions that have no window.
    pub skip: Vec<[u16; 2]>,
}

impl GridLayout {
    /// Grid positions `[column, row]` that have a window, in window order.
    pub fn positions(&self) -> impl Iterator<Item = [u16; 2]> {
        let g = self.grid;
        let skip: std::collections::HashSet<[u16; 2]> = self.skip.iter().copied().collect();
        (0..g.rows)
            .flat_map(move |r| (0..g.columns).map(move |c| [c, r]))
            .filter(move |p| !skip.contains(p))
    }

    pub fn windows(&self) -> Vec<SubapertureWindow> {
        self.positions()
            .map(|[c, r]| self.grid.window(c, r))
            .collect()
    }
}

/// A whole processing configuration, owning its maps. Fields are in the
/// engine's fixed-point units (see the module documentation).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ProcessingConfig {
    pub camera: Camera,
    /// The windows, in output order.
    pub windows: Vec<SubapertureWindow>,
    /// The grid the windows came from, if they came from one; kept so that a
    /// saved configuration stays a grid. Ignored (and dropped on save) when it
    /// no longer yields `windows`.
    pub grid: Option<GridLayout>,
    /// Background in 1/16 count, one per camera pixel, row-major.
    pub background: Option<Vec<i32>>,
    /// Gain (flat x pixel weight) in 1/4096, one per camera pixel.
    pub gain: Option<Vec<u16>>,
    /// Threshold in 1/16 count.
    pub threshold: Option<i32>,
    pub rule: SelectionRule,
    pub pixels: PixelCounts,
    pub level_filter: Option<LevelFilter>,
    /// `[x, y]` in 2^-16 pixel, one per window.
    pub reference_slopes: Option<Vec<[i32; 2]>>,
    /// Minimum flux in 1/16 count.
    pub min_flux: i64,
    /// Where `camera` lies on a larger sensor: a board's part of a rig
    /// (`rig::board_config` sets it; in the TOML file `[camera.crop]`).
    pub crop: Option<Crop>,
}

impl ProcessingConfig {
    /// `windows` on `camera` with the defaults: no calibration, the paper's
    /// subtract-next with N = 20, no level filter, zero reference slopes,
    /// no minimum flux.
    pub fn new(camera: Camera, windows: Vec<SubapertureWindow>) -> Self {
        ProcessingConfig {
            camera,
            windows,
            grid: None,
            background: None,
            gain: None,
            threshold: None,
            rule: SelectionRule::SubtractNext,
            pixels: PixelCounts::All(DEFAULT_PIXELS),
            level_filter: None,
            reference_slopes: None,
            min_flux: 0,
            crop: None,
        }
    }

    /// A regular grid without the `skip`ped `[column, row]` positions, with
    /// the defaults of [`ProcessingConfig::new`].
    pub fn from_grid(camera: Camera, grid: RegularGrid, skip: &[[u16; 2]]) -> Self {
        let layout = GridLayout {
            grid,
            skip: skip.to_vec(),
        };
        let mut config = Self::new(camera, layout.windows());
        config.grid = Some(layout);
        config
    }

    /// The borrowed view the engine consumes.
    pub fn view(&self) -> Config<'_> {
        Config {
            camera: self.camera,
            windows: &self.windows,
            calibration: Calibration {
                background: self.background.as_deref(),
                gain: self.gain.as_deref(),
                threshold: self.threshold,
            },
            selection: Selection {
                rule: self.rule,
                count: match &self.pixels {
                    PixelCounts::All(n) => PixelCount::All(*n),
                    PixelCounts::PerSubaperture(list) => PixelCount::PerSubaperture(list),
                },
                level_filter: self.level_filter,
            },
            centroid: Centroid {
                reference_slopes: self.reference_slopes.as_deref(),
                min_flux: self.min_flux,
            },
            crop: self.crop,
        }
    }

    /// [`Config::validate`] of the view.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.view().validate()
    }

    /// Loads and validates a TOML configuration file. Relative data-file
    /// paths in it resolve against the file's directory.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigFileError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigFileError {
            file: path.to_path_buf(),
            field: None,
            kind: ConfigFileErrorKind::Read,
            message: format!("cannot read the configuration: {e}"),
        })?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and validates TOML `text` as if read from `path`: `path` names
    /// the configuration in errors and its directory anchors relative
    /// data-file paths.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, ConfigFileError> {
        let values = read::FileReader::new(path).values(text)?;
        Self::from_values(values, path)
    }

    /// Converts `values` to the engine's units and validates them, with the
    /// rules and messages of a TOML file; `origin` names the configuration
    /// in errors (as a file's path does).
    pub fn from_values(values: ConfigValues, origin: &Path) -> Result<Self, ConfigFileError> {
        convert::Converter::new(origin).convert(values)
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;

    #[test]
    fn view_borrows_everything() {
        let mut c = parse(BASE).unwrap();
        c.pixels = PixelCounts::PerSubaperture(vec![3; 12]);
        c.gain = Some(vec![4096; 64 * 48]);
        let v = c.view();
        assert_eq!(v.windows.len(), 12);
        assert_eq!(v.pixel_count(11), 3);
        assert_eq!(v.calibration.gain.unwrap().len(), 64 * 48);
        assert_eq!(v.selection.rule, SelectionRule::SubtractNext);
    }
}
