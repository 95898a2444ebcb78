//! A configuration written back as TOML: inline where the format allows,
//! in sibling `.npy` files where it does not (maps, reference slopes, long
//! lists). Loading the result gives the same [`ProcessingConfig`].

use std::path::{Path, PathBuf};

use brightpix_protocol::SelectionRule;

use super::{ConfigFileError, ConfigFileErrorKind, PixelCounts, ProcessingConfig};
use crate::io;

/// Windows longer than this are saved as a sibling `.npy` instead of inline.
const INLINE_LIST_MAX: usize = 256;

impl ProcessingConfig {
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
        if let Some(c) = self.crop {
            t.push_str(
                "\n# This camera is a rectangle of a larger sensor, which the board's camera\n\
                 # interface crops (one board of a rig: brightpix rig plan). Everything else\n\
                 # here is in the rectangle's pixels.\n[camera.crop]\n",
            );
            t.push_str(&format!(
                "x = {}  # the rectangle's left column on the sensor, pixels\ny = {}  # its top row on the sensor, pixels\n",
                c.x, c.y
            ));
            t.push_str(&format!(
                "sensor_width = {}  # pixels\nsensor_height = {}  # pixels\n",
                c.sensor_width, c.sensor_height
            ));
        }

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

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::super::*;
    use crate::io::test_util::temp_dir;

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
        // The same as one board's part of a larger sensor: [camera.crop].
        c.crop = Some(brightpix_protocol::Crop {
            x: 8,
            y: 20,
            sensor_width: 64,
            sensor_height: 40,
        });
        let path = c.save(&dir, "board").unwrap();
        assert_eq!(ProcessingConfig::load(&path).unwrap(), c);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.contains("[camera.crop]\nx = 8") && text.contains("sensor_height = 40"),
            "{text}"
        );
        c.crop = None;
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
}
