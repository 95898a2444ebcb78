//! The TOML file's structure, key by key (docs/CONFIG.md says what each
//! means): serde types that refuse unknown keys, read by `read`.
//! Values stay as written; nothing here converts or checks ranges.

use serde::Deserialize;

use super::{GridValues, RuleName};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileConfig {
    pub camera: FileCamera,
    pub subapertures: FileSubapertures,
    #[serde(default)]
    pub calibration: FileCalibration,
    #[serde(default)]
    pub selection: FileSelection,
    #[serde(default)]
    pub centroid: FileCentroid,
    /// What `brightpix tune` assumed and found: a record for people, not
    /// read by the loader (any content is accepted and ignored).
    #[serde(default, rename = "tuned")]
    _tuned: Option<toml::Table>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileCamera {
    pub width: u16,
    pub height: u16,
    pub bit_depth: u8,
    pub crop: Option<FileCrop>,
}

/// `[camera.crop]`: where the camera lies on a larger sensor.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileCrop {
    pub x: u16,
    pub y: u16,
    pub sensor_width: u16,
    pub sensor_height: u16,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileSubapertures {
    pub grid: Option<GridValues>,
    pub window: Option<Vec<FileWindow>>,
    pub file: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileWindow {
    pub x: u16,
    pub y: u16,
    pub width: u16,
    pub height: u16,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileCalibration {
    pub background: Option<String>,
    pub background_counts: Option<f64>,
    pub flat: Option<String>,
    pub pixel_weight: Option<String>,
    pub threshold_counts: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileSelection {
    pub rule: Option<RuleName>,
    pub mean_count: Option<u16>,
    pub pixels: Option<toml::Value>,
    pub pixels_file: Option<String>,
    pub level_filter: Option<FileLevelFilter>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileLevelFilter {
    pub gain_shift: u8,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileCentroid {
    pub reference_slopes: Option<String>,
    pub min_flux_counts: Option<f64>,
}
