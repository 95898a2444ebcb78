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

use std::fmt;
use std::path::{Path, PathBuf};

use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, ConfigError, LevelFilter, MapKind, PixelCount,
    RegularGrid, Selection, SelectionRule, SubapertureWindow, MAX_BACKGROUND_ABS,
    MAX_REFERENCE_SLOPE_ABS, MAX_SUBAPERTURES, MAX_THRESHOLD_ABS, MAX_WINDOW_SIDE,
};
use serde::Deserialize;

use crate::io::{self, shape_string};

/// The paper's recommended number of brightest pixels.
pub const DEFAULT_PIXELS: u16 = 20;

/// Windows longer than this are saved as a sibling `.npy` instead of inline.
const INLINE_LIST_MAX: usize = 256;

// ---------------------------------------------------------------------------
// The owned configuration
// ---------------------------------------------------------------------------

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
        Loader::new(path).load(text)
    }

    /// The configuration as TOML text. Whatever has no inline form (a
    /// non-constant background, a gain map, reference slopes, long window or
    /// N lists) is referenced as a sibling file named `{name}-*.npy`, which
    /// [`ProcessingConfig::save`] writes.
    pub fn to_toml_string(&self, name: &str) -> String {
        self.render(name).0
    }

    /// Writes `{dir}/{name}.toml` and the sibling `.npy` files it references;
    /// returns the TOML file's path. The configuration must validate.
    pub fn save(&self, dir: impl AsRef<Path>, name: &str) -> Result<PathBuf, ConfigFileError> {
        let dir = dir.as_ref();
        let toml_path = dir.join(format!("{name}.toml"));
        let error = |kind, message: String| ConfigFileError {
            file: toml_path.clone(),
            field: None,
            kind,
            message,
        };
        if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
            return Err(error(
                ConfigFileErrorKind::Value,
                format!("configuration name {name:?} must be a plain file name"),
            ));
        }
        if let Err(e) = self.validate() {
            return Err(error(
                ConfigFileErrorKind::Invalid(e),
                format!("refusing to save an invalid configuration: {e}"),
            ));
        }
        let (text, side_files) = self.render(name);
        std::fs::create_dir_all(dir).map_err(|e| {
            error(
                ConfigFileErrorKind::Data,
                format!("cannot create {}: {e}", dir.display()),
            )
        })?;
        for side in side_files {
            let path = dir.join(&side.file);
            let result = match &side.data {
                SideData::F64(v) => io::write_array(&path, &side.shape, v),
                SideData::U16(v) => io::write_array(&path, &side.shape, v),
                SideData::I32(v) => io::write_array(&path, &side.shape, v),
            };
            result.map_err(|e| error(ConfigFileErrorKind::Data, e.to_string()))?;
        }
        std::fs::write(&toml_path, text)
            .map_err(|e| error(ConfigFileErrorKind::Data, format!("cannot write: {e}")))?;
        Ok(toml_path)
    }

    fn render(&self, name: &str) -> (String, Vec<SideFile>) {
        let mut side = Vec::new();
        let mut t = String::new();
        let s = |text: &str| toml::Value::String(text.to_string()).to_string();
        let f = |v: f64| toml::Value::Float(v).to_string();
        t.push_str("# brightpix processing configuration. Keys and units: docs/CONFIG.md\n");
        t.push_str("\n[camera]\n");
        t.push_str(&format!("width = {}  # pixels\n", self.camera.width));
        t.push_str(&format!("height = {}  # pixels\n", self.camera.height));
        t.push_str(&format!(
            "bit_depth = {}  # bits per raw pixel\n",
            self.camera.bit_depth
        ));

        let grid = self
            .grid
            .as_ref()
            .filter(|layout| layout.windows() == self.windows);
        if let Some(layout) = grid {
            let g = layout.grid;
            t.push_str("\n[subapertures.grid]\n");
            t.push_str(&format!(
                "x = {}  # first window's left column, pixels\ny = {}  # first window's top row, pixels\n",
                g.x, g.y
            ));
            t.push_str(&format!("columns = {}\nrows = {}\n", g.columns, g.rows));
            t.push_str(&format!(
                "width = {}  # pixels\nheight = {}  # pixels\n",
                g.width, g.height
            ));
            t.push_str(&format!(
                "pitch_x = {}  # pixels\npitch_y = {}  # pixels\n",
                g.pitch_x, g.pitch_y
            ));
            if !layout.skip.is_empty() {
                let list: Vec<String> = layout
                    .skip
                    .iter()
                    .map(|[c, r]| format!("[{c}, {r}]"))
                    .collect();
                t.push_str(&format!("skip = [{}]  # [column, row]\n", list.join(", ")));
            }
        } else if self.windows.len() > INLINE_LIST_MAX {
            let file = format!("{name}-windows.npy");
            t.push_str(&format!(
                "\n[subapertures]\nfile = {}  # (n, 4): x, y, width, height\n",
                s(&file)
            ));
            let data = self
                .windows
                .iter()
                .flat_map(|w| [w.x, w.y, w.width, w.height].map(i32::from))
                .collect();
            side.push(SideFile {
                file,
                shape: vec![self.windows.len(), 4],
                data: SideData::I32(data),
            });
        } else if self.windows.is_empty() {
            t.push_str("\n[subapertures]\nwindow = []\n");
        } else {
            for w in &self.windows {
                t.push_str(&format!(
                    "\n[[subapertures.window]]\nx = {}\ny = {}\nwidth = {}\nheight = {}\n",
                    w.x, w.y, w.width, w.height
                ));
            }
        }

        let mut cal = String::new();
        if let Some(bg) = &self.background {
            match bg.first() {
                Some(&b0) if bg.iter().all(|&b| b == b0) => {
                    cal.push_str(&format!("background_counts = {}\n", f(b0 as f64 / 16.0)));
                }
                _ => {
                    let file = format!("{name}-background.npy");
                    cal.push_str(&format!("background = {}  # counts\n", s(&file)));
                    side.push(SideFile {
                        file,
                        shape: vec![self.camera.height as usize, self.camera.width as usize],
                        data: SideData::F64(bg.iter().map(|&b| b as f64 / 16.0).collect()),
                    });
                }
            }
        }
        if let Some(gain) = &self.gain {
            let file = format!("{name}-gain.npy");
            cal.push_str(&format!(
                "flat = {}  # flat field x pixel weight, combined\n",
                s(&file)
            ));
            side.push(SideFile {
                file,
                shape: vec![self.camera.height as usize, self.camera.width as usize],
                data: SideData::F64(gain.iter().map(|&g| g as f64 / 4096.0).collect()),
            });
        }
        if let Some(th) = self.threshold {
            cal.push_str(&format!("threshold_counts = {}\n", f(th as f64 / 16.0)));
        }
        if !cal.is_empty() {
            t.push_str("\n[calibration]\n");
            t.push_str(&cal);
        }

        t.push_str("\n[selection]\n");
        let (rule, mean) = match self.rule {
            SelectionRule::SubtractNext => ("subtract-next", None),
            SelectionRule::Threshold => ("threshold", None),
            SelectionRule::SubtractNextDistinct => ("subtract-next-distinct", None),
            SelectionRule::SubtractMean { count } => ("subtract-mean", Some(count)),
        };
        t.push_str(&format!("rule = {}\n", s(rule)));
        if let Some(m) = mean {
            t.push_str(&format!("mean_count = {m}\n"));
        }
        match &self.pixels {
            PixelCounts::All(n) => t.push_str(&format!("pixels = {n}\n")),
            PixelCounts::PerSubaperture(list) if list.len() > INLINE_LIST_MAX => {
                let file = format!("{name}-pixels.npy");
                t.push_str(&format!(
                    "pixels_file = {}  # N per sub-aperture\n",
                    s(&file)
                ));
                side.push(SideFile {
                    file,
                    shape: vec![list.len()],
                    data: SideData::U16(list.clone()),
                });
            }
            PixelCounts::PerSubaperture(list) => {
                let items: Vec<String> = list.iter().map(u16::to_string).collect();
                t.push_str(&format!("pixels = [{}]\n", items.join(", ")));
            }
        }
        if let Some(filter) = self.level_filter {
            t.push_str(&format!(
                "\n[selection.level_filter]\ngain_shift = {}  # filter gain 2^-gain_shift\n",
                filter.gain_shift
            ));
        }

        t.push_str("\n[centroid]\n");
        if let Some(refs) = &self.reference_slopes {
            let file = format!("{name}-reference-slopes.npy");
            t.push_str(&format!(
                "reference_slopes = {}  # (n, 2): x, y in pixels\n",
                s(&file)
            ));
            side.push(SideFile {
                file,
                shape: vec![refs.len(), 2],
                data: SideData::F64(
                    refs.iter()
                        .flat_map(|r| r.map(|v| v as f64 / 65536.0))
                        .collect(),
                ),
            });
        }
        t.push_str(&format!(
            "min_flux_counts = {}\n",
            f(self.min_flux as f64 / 16.0)
        ));
        (t, side)
    }
}

struct SideFile {
    file: String,
    shape: Vec<usize>,
    data: SideData,
}

enum SideData {
    F64(Vec<f64>),
    U16(Vec<u16>),
    I32(Vec<i32>),
}

// ---------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------

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
    /// [`Config::validate`] refused the configuration.
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

// ---------------------------------------------------------------------------
// Values in natural units, data arrays in memory
// ---------------------------------------------------------------------------

/// An array handed to [`ConfigValues`]: read from a data file by the TOML
/// loader, or given in memory by a program (the Python package). Row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayValues {
    /// Names the array in error messages (the data file's path); `None` for
    /// an array given in memory, whose errors then name only the key.
    pub label: Option<String>,
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

impl ArrayValues {
    /// An array given in memory (no label). `data.len()` must be the
    /// product of `shape` (`1` for a 0-d array).
    pub fn new(shape: Vec<usize>, data: Vec<f64>) -> Self {
        ArrayValues {
            label: None,
            shape,
            data,
        }
    }

    /// `text`, prefixed with the array's label if it has one.
    fn named(&self, text: String) -> String {
        match &self.label {
            Some(label) => format!("{label}: {text}"),
            None => text,
        }
    }
}

/// A regular grid of windows, as `[subapertures.grid]` gives it (pixels;
/// the pitches default to the window size).
#[derive(Deserialize, Clone, Debug, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct GridValues {
    pub x: u16,
    pub y: u16,
    pub columns: u16,
    pub rows: u16,
    pub width: u16,
    pub height: u16,
    pub pitch_x: Option<u16>,
    pub pitch_y: Option<u16>,
    /// `[column, row]` grid positions without a window.
    #[serde(default)]
    pub skip: Vec<[u16; 2]>,
}

/// Where the windows come from.
#[derive(Clone, Debug, PartialEq)]
pub enum SubapertureValues {
    Grid(GridValues),
    /// `[[subapertures.window]]`.
    Windows(Vec<SubapertureWindow>),
    /// An `(n, 4)` table of integer-valued `x, y, width, height`.
    Table(ArrayValues),
}

/// The background, in counts.
#[derive(Clone, Debug, PartialEq)]
pub enum BackgroundValues {
    Constant(f64),
    /// `(height, width)` or `(1, height, width)`.
    Map(ArrayValues),
}

/// N, the number of brightest pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum PixelValues {
    /// [`DEFAULT_PIXELS`] for every sub-aperture.
    #[default]
    Default,
    Counts(PixelCounts),
    /// Integer values: 0-d (one N for all) or `(n,)` (one per sub-aperture).
    Table(ArrayValues),
}

/// The selection rules by their names in the file.
#[derive(Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum RuleName {
    #[default]
    SubtractNext,
    Threshold,
    SubtractNextDistinct,
    SubtractMean,
}

impl RuleName {
    /// Every rule with its name, in the order the documentation lists them.
    pub const ALL: [(RuleName, &'static str); 4] = [
        (RuleName::SubtractNext, "subtract-next"),
        (RuleName::Threshold, "threshold"),
        (RuleName::SubtractNextDistinct, "subtract-next-distinct"),
        (RuleName::SubtractMean, "subtract-mean"),
    ];

    /// The rule named `name` (`"subtract-next"`, ...).
    pub fn from_name(name: &str) -> Option<RuleName> {
        Self::ALL.iter().find(|(_, n)| *n == name).map(|(r, _)| *r)
    }

    pub fn name(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(r, _)| *r == self)
            .map_or("", |(_, n)| n)
    }

    /// The name of `rule`'s kind.
    pub fn of(rule: SelectionRule) -> RuleName {
        match rule {
            SelectionRule::SubtractNext => RuleName::SubtractNext,
            SelectionRule::Threshold => RuleName::Threshold,
            SelectionRule::SubtractNextDistinct => RuleName::SubtractNextDistinct,
            SelectionRule::SubtractMean { .. } => RuleName::SubtractMean,
        }
    }
}

/// A whole configuration in the file's natural units (counts, pixels,
/// plain gains; docs/CONFIG.md) with its arrays in memory: what a TOML file
/// says once its data files are read, or what a program builds directly.
/// [`ProcessingConfig::from_values`] converts and validates it with the
/// same rules and messages as a file.
#[derive(Clone, Debug, PartialEq)]
pub struct ConfigValues {
    pub camera: Camera,
    pub subapertures: SubapertureValues,
    pub background: Option<BackgroundValues>,
    /// Flat field, `(height, width)`; the gain is flat x pixel weight.
    pub flat: Option<ArrayValues>,
    pub pixel_weight: Option<ArrayValues>,
    pub threshold_counts: Option<f64>,
    pub rule: RuleName,
    /// M of `subtract-mean` (required by it, refused by the others).
    pub mean_count: Option<u16>,
    pub pixels: PixelValues,
    pub level_filter: Option<LevelFilter>,
    /// `(n, 2)`: `[x, y]` in pixels per sub-aperture.
    pub reference_slopes: Option<ArrayValues>,
    pub min_flux_counts: Option<f64>,
}

impl ConfigValues {
    /// `subapertures` on `camera`, everything else at the file's defaults.
    pub fn new(camera: Camera, subapertures: SubapertureValues) -> Self {
        ConfigValues {
            camera,
            subapertures,
            background: None,
            flat: None,
            pixel_weight: None,
            threshold_counts: None,
            rule: RuleName::default(),
            mean_count: None,
            pixels: PixelValues::Default,
            level_filter: None,
            reference_slopes: None,
            min_flux_counts: None,
        }
    }
}

impl ProcessingConfig {
    /// Converts `values` to the engine's units and validates them, with the
    /// rules and messages of a TOML file; `origin` names the configuration
    /// in errors (as a file's path does).
    pub fn from_values(values: ConfigValues, origin: &Path) -> Result<Self, ConfigFileError> {
        Loader::new(origin).build(values)
    }
}

// ---------------------------------------------------------------------------
// The file format (see docs/CONFIG.md)
// ---------------------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    camera: FileCamera,
    subapertures: FileSubapertures,
    #[serde(default)]
    calibration: FileCalibration,
    #[serde(default)]
    selection: FileSelection,
    #[serde(default)]
    centroid: FileCentroid,
    /// What `brightpix tune` assumed and found: a record for people, not
    /// read by the loader (any content is accepted and ignored).
    #[serde(default, rename = "tuned")]
    _tuned: Option<toml::Table>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileCamera {
    width: u16,
    height: u16,
    bit_depth: u8,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileSubapertures {
    grid: Option<GridValues>,
    window: Option<Vec<FileWindow>>,
    file: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileWindow {
    x: u16,
    y: u16,
    width: u16,
    height: u16,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileCalibration {
    background: Option<String>,
    background_counts: Option<f64>,
    flat: Option<String>,
    pixel_weight: Option<String>,
    threshold_counts: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileSelection {
    rule: Option<RuleName>,
    mean_count: Option<u16>,
    pixels: Option<toml::Value>,
    pixels_file: Option<String>,
    level_filter: Option<FileLevelFilter>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileLevelFilter {
    gain_shift: u8,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct FileCentroid {
    reference_slopes: Option<String>,
    min_flux_counts: Option<f64>,
}

// ---------------------------------------------------------------------------
// Loading
// ---------------------------------------------------------------------------

/// Where each validated item came from, to name it in errors.
#[derive(Default)]
struct Sources {
    windows: &'static str,
    /// The windows' table was given in memory (no file to name).
    windows_in_memory: bool,
    pixels: &'static str,
    background: &'static str,
    gain: &'static str,
}

struct Loader {
    file: PathBuf,
    base: PathBuf,
}

type Result<T, E = ConfigFileError> = std::result::Result<T, E>;

impl Loader {
    fn new(file: &Path) -> Self {
        Loader {
            file: file.to_path_buf(),
            base: file.parent().map(Path::to_path_buf).unwrap_or_default(),
        }
    }

    fn error(
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

    fn value_error(&self, field: &str, message: impl Into<String>) -> ConfigFileError {
        self.error(field, ConfigFileErrorKind::Value, message)
    }

    fn resolve(&self, name: &str) -> PathBuf {
        let p = Path::new(name);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.base.join(p)
        }
    }

    /// A data file named in the TOML, labelled with its resolved path.
    fn read_array(&self, field: &str, name: &str) -> Result<ArrayValues> {
        let path = self.resolve(name);
        let array = io::read_array(&path)
            .map_err(|e| self.error(field, ConfigFileErrorKind::Data, e.to_string()))?;
        Ok(ArrayValues {
            label: Some(path.display().to_string()),
            shape: array.shape,
            data: array.data,
        })
    }

    fn shape_error(&self, field: &str, array: &ArrayValues, expected: &str) -> ConfigFileError {
        let found = shape_string(&array.shape);
        let message = match &array.label {
            Some(label) => format!("{label} has shape {found}; expected {expected}"),
            None => format!("shape {found}; expected {expected}"),
        };
        self.error(field, ConfigFileErrorKind::Shape, message)
    }

    /// A full-frame map: shape (height, width), or (1, height, width) (a
    /// map averaged over a cube with its axis kept); docs/CONFIG.md says so
    /// for every map.
    fn camera_map<'a>(
        &self,
        field: &str,
        array: &'a ArrayValues,
        camera: &Camera,
    ) -> Result<&'a [f64]> {
        let (h, w) = (camera.height as usize, camera.width as usize);
        let ok = match array.shape[..] {
            [rows, cols] | [1, rows, cols] => rows == h && cols == w,
            _ => false,
        };
        if !ok {
            return Err(self.shape_error(
                field,
                array,
                &format!("({h}, {w}), the camera's (height, width)"),
            ));
        }
        Ok(&array.data)
    }

    /// A 0-d, 1-D or (n, k) table of integers, each in `0..=65535`.
    fn integer_table(&self, field: &str, array: &ArrayValues, columns: usize) -> Result<Vec<u16>> {
        array
            .data
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                if v.fract() == 0.0 && (0.0..=65535.0).contains(&v) {
                    Ok(v as u16)
                } else {
                    let at = if array.shape.is_empty() {
                        "the value".to_string()
                    } else if columns > 1 {
                        format!("row {}, column {}", i / columns, i % columns)
                    } else {
                        format!("entry {i}")
                    };
                    Err(self.value_error(
                        field,
                        array.named(format!("{at} is {v}; expected an integer in 0..=65535")),
                    ))
                }
            })
            .collect()
    }

    /// The TOML text, its data files read, converted and validated.
    fn load(&self, text: &str) -> Result<ProcessingConfig> {
        let file: FileConfig = toml::from_str(text)
            .map_err(|e| self.error("", ConfigFileErrorKind::Toml, e.to_string().trim_end()))?;
        let camera = Camera {
            width: file.camera.width,
            height: file.camera.height,
            bit_depth: file.camera.bit_depth,
        };

        let sub = file.subapertures;
        let subapertures = match (sub.grid, sub.window, sub.file) {
            (Some(grid), None, None) => SubapertureValues::Grid(grid),
            (None, Some(list), None) => SubapertureValues::Windows(
                list.iter()
                    .map(|w| SubapertureWindow {
                        x: w.x,
                        y: w.y,
                        width: w.width,
                        height: w.height,
                    })
                    .collect(),
            ),
            (None, None, Some(name)) => {
                SubapertureValues::Table(self.read_array("subapertures.file", &name)?)
            }
            _ => return Err(self.value_error(
                "subapertures",
                "give exactly one of [subapertures.grid], [[subapertures.window]] or subapertures.file",
            )),
        };
        let mut values = ConfigValues::new(camera, subapertures);

        let sel = file.selection;
        values.rule = sel.rule.unwrap_or_default();
        values.mean_count = sel.mean_count;
        values.pixels = match (&sel.pixels, &sel.pixels_file) {
            (Some(_), Some(_)) => {
                return Err(self.value_error(
                    "selection.pixels",
                    "give either selection.pixels or selection.pixels_file, not both",
                ))
            }
            (None, None) => PixelValues::Default,
            (Some(value), None) => PixelValues::Counts(self.pixels_value(value)?),
            (None, Some(name)) => {
                PixelValues::Table(self.read_array("selection.pixels_file", name)?)
            }
        };
        values.level_filter = sel.level_filter.map(|f| LevelFilter {
            gain_shift: f.gain_shift,
        });

        let cal = file.calibration;
        values.background =
            match (&cal.background, cal.background_counts) {
                (Some(_), Some(_)) => return Err(self.value_error(
                    "calibration.background",
                    "give either background (a map) or background_counts (a constant), not both",
                )),
                (None, None) => None,
                (Some(name), None) => Some(BackgroundValues::Map(
                    self.read_array("calibration.background", name)?,
                )),
                (None, Some(v)) => Some(BackgroundValues::Constant(v)),
            };
        values.flat = match &cal.flat {
            Some(name) => Some(self.read_array("calibration.flat", name)?),
            None => None,
        };
        values.pixel_weight = match &cal.pixel_weight {
            Some(name) => Some(self.read_array("calibration.pixel_weight", name)?),
            None => None,
        };
        values.threshold_counts = cal.threshold_counts;

        let cen = file.centroid;
        values.reference_slopes = match &cen.reference_slopes {
            Some(name) => Some(self.read_array("centroid.reference_slopes", name)?),
            None => None,
        };
        values.min_flux_counts = cen.min_flux_counts;
        self.build(values)
    }

    /// Converts and validates values in natural units.
    fn build(&self, values: ConfigValues) -> Result<ProcessingConfig> {
        let camera = values.camera;
        let mut sources = Sources::default();

        // Windows.
        let mut grid = None;
        let windows = match &values.subapertures {
            SubapertureValues::Grid(g) => {
                sources.windows = "subapertures.grid";
                let layout = self.grid_layout(g)?;
                let windows = layout.windows();
                grid = Some(layout);
                windows
            }
            SubapertureValues::Windows(list) => {
                sources.windows = "subapertures.window";
                list.clone()
            }
            SubapertureValues::Table(array) => {
                sources.windows = "subapertures.file";
                sources.windows_in_memory = array.label.is_none();
                if !matches!(array.shape[..], [_, 4]) {
                    return Err(self.shape_error(
                        sources.windows,
                        array,
                        "(n, 4): x, y, width, height of each window",
                    ));
                }
                let values = self.integer_table(sources.windows, array, 4)?;
                values
                    .chunks_exact(4)
                    .map(|v| SubapertureWindow {
                        x: v[0],
                        y: v[1],
                        width: v[2],
                        height: v[3],
                    })
                    .collect()
            }
        };
        let count = windows.len();

        // Selection.
        let rule =
            match (values.rule, values.mean_count) {
                (RuleName::SubtractMean, Some(count)) => SelectionRule::SubtractMean { count },
                (RuleName::SubtractMean, None) => return Err(self.value_error(
                    "selection.mean_count",
                    "rule = \"subtract-mean\" needs mean_count (M, the number of values averaged)",
                )),
                (_, Some(_)) => {
                    return Err(self.value_error(
                        "selection.mean_count",
                        "mean_count applies only to rule = \"subtract-mean\"",
                    ))
                }
                (RuleName::SubtractNext, None) => SelectionRule::SubtractNext,
                (RuleName::Threshold, None) => SelectionRule::Threshold,
                (RuleName::SubtractNextDistinct, None) => SelectionRule::SubtractNextDistinct,
            };
        sources.pixels = "selection.pixels";
        let pixels = match &values.pixels {
            PixelValues::Default => PixelCounts::All(DEFAULT_PIXELS),
            PixelValues::Counts(counts) => counts.clone(),
            PixelValues::Table(array) => {
                sources.pixels = "selection.pixels_file";
                match array.shape[..] {
                    [] => PixelCounts::All(self.integer_table(sources.pixels, array, 1)?[0]),
                    [_] => {
                        PixelCounts::PerSubaperture(self.integer_table(sources.pixels, array, 1)?)
                    }
                    _ => {
                        return Err(self.shape_error(
                            sources.pixels,
                            array,
                            &format!("({count},): N for each sub-aperture"),
                        ))
                    }
                }
            }
        };

        let mut config = ProcessingConfig {
            camera,
            windows,
            grid,
            background: None,
            gain: None,
            threshold: None,
            rule,
            pixels,
            level_filter: values.level_filter,
            reference_slopes: None,
            min_flux: 0,
        };
        // Camera, windows and selection first, so that map shapes are
        // checked against a sound camera and window list.
        config
            .validate()
            .map_err(|e| self.explain(e, &config, &sources))?;

        // Calibration.
        sources.background = "calibration.background";
        config.background = match &values.background {
            None => None,
            Some(BackgroundValues::Map(array)) => {
                let field = sources.background;
                let map = self.camera_map(field, array, &camera)?;
                let mut out = Vec::with_capacity(map.len());
                for (i, &v) in map.iter().enumerate() {
                    out.push(background_fixed(v).ok_or_else(|| {
                        let (r, c) = (i / camera.width as usize, i % camera.width as usize);
                        self.value_error(
                            field,
                            array.named(format!(
                                "pixel (row {r}, column {c}) is {v} counts; a background must be finite and within +-{} counts",
                                MAX_BACKGROUND_ABS / 16
                            )),
                        )
                    })?);
                }
                Some(out)
            }
            Some(BackgroundValues::Constant(v)) => {
                let v = *v;
                sources.background = "calibration.background_counts";
                let b = background_fixed(v).ok_or_else(|| {
                    self.value_error(
                        "calibration.background_counts",
                        format!(
                            "{v} counts; a background must be finite and within +-{} counts",
                            MAX_BACKGROUND_ABS / 16
                        ),
                    )
                })?;
                Some(vec![b; camera.pixel_count()])
            }
        };
        config.gain = self.gain(&values, &camera, &mut sources)?;
        if let Some(v) = values.threshold_counts {
            // The range applies to the value as written, not as rounded.
            let r = (v * 16.0).round();
            if !(v.is_finite() && v.abs() <= MAX_THRESHOLD_ABS as f64 / 16.0) {
                return Err(self.value_error(
                    "calibration.threshold_counts",
                    format!(
                        "{v} counts; the threshold must be finite and within +-{} counts",
                        MAX_THRESHOLD_ABS / 16
                    ),
                ));
            }
            config.threshold = Some(r as i32);
        }

        // Centroid.
        if let Some(array) = &values.reference_slopes {
            let field = "centroid.reference_slopes";
            if array.shape[..] != [count, 2] {
                return Err(self.shape_error(
                    field,
                    array,
                    &format!(
                        "({count}, 2): [x, y] in pixels for each of the {count} sub-apertures"
                    ),
                ));
            }
            let max = MAX_REFERENCE_SLOPE_ABS as f64;
            let mut refs = Vec::with_capacity(count);
            for (i, pair) in array.data.chunks_exact(2).enumerate() {
                let mut out = [0i32; 2];
                for (axis, (&v, o)) in pair.iter().zip(&mut out).enumerate() {
                    let r = (v * 65536.0).round();
                    if !(v.is_finite() && v.abs() <= max / 65536.0) {
                        return Err(self.value_error(
                            field,
                            array.named(format!(
                                "sub-aperture {i} has {} = {v} pixels; reference slopes must be finite and within +-{} pixels",
                                ["x", "y"][axis],
                                MAX_REFERENCE_SLOPE_ABS >> 16
                            )),
                        ));
                    }
                    *o = r as i32;
                }
                refs.push(out);
            }
            config.reference_slopes = Some(refs);
        }
        if let Some(v) = values.min_flux_counts {
            let r = (v * 16.0).round();
            // -0.01 is negative even though it rounds to 0.
            if !(v.is_finite() && v >= 0.0 && r <= (1u64 << 62) as f64) {
                return Err(self.value_error(
                    "centroid.min_flux_counts",
                    format!("{v} counts; the minimum flux must be finite and >= 0"),
                ));
            }
            config.min_flux = r as i64;
        }

        config
            .validate()
            .map_err(|e| self.explain(e, &config, &sources))?;
        Ok(config)
    }

    fn grid_layout(&self, g: &GridValues) -> Result<GridLayout> {
        let mut seen = std::collections::HashSet::with_capacity(g.skip.len());
        for &[c, r] in &g.skip {
            if c >= g.columns || r >= g.rows {
                return Err(self.value_error(
                    "subapertures.grid.skip",
                    format!(
                        "[{c}, {r}] is outside the {}x{} grid (columns 0..{}, rows 0..{})",
                        g.columns, g.rows, g.columns, g.rows
                    ),
                ));
            }
            if !seen.insert([c, r]) {
                return Err(self.value_error(
                    "subapertures.grid.skip",
                    format!("[{c}, {r}] is listed twice"),
                ));
            }
        }
        for (key, pitch) in [("pitch_x", g.pitch_x), ("pitch_y", g.pitch_y)] {
            if pitch == Some(0) {
                return Err(self.value_error(
                    &format!("subapertures.grid.{key}"),
                    "0 pixels would put every window of the grid in one place; the pitch must be at least 1",
                ));
            }
        }
        // Refuse before expanding: a huge grid would take a lot of memory.
        let count = g.columns as usize * g.rows as usize - g.skip.len();
        if count > MAX_SUBAPERTURES {
            let e = ConfigError::TooManySubapertures {
                count,
                max: MAX_SUBAPERTURES,
            };
            return Err(self.error(
                "subapertures.grid",
                ConfigFileErrorKind::Invalid(e),
                format!(
                    "{e} ({} columns x {} rows, {} skipped)",
                    g.columns,
                    g.rows,
                    g.skip.len()
                ),
            ));
        }
        let skip = g.skip.clone();
        Ok(GridLayout {
            grid: RegularGrid {
                x: g.x,
                y: g.y,
                columns: g.columns,
                rows: g.rows,
                width: g.width,
                height: g.height,
                pitch_x: g.pitch_x.unwrap_or(g.width),
                pitch_y: g.pitch_y.unwrap_or(g.height),
            },
            skip,
        })
    }

    fn pixels_value(&self, value: &toml::Value) -> Result<PixelCounts> {
        let field = "selection.pixels";
        let one = |v: &toml::Value, what: &str| -> Result<u16> {
            match v.as_integer() {
                Some(n) if (0..=65535).contains(&n) => Ok(n as u16),
                _ => Err(self.value_error(
                    field,
                    format!("{what} is {v}; N must be an integer in 1..=65535"),
                )),
            }
        };
        match value {
            toml::Value::Array(list) => Ok(PixelCounts::PerSubaperture(
                list.iter()
                    .enumerate()
                    .map(|(i, v)| one(v, &format!("entry {i}")))
                    .collect::<Result<_>>()?,
            )),
            v => Ok(PixelCounts::All(one(v, "the value")?)),
        }
    }

    fn gain(
        &self,
        values: &ConfigValues,
        camera: &Camera,
        sources: &mut Sources,
    ) -> Result<Option<Vec<u16>>> {
        let field = match (&values.flat, &values.pixel_weight) {
            (None, None) => return Ok(None),
            (Some(_), None) => "calibration.flat",
            (None, Some(_)) => "calibration.pixel_weight",
            (Some(_), Some(_)) => "calibration.flat * calibration.pixel_weight",
        };
        sources.gain = field;
        let flat = match &values.flat {
            Some(array) => Some(self.camera_map("calibration.flat", array, camera)?),
            None => None,
        };
        let weight = match &values.pixel_weight {
            Some(array) => Some(self.camera_map("calibration.pixel_weight", array, camera)?),
            None => None,
        };
        let n = camera.pixel_count();
        let mut gain = Vec::with_capacity(n);
        for i in 0..n {
            let f = flat.map_or(1.0, |m| m[i]);
            let w = weight.map_or(1.0, |m| m[i]);
            let g = f * w;
            let r = (g * 4096.0).round();
            // The range applies to the gain as given: -0.0001 is negative.
            if !(g.is_finite() && (0.0..=65535.0 / 4096.0).contains(&g)) {
                let (row, col) = (i / camera.width as usize, i % camera.width as usize);
                let parts = match (&flat, &weight) {
                    (Some(_), Some(_)) => format!(" (flat {f} x weight {w})"),
                    _ => String::new(),
                };
                return Err(self.value_error(
                    field,
                    format!(
                        "pixel (row {row}, column {col}) has gain {g}{parts}; the gain must be within 0..={} (65535/4096)",
                        65535.0 / 4096.0
                    ),
                ));
            }
            gain.push(r as u16);
        }
        Ok(Some(gain))
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

    /// A [`Config::validate`] error, named by the key it comes from.
    fn explain(
        &self,
        e: ConfigError,
        config: &ProcessingConfig,
        sources: &Sources,
    ) -> ConfigFileError {
        use ConfigError::*;
        let (field, message) = match e {
            CameraSize { .. } | BitDepth { .. } => ("camera", e.to_string()),
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

/// Counts to 1/16 count, half away from zero; `None` if not finite or beyond
/// the engine's range.
fn background_fixed(counts: f64) -> Option<i32> {
    // The range applies to the value as given: 65536.03 is beyond 65536.
    let in_range = counts.is_finite() && counts.abs() <= MAX_BACKGROUND_ABS as f64 / 16.0;
    in_range.then(|| (counts * 16.0).round() as i32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::test_util::temp_dir;
    use crate::io::write_array;

    fn examples() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
    }

    const BASE: &str = r#"
[camera]
width = 64
height = 48
bit_depth = 12

[subapertures.grid]
x = 0
y = 0
columns = 4
rows = 3
width = 16
height = 16
"#;

    /// Parses `text` as if it were `dir/c.toml`.
    fn parse_in(dir: &Path, text: &str) -> Result<ProcessingConfig> {
        ProcessingConfig::from_toml_str(text, &dir.join("c.toml"))
    }

    fn parse(text: &str) -> Result<ProcessingConfig> {
        parse_in(Path::new("/nonexistent/conf"), text)
    }

    fn invalid(text: &str) -> ConfigFileError {
        let err = parse(text).unwrap_err();
        assert!(
            err.to_string().starts_with("/nonexistent/conf/c.toml: "),
            "{err}"
        );
        err
    }

    /// Issue 10, fault 6: the guide's ranges apply to the values as
    /// written (before rounding to fixed point), a negative flat or minimum
    /// flux is an error however small, a grid pitch of 0 is refused, and
    /// every map may carry a leading axis of length 1 (as documented).
    #[test]
    fn ranges_apply_to_the_values_as_written() {
        let field_of = |text: String| invalid(&text).field.unwrap_or_default();
        assert_eq!(
            field_of(format!(
                "{BASE}[calibration]\nbackground_counts = 65536.03\n"
            )),
            "calibration.background_counts"
        );
        parse(&format!(
            "{BASE}[calibration]\nbackground_counts = -65536\n"
        ))
        .unwrap();
        assert_eq!(
            field_of(format!(
                "{BASE}[calibration]\nthreshold_counts = 2097152.01\n"
            )),
            "calibration.threshold_counts"
        );
        assert_eq!(
            field_of(format!("{BASE}[centroid]\nmin_flux_counts = -0.0001\n")),
            "centroid.min_flux_counts"
        );
        for pitch in ["pitch_x", "pitch_y"] {
            let text = BASE.replace("height = 16\n", &format!("height = 16\n{pitch} = 0\n"));
            assert_eq!(field_of(text), format!("subapertures.grid.{pitch}"));
        }
        let dir = temp_dir("ranges");
        let n = 64 * 48;
        let mut flat = vec![1.0f64; n];
        flat[70] = -0.0001;
        write_array(dir.join("flat.npy"), &[48, 64], &flat).unwrap();
        flat[70] = 65535.2 / 4096.0; // rounds to 65535, but is above it
        write_array(dir.join("high.npy"), &[48, 64], &flat).unwrap();
        for name in ["flat.npy", "high.npy"] {
            let err =
                parse_in(&dir, &format!("{BASE}[calibration]\nflat = \"{name}\"\n")).unwrap_err();
            assert_eq!(err.field.as_deref(), Some("calibration.flat"), "{err}");
            assert!(err.to_string().contains("row 1, column 6"), "{err}");
        }
        let mut refs = vec![0.0f64; 24];
        refs[5] = 64.000001;
        write_array(dir.join("refs.npy"), &[12, 2], &refs).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}[centroid]\nreference_slopes = \"refs.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(
            err.field.as_deref(),
            Some("centroid.reference_slopes"),
            "{err}"
        );
        // (1, H, W) is a map for every key, as the guide says; (2, H, W) is not.
        write_array(dir.join("cube.npy"), &[1, 48, 64], &vec![1.0f64; n]).unwrap();
        write_array(dir.join("two.npy"), &[2, 48, 64], &vec![1.0f64; 2 * n]).unwrap();
        for key in ["background", "flat", "pixel_weight"] {
            parse_in(
                &dir,
                &format!("{BASE}[calibration]\n{key} = \"cube.npy\"\n"),
            )
            .unwrap();
            let err =
                parse_in(&dir, &format!("{BASE}[calibration]\n{key} = \"two.npy\"\n")).unwrap_err();
            assert!(
                err.to_string().contains("(2, 48, 64); expected (48, 64)"),
                "{err}"
            );
        }
    }

    #[test]
    fn canary_example() {
        let c = ProcessingConfig::load(examples().join("canary.toml")).unwrap();
        assert_eq!(
            c.camera,
            Camera {
                width: 112,
                height: 112,
                bit_depth: 16
            }
        );
        assert_eq!(c.windows.len(), 49);
        assert_eq!(
            c.windows[8],
            SubapertureWindow {
                x: 16,
                y: 16,
                width: 16,
                height: 16
            }
        );
        assert_eq!(
            *c.windows.last().unwrap(),
            SubapertureWindow {
                x: 96,
                y: 96,
                width: 16,
                height: 16
            }
        );
        assert_eq!(c.background.as_ref().unwrap().len(), 112 * 112);
        assert!(c.background.as_ref().unwrap().iter().all(|&b| b == 50 * 16));
        assert_eq!(c.gain, None);
        assert_eq!(c.rule, SelectionRule::SubtractNext);
        assert_eq!(c.pixels, PixelCounts::All(20));
        assert_eq!(c.level_filter, None);
        assert_eq!(c.min_flux, 0);
        c.validate().unwrap();
    }

    #[test]
    fn canary_vignetted_example() {
        let c = ProcessingConfig::load(examples().join("canary-vignetted.toml")).unwrap();
        assert_eq!(c.windows.len(), 36);
        let layout = c.grid.as_ref().unwrap();
        assert_eq!(layout.skip.len(), 13);
        let corner = |x, y| SubapertureWindow {
            x,
            y,
            width: 16,
            height: 16,
        };
        for w in [
            corner(0, 0),
            corner(96, 0),
            corner(0, 96),
            corner(96, 96),
            corner(48, 48),
        ] {
            assert!(!c.windows.contains(&w), "{w:?}");
        }
        // first valid window is column 2 of row 0
        assert_eq!(c.windows[0], corner(32, 0));
        assert_eq!(c.pixels, PixelCounts::All(20));
    }

    #[test]
    fn defaults() {
        let c = parse(BASE).unwrap();
        assert_eq!(c.windows.len(), 12);
        assert_eq!(c.rule, SelectionRule::SubtractNext);
        assert_eq!(c.pixels, PixelCounts::All(20));
        assert_eq!(
            (c.background.clone(), c.gain.clone(), c.threshold),
            (None, None, None)
        );
        assert_eq!((c.reference_slopes.clone(), c.min_flux), (None, 0));
        let expected = ProcessingConfig::from_grid(
            c.camera,
            RegularGrid {
                x: 0,
                y: 0,
                columns: 4,
                rows: 3,
                width: 16,
                height: 16,
                pitch_x: 16,
                pitch_y: 16,
            },
            &[],
        );
        assert_eq!(c, expected);
    }

    #[test]
    fn all_keys_parse() {
        let text = r#"
[camera]
width = 40
height = 20
bit_depth = 10

[[subapertures.window]]
x = 0
y = 0
width = 10
height = 10

[[subapertures.window]]
x = 30
y = 10
width = 10
height = 10

[calibration]
background_counts = -0.03125
threshold_counts = 3.5

[selection]
rule = "subtract-mean"
mean_count = 4
pixels = [5, 100]

[selection.level_filter]
gain_shift = 4

[centroid]
min_flux_counts = 12.5
"#;
        let c = parse(text).unwrap();
        assert_eq!(
            c.windows[1],
            SubapertureWindow {
                x: 30,
                y: 10,
                width: 10,
                height: 10
            }
        );
        // -0.5 in 1/16 count rounds away from zero
        assert!(c.background.as_ref().unwrap().iter().all(|&b| b == -1));
        assert_eq!(c.threshold, Some(56));
        assert_eq!(c.rule, SelectionRule::SubtractMean { count: 4 });
        assert_eq!(c.pixels, PixelCounts::PerSubaperture(vec![5, 100]));
        assert_eq!(c.level_filter, Some(LevelFilter { gain_shift: 4 }));
        assert_eq!(c.min_flux, 200);
        assert_eq!(c.grid, None);
        // integers are accepted for float keys
        let c = parse(&format!("{BASE}\n[calibration]\nbackground_counts = 50\n")).unwrap();
        assert!(c.background.unwrap().iter().all(|&b| b == 800));
        for (name, rule) in [
            ("threshold", SelectionRule::Threshold),
            (
                "subtract-next-distinct",
                SelectionRule::SubtractNextDistinct,
            ),
            ("subtract-next", SelectionRule::SubtractNext),
        ] {
            let c = parse(&format!("{BASE}\n[selection]\nrule = \"{name}\"\n")).unwrap();
            assert_eq!(c.rule, rule);
        }
    }

    #[test]
    fn pitch_and_skip() {
        let text = BASE
            .replace(
                "height = 16\n",
                "height = 16\npitch_x = 20\npitch_y = 16\nskip = [[3, 0], [0, 2]]\n",
            )
            .replace("width = 64", "width = 80");
        let c = parse(&text).unwrap();
        assert_eq!(c.windows.len(), 10);
        assert_eq!(
            c.windows[1],
            SubapertureWindow {
                x: 20,
                y: 0,
                width: 16,
                height: 16
            }
        );
        assert_eq!(
            c.windows[3],
            SubapertureWindow {
                x: 0,
                y: 16,
                width: 16,
                height: 16
            }
        );
        assert_eq!(
            c.windows[7],
            SubapertureWindow {
                x: 20,
                y: 32,
                width: 16,
                height: 16
            }
        );

        let err = invalid(&BASE.replace("height = 16\n", "height = 16\nskip = [[4, 0]]\n"));
        assert_eq!(err.field.as_deref(), Some("subapertures.grid.skip"));
        assert!(
            err.message.contains("[4, 0] is outside the 4x3 grid"),
            "{err}"
        );
        let err = invalid(&BASE.replace("height = 16\n", "height = 16\nskip = [[1, 1], [1, 1]]\n"));
        assert!(err.message.contains("twice"), "{err}");
    }

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

    #[test]
    fn unknown_keys_are_errors() {
        for (text, key) in [
            (
                BASE.replace("bit_depth = 12", "bit_depth = 12\nexposure = 3"),
                "exposure",
            ),
            (format!("{BASE}\n[selection]\npixel = 20\n"), "pixel"),
            (
                format!("{BASE}\n[calibration]\nbackground_count = 50\n"),
                "background_count",
            ),
            (
                format!("{BASE}\n[centroids]\nmin_flux_counts = 0\n"),
                "centroids",
            ),
            (BASE.replace("columns", "cols"), "cols"),
        ] {
            let err = invalid(&text);
            assert_eq!(err.kind, ConfigFileErrorKind::Toml, "{key}");
            assert!(
                err.message.contains(&format!("unknown field `{key}`")),
                "{err}"
            );
            assert!(err.message.contains("line"), "{err}");
        }
        let err = invalid(&format!("{BASE}\n[selection]\nrule = \"brightest\"\n"));
        assert!(err.message.contains("subtract-next-distinct"), "{err}");
        let err = invalid("[camera]\nwidth = 1\nheight = 1\nbit_depth = 8\n");
        assert!(
            err.message.contains("missing field `subapertures`"),
            "{err}"
        );
    }

    #[test]
    fn conflicting_and_missing_keys() {
        let err = invalid(&format!("{BASE}\n[selection]\nrule = \"subtract-mean\"\n"));
        assert_eq!(err.field.as_deref(), Some("selection.mean_count"));
        let err = invalid(&format!("{BASE}\n[selection]\nmean_count = 3\n"));
        assert!(err.message.contains("only"), "{err}");
        let err = invalid(&format!(
            "{BASE}\n[selection]\nrule = \"subtract-mean\"\nmean_count = 17\n"
        ));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::MeanCount { count: 17 })
        );
        let err = invalid(&format!(
            "{BASE}\n[selection]\nrule = \"threshold\"\n[selection.level_filter]\ngain_shift = 3\n"
        ));
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::LevelFilterWithoutSubtraction)
        );
        assert_eq!(err.field.as_deref(), Some("selection.level_filter"));
        let err = invalid(&format!(
            "{BASE}\n[selection.level_filter]\ngain_shift = 0\n"
        ));
        assert_eq!(
            err.field.as_deref(),
            Some("selection.level_filter.gain_shift")
        );
        let err = invalid(&format!(
            "{BASE}\n[calibration]\nbackground = \"b.npy\"\nbackground_counts = 3\n"
        ));
        assert_eq!(err.field.as_deref(), Some("calibration.background"));
        let err = invalid(&format!("{BASE}\n[subapertures.file]\n"));
        assert_eq!(err.kind, ConfigFileErrorKind::Toml);
        let err = invalid(&format!(
            "{BASE}\n[[subapertures.window]]\nx = 0\ny = 0\nwidth = 1\nheight = 1\n"
        ));
        assert!(err.message.contains("exactly one"), "{err}");
        let err = invalid(&format!("{BASE}\n[centroid]\nmin_flux_counts = -1\n"));
        assert_eq!(err.field.as_deref(), Some("centroid.min_flux_counts"));
        let err = invalid(&format!("{BASE}\n[calibration]\nthreshold_counts = 3e7\n"));
        assert_eq!(err.field.as_deref(), Some("calibration.threshold_counts"));
        let err = invalid(&format!(
            "{BASE}\n[calibration]\nbackground_counts = 70000\n"
        ));
        assert_eq!(err.field.as_deref(), Some("calibration.background_counts"));
    }

    #[test]
    fn maps_are_loaded_and_converted() {
        let dir = temp_dir("maps");
        let n = 64 * 48;
        let bg: Vec<f64> = (0..n).map(|i| (i % 7) as f64 * 1.03125 - 2.0).collect();
        write_array(dir.join("bg.fits"), &[48, 64], &bg).unwrap();
        let flat: Vec<f32> = (0..n).map(|i| 0.5 + (i % 5) as f32 * 0.25).collect();
        write_array(dir.join("flat.npy"), &[48, 64], &flat).unwrap();
        write_array(dir.join("w.npy"), &[48, 64], &vec![2u8; n]).unwrap();
        let refs: Vec<f64> = (0..24).map(|i| i as f64 / 8.0 - 1.0).collect();
        write_array(dir.join("ref.npy"), &[12, 2], &refs).unwrap();
        let text = format!(
            "{BASE}\n[calibration]\nbackground = \"bg.fits\"\nflat = \"flat.npy\"\npixel_weight = \"w.npy\"\n[centroid]\nreference_slopes = \"ref.npy\"\n"
        );
        let c = parse_in(&dir, &text).unwrap();
        let b = c.background.as_ref().unwrap();
        for i in 0..n {
            assert_eq!(b[i], (bg[i] * 16.0).round() as i32);
            assert_eq!(
                c.gain.as_ref().unwrap()[i],
                (flat[i] as f64 * 2.0 * 4096.0).round() as u16
            );
        }
        assert_eq!(c.reference_slopes.as_ref().unwrap()[3], [-16384, -8192]);
    }

    #[test]
    fn map_of_wrong_size() {
        let dir = temp_dir("mapsize");
        write_array(dir.join("bg.npy"), &[64, 48], &vec![1.0f64; 64 * 48]).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nbackground = \"bg.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(err.kind, ConfigFileErrorKind::Shape);
        assert_eq!(err.field.as_deref(), Some("calibration.background"));
        assert!(
            err.message
                .contains("bg.npy has shape (64, 48); expected (48, 64)"),
            "{err}"
        );

        write_array(dir.join("ref.npy"), &[11, 2], &[0.0f64; 22]).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[centroid]\nreference_slopes = \"ref.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(err.kind, ConfigFileErrorKind::Shape);
        assert!(err.message.contains("(12, 2)"), "{err}");
    }

    #[test]
    fn gain_out_of_range() {
        let dir = temp_dir("gain");
        let n = 64 * 48;
        let mut flat = vec![1.0f64; n];
        flat[64 * 2 + 5] = 9.0;
        write_array(dir.join("flat.npy"), &[48, 64], &flat).unwrap();
        write_array(dir.join("w.npy"), &[48, 64], &vec![2.0f64; n]).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nflat = \"flat.npy\"\npixel_weight = \"w.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(err.kind, ConfigFileErrorKind::Value);
        assert_eq!(
            err.field.as_deref(),
            Some("calibration.flat * calibration.pixel_weight")
        );
        assert!(
            err.message
                .contains("pixel (row 2, column 5) has gain 18 (flat 9 x weight 2)"),
            "{err}"
        );
        // negative gain
        flat[64 * 2 + 5] = -0.5;
        write_array(dir.join("flat.npy"), &[48, 64], &flat).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nflat = \"flat.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(err.field.as_deref(), Some("calibration.flat"));
        assert!(err.message.contains("gain -0.5"), "{err}");
        // 65535/4096 is the largest gain; NaN is refused
        flat[64 * 2 + 5] = 65535.0 / 4096.0;
        write_array(dir.join("flat.npy"), &[48, 64], &flat).unwrap();
        let c = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nflat = \"flat.npy\"\n"),
        )
        .unwrap();
        assert_eq!(c.gain.unwrap()[64 * 2 + 5], 65535);
        flat[0] = f64::NAN;
        write_array(dir.join("flat.npy"), &[48, 64], &flat).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nflat = \"flat.npy\"\n"),
        )
        .unwrap_err();
        assert!(err.message.contains("row 0, column 0"), "{err}");
    }

    #[test]
    fn background_out_of_range() {
        let dir = temp_dir("bgrange");
        let mut bg = vec![0.0f64; 64 * 48];
        bg[64 + 1] = -65536.5;
        write_array(dir.join("bg.npy"), &[48, 64], &bg).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nbackground = \"bg.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(err.field.as_deref(), Some("calibration.background"));
        assert!(
            err.message
                .contains("pixel (row 1, column 1) is -65536.5 counts"),
            "{err}"
        );
        // the limit itself is fine, and (1, h, w) is accepted
        bg[64 + 1] = -65536.0;
        write_array(dir.join("bg.npy"), &[1, 48, 64], &bg).unwrap();
        let c = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nbackground = \"bg.npy\"\n"),
        )
        .unwrap();
        assert_eq!(c.background.unwrap()[65], -(1 << 20));
    }

    #[test]
    fn reference_slopes_out_of_range() {
        let dir = temp_dir("refrange");
        let mut refs = vec![0.0f64; 24];
        refs[7] = 64.5;
        write_array(dir.join("r.npy"), &[12, 2], &refs).unwrap();
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[centroid]\nreference_slopes = \"r.npy\"\n"),
        )
        .unwrap_err();
        assert!(
            err.message.contains("sub-aperture 3 has y = 64.5 pixels"),
            "{err}"
        );
    }

    #[test]
    fn relative_paths_resolve_against_the_toml_directory() {
        let dir = temp_dir("relative");
        let conf = dir.join("conf");
        std::fs::create_dir_all(conf.join("maps")).unwrap();
        write_array(conf.join("maps/bg.npy"), &[48, 64], &vec![2.0f64; 64 * 48]).unwrap();
        write_array(dir.join("abs.npy"), &[12], &[7u16; 12]).unwrap();
        let text = format!(
            "{BASE}\n[calibration]\nbackground = \"maps/bg.npy\"\n[selection]\npixels_file = {}\n",
            toml::Value::String(dir.join("abs.npy").display().to_string())
        );
        std::fs::write(conf.join("c.toml"), &text).unwrap();
        // loaded from anywhere: the current directory plays no part
        let c = ProcessingConfig::load(conf.join("c.toml")).unwrap();
        assert!(c.background.unwrap().iter().all(|&b| b == 32));
        assert_eq!(c.pixels, PixelCounts::PerSubaperture(vec![7; 12]));
        // a missing file names the resolved path and the key
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nflat = \"maps/flat.fits\"\n"),
        )
        .unwrap_err();
        assert_eq!(err.kind, ConfigFileErrorKind::Data);
        assert_eq!(err.field.as_deref(), Some("calibration.flat"));
        assert!(
            err.message
                .contains(&dir.join("maps/flat.fits").display().to_string()),
            "{err}"
        );
        let err = parse_in(
            &dir,
            &format!("{BASE}\n[calibration]\nflat = \"flat.txt\"\n"),
        )
        .unwrap_err();
        assert!(err.message.contains("unrecognised file type"), "{err}");
    }

    #[test]
    fn windows_and_pixels_files() {
        let dir = temp_dir("winfile");
        let windows: Vec<i32> = vec![0, 0, 8, 8, 8, 0, 8, 8, 4, 8, 8, 8];
        write_array(dir.join("win.fits"), &[3, 4], &windows).unwrap();
        write_array(dir.join("n.npy"), &[3], &[1.0f64, 2.0, 64.0]).unwrap();
        let head = "[camera]\nwidth = 16\nheight = 16\nbit_depth = 8\n[subapertures]\nfile = \"win.fits\"\n";
        let c = parse_in(
            &dir,
            &format!("{head}[selection]\npixels_file = \"n.npy\"\n"),
        )
        .unwrap();
        assert_eq!(
            c.windows[2],
            SubapertureWindow {
                x: 4,
                y: 8,
                width: 8,
                height: 8
            }
        );
        assert_eq!(c.pixels, PixelCounts::PerSubaperture(vec![1, 2, 64]));

        write_array(dir.join("win.fits"), &[4, 3], &windows).unwrap();
        let err = parse_in(&dir, head).unwrap_err();
        assert_eq!(err.kind, ConfigFileErrorKind::Shape);
        assert!(
            err.message.contains("(4, 3)") && err.message.contains("(n, 4)"),
            "{err}"
        );

        write_array(
            dir.join("win.fits"),
            &[3, 4],
            &[
                0.0, 0.0, 8.0, 8.5, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0f64,
            ],
        )
        .unwrap();
        let err = parse_in(&dir, head).unwrap_err();
        assert!(err.message.contains("row 0, column 3 is 8.5"), "{err}");

        write_array(dir.join("win.fits"), &[3, 4], &windows).unwrap();
        write_array(dir.join("n.npy"), &[3, 1], &[1.0f64, 2.0, 64.0]).unwrap();
        let err = parse_in(
            &dir,
            &format!("{head}[selection]\npixels_file = \"n.npy\"\n"),
        )
        .unwrap_err();
        assert_eq!(
            (err.kind, err.field.as_deref()),
            (ConfigFileErrorKind::Shape, Some("selection.pixels_file"))
        );
    }

    #[test]
    fn save_and_reload_round_trip() {
        let dir = temp_dir("save");
        // canary: everything inline, grid kept
        let canary = ProcessingConfig::load(examples().join("canary-vignetted.toml")).unwrap();
        let path = canary.save(&dir, "canary").unwrap();
        assert_eq!(ProcessingConfig::load(&path).unwrap(), canary);
        let text = canary.to_toml_string("canary");
        assert!(
            text.contains("[subapertures.grid]") && text.contains("background_counts = 50.0"),
            "{text}"
        );
        assert!(!text.contains(".npy"), "{text}");

        // maps, a window list and per-sub-aperture N
        let camera = Camera {
            width: 30,
            height: 20,
            bit_depth: 14,
        };
        let windows: Vec<SubapertureWindow> = (0..5)
            .map(|i| SubapertureWindow {
                x: i * 5,
                y: i,
                width: 5,
                height: 7,
            })
            .collect();
        let mut c = ProcessingConfig::new(camera, windows);
        c.background = Some((0..600).map(|i| i * 37 % 2001 - 1000).collect());
        c.gain = Some((0..600).map(|i| (i * 911 % 65536) as u16).collect());
        c.threshold = Some(-7);
        c.rule = SelectionRule::SubtractMean { count: 3 };
        c.pixels = PixelCounts::PerSubaperture(vec![1, 5, 20, 35, 2]);
        c.level_filter = Some(LevelFilter { gain_shift: 5 });
        c.reference_slopes = Some((0..5).map(|i| [i * 12345 - 30000, -i * 99]).collect());
        c.min_flux = 12345;
        let path = c.save(&dir, "tuned").unwrap();
        assert_eq!(ProcessingConfig::load(&path).unwrap(), c);
        for side in [
            "tuned-background.npy",
            "tuned-gain.npy",
            "tuned-reference-slopes.npy",
        ] {
            assert!(dir.join(side).exists(), "{side}");
        }

        // many windows go to a file, and so does a long N list
        let camera = Camera {
            width: 400,
            height: 400,
            bit_depth: 16,
        };
        let windows: Vec<SubapertureWindow> = (0..300)
            .map(|i| SubapertureWindow {
                x: (i % 20) * 20,
                y: (i / 20) * 20,
                width: 20,
                height: 20,
            })
            .collect();
        let mut c = ProcessingConfig::new(camera, windows);
        c.pixels = PixelCounts::PerSubaperture((0..300).map(|i| 1 + i as u16).collect());
        let path = c.save(&dir, "big").unwrap();
        assert!(dir.join("big-windows.npy").exists() && dir.join("big-pixels.npy").exists());
        assert_eq!(ProcessingConfig::load(&path).unwrap(), c);

        // invalid configurations are refused
        c.pixels = PixelCounts::All(0);
        let err = c.save(&dir, "bad").unwrap_err();
        assert_eq!(
            err.kind,
            ConfigFileErrorKind::Invalid(ConfigError::PixelCountZeroAll)
        );
        assert!(c.save(&dir, "../x").is_err());
    }

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

    fn memory_values() -> ConfigValues {
        let camera = Camera {
            width: 64,
            height: 48,
            bit_depth: 12,
        };
        let table: Vec<f64> = [[0, 0, 16, 16], [16, 0, 16, 16], [32, 16, 16, 16]]
            .iter()
            .flatten()
            .map(|&v| v as f64)
            .collect();
        let mut v = ConfigValues::new(
            camera,
            SubapertureValues::Table(ArrayValues::new(vec![3, 4], table)),
        );
        v.background = Some(BackgroundValues::Map(ArrayValues::new(
            vec![48, 64],
            (0..64 * 48).map(|i| (i % 7) as f64 * 0.5).collect(),
        )));
        v.flat = Some(ArrayValues::new(vec![48, 64], vec![1.25; 64 * 48]));
        v.pixel_weight = Some(ArrayValues::new(vec![1, 48, 64], vec![0.5; 64 * 48]));
        v.threshold_counts = Some(3.0);
        v.rule = RuleName::SubtractMean;
        v.mean_count = Some(4);
        v.pixels = PixelValues::Table(ArrayValues::new(vec![3], vec![5.0, 6.0, 7.0]));
        v.level_filter = Some(LevelFilter { gain_shift: 3 });
        v.reference_slopes = Some(ArrayValues::new(
            vec![3, 2],
            vec![0.5, -0.25, 0.0, 1.0, -2.0, 0.125],
        ));
        v.min_flux_counts = Some(10.0);
        v
    }

    #[test]
    fn values_in_memory_convert_as_a_file_does() {
        let c = ProcessingConfig::from_values(memory_values(), Path::new("keywords")).unwrap();
        assert_eq!(c.windows.len(), 3);
        assert_eq!(c.windows[2].x, 32);
        assert_eq!(c.rule, SelectionRule::SubtractMean { count: 4 });
        assert_eq!(c.pixels, PixelCounts::PerSubaperture(vec![5, 6, 7]));
        assert_eq!(c.gain.as_ref().unwrap()[0], 2560); // 1.25 x 0.5 x 4096
        assert_eq!(c.background.as_ref().unwrap()[3], 24); // 1.5 counts in 1/16
        assert_eq!(c.threshold, Some(48));
        assert_eq!(c.min_flux, 160);
        assert_eq!(c.reference_slopes.as_ref().unwrap()[2], [-131072, 8192]);
        // saved and loaded back from files: the same configuration
        let dir = temp_dir("values");
        let path = c.save(&dir, "mem").unwrap();
        assert_eq!(ProcessingConfig::load(path).unwrap(), c);
        // a 0-d N is one N for all
        let mut v = memory_values();
        v.pixels = PixelValues::Table(ArrayValues::new(vec![], vec![9.0]));
        let c = ProcessingConfig::from_values(v, Path::new("keywords")).unwrap();
        assert_eq!(c.pixels, PixelCounts::All(9));
    }

    #[test]
    fn values_in_memory_errors_name_the_key_not_a_file() {
        let origin = Path::new("keywords");
        let mut v = memory_values();
        if let Some(BackgroundValues::Map(a)) = &mut v.background {
            a.data[64 + 2] = f64::NAN;
        }
        let err = ProcessingConfig::from_values(v, origin).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("calibration.background"));
        assert!(
            err.message
                .starts_with("pixel (row 1, column 2) is NaN counts"),
            "{err}"
        );
        let mut v = memory_values();
        v.flat = Some(ArrayValues::new(vec![64, 48], vec![1.0; 64 * 48]));
        let err = ProcessingConfig::from_values(v, origin).unwrap_err();
        assert_eq!(err.kind, ConfigFileErrorKind::Shape);
        assert_eq!(
            err.message,
            "shape (64, 48); expected (48, 64), the camera's (height, width)"
        );
        let mut v = memory_values();
        v.pixels = PixelValues::Table(ArrayValues::new(vec![3], vec![5.0, 2.5, 7.0]));
        let err = ProcessingConfig::from_values(v, origin).unwrap_err();
        assert_eq!(
            err.message,
            "entry 1 is 2.5; expected an integer in 0..=65535"
        );
        let mut v = memory_values();
        if let SubapertureValues::Table(a) = &mut v.subapertures {
            a.data[8] = 60.0;
        }
        let err = ProcessingConfig::from_values(v, origin).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("subapertures.file"));
        assert!(
            err.message.starts_with(
                "sub-aperture 2 (row 2: x = 60, y = 16, 16x16 pixels) extends outside"
            ),
            "{err}"
        );
        assert!(err.to_string().starts_with("keywords: subapertures.file: "));
    }

    #[test]
    fn rule_names() {
        for (rule, name) in RuleName::ALL {
            assert_eq!(RuleName::from_name(name), Some(rule));
            assert_eq!(rule.name(), name);
        }
        assert_eq!(RuleName::from_name("subtract_next"), None);
        assert_eq!(
            RuleName::of(SelectionRule::SubtractMean { count: 2 }),
            RuleName::SubtractMean
        );
    }
}
