//! A configuration in the file's natural units (counts, pixels, plain
//! gains) with its arrays in memory: what a TOML file says once its data
//! files are read (`read`), or what a program builds directly (the
//! Python package). [`ProcessingConfig::from_values`](super::ProcessingConfig::from_values)
//! converts it.

use brightpix_protocol::{Camera, Crop, LevelFilter, SelectionRule, SubapertureWindow};
use serde::Deserialize;

use super::PixelCounts;

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
    pub(super) fn named(&self, text: String) -> String {
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
    /// Where `camera` lies on a larger sensor (`[camera.crop]`).
    pub crop: Option<Crop>,
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
            crop: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
