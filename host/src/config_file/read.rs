//! Reading a configuration: the TOML text parsed by `schema`, and
//! the data files it names (maps, window and N tables: `.npy` or FITS,
//! relative paths against the TOML file's directory) read into
//! [`ConfigValues`]. Which keys conflict or are missing is decided here;
//! ranges and shapes are checked by `convert`.

use std::path::{Path, PathBuf};

use brightpix_protocol::{Camera, Crop, LevelFilter, SubapertureWindow};

use super::errors::{ErrorSite, Result};
use super::schema::FileConfig;
use super::{
    ArrayValues, BackgroundValues, ConfigFileErrorKind, ConfigValues, PixelCounts, PixelValues,
    SubapertureValues,
};
use crate::io;

/// Reads one configuration file's text and the files it names.
pub(super) struct FileReader {
    errors: ErrorSite,
    /// The directory relative data-file paths resolve against.
    base: PathBuf,
}

impl FileReader {
    /// For the TOML file at `file` (named in errors; its directory anchors
    /// relative paths).
    pub(super) fn new(file: &Path) -> Self {
        FileReader {
            errors: ErrorSite::new(file),
            base: file.parent().map(Path::to_path_buf).unwrap_or_default(),
        }
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
        let array = io::read_array(&path).map_err(|e| {
            self.errors
                .error(field, ConfigFileErrorKind::Data, e.to_string())
        })?;
        Ok(ArrayValues {
            label: Some(path.display().to_string()),
            shape: array.shape,
            data: array.data,
        })
    }

    /// The TOML text, its data files read (nothing converted yet).
    pub(super) fn values(&self, text: &str) -> Result<ConfigValues> {
        let file: FileConfig = toml::from_str(text).map_err(|e| {
            self.errors
                .error("", ConfigFileErrorKind::Toml, e.to_string().trim_end())
        })?;
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
            _ => return Err(self.errors.value_error(
                "subapertures",
                "give exactly one of [subapertures.grid], [[subapertures.window]] or subapertures.file",
            )),
        };
        let mut values = ConfigValues::new(camera, subapertures);
        values.crop = file.camera.crop.map(|c| Crop {
            x: c.x,
            y: c.y,
            sensor_width: c.sensor_width,
            sensor_height: c.sensor_height,
        });

        let sel = file.selection;
        values.rule = sel.rule.unwrap_or_default();
        values.mean_count = sel.mean_count;
        values.pixels = match (&sel.pixels, &sel.pixels_file) {
            (Some(_), Some(_)) => {
                return Err(self.errors.value_error(
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
                (Some(_), Some(_)) => return Err(self.errors.value_error(
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
        Ok(values)
    }

    fn pixels_value(&self, value: &toml::Value) -> Result<PixelCounts> {
        let field = "selection.pixels";
        let one = |v: &toml::Value, what: &str| -> Result<u16> {
            match v.as_integer() {
                Some(n) if (0..=65535).contains(&n) => Ok(n as u16),
                _ => Err(self.errors.value_error(
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
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::super::*;
    use crate::io::test_util::temp_dir;
    use crate::io::write_array;
    use brightpix_protocol::{ConfigError, SelectionRule};

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

    /// `[camera.crop]`: the camera is a rectangle of a larger sensor (one
    /// board of a rig); checked against the sensor like the rest.
    #[test]
    fn a_crop_places_the_camera_on_its_sensor() {
        let crop = "\n[camera.crop]\nx = 16\ny = 32\nsensor_width = 112\nsensor_height = 112\n";
        let c =
            parse(&BASE.replace("bit_depth = 12\n", &format!("bit_depth = 12\n{crop}"))).unwrap();
        assert_eq!(
            c.crop,
            Some(brightpix_protocol::Crop {
                x: 16,
                y: 32,
                sensor_width: 112,
                sensor_height: 112
            })
        );
        assert_eq!(c.view().crop, c.crop);
        assert_eq!(parse(BASE).unwrap().crop, None);
        // 32 + 48 rows > a sensor of 64.
        let err = invalid(&BASE.replace(
            "bit_depth = 12\n",
            "bit_depth = 12\n[camera.crop]\nx = 0\ny = 32\nsensor_width = 64\nsensor_height = 64\n",
        ));
        assert_eq!(err.field.as_deref(), Some("camera.crop"), "{err}");
        assert!(
            matches!(
                err.kind,
                ConfigFileErrorKind::Invalid(ConfigError::CropOutsideSensor { .. })
            ),
            "{err}"
        );
        assert!(err.message.contains("64x64 sensor"), "{err}");
        // Every key is required, no other is known.
        let err = invalid(&BASE.replace(
            "bit_depth = 12\n",
            "bit_depth = 12\n[camera.crop]\nx = 0\ny = 0\nsensor_width = 64\n",
        ));
        assert!(err.message.contains("sensor_height"), "{err}");
        let err = invalid(&BASE.replace(
            "bit_depth = 12\n",
            "bit_depth = 12\n[camera.crop]\nx = 0\ny = 0\nwidth = 64\nsensor_width = 64\nsensor_height = 64\n",
        ));
        assert!(err.message.contains("unknown field `width`"), "{err}");
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
}
