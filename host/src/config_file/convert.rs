//! [`ConfigValues`] in natural units to the device's integers (the table
//! in the module documentation of [`super`]): each range checked on the
//! value as written, each shape against the camera and the windows, then
//! [`Config::validate`](brightpix_protocol::Config::validate) with its
//! errors named by the key they come from.

use std::path::Path;

use brightpix_protocol::{
    Camera, ConfigError, RegularGrid, SelectionRule, SubapertureWindow, MAX_BACKGROUND_ABS,
    MAX_REFERENCE_SLOPE_ABS, MAX_SUBAPERTURES, MAX_THRESHOLD_ABS,
};

use super::errors::{ErrorSite, Result, Sources};
use super::{
    ArrayValues, BackgroundValues, ConfigFileErrorKind, ConfigValues, GridLayout, GridValues,
    PixelCounts, PixelValues, ProcessingConfig, RuleName, SubapertureValues, DEFAULT_PIXELS,
};

/// Converts and validates one configuration's values.
pub(super) struct Converter {
    errors: ErrorSite,
}

impl Converter {
    /// `origin` names the configuration in errors.
    pub(super) fn new(origin: &Path) -> Self {
        Converter {
            errors: ErrorSite::new(origin),
        }
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
            return Err(self.errors.shape_error(
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
                    Err(self.errors.value_error(
                        field,
                        array.named(format!("{at} is {v}; expected an integer in 0..=65535")),
                    ))
                }
            })
            .collect()
    }

    /// Converts and validates values in natural units.
    pub(super) fn convert(&self, values: ConfigValues) -> Result<ProcessingConfig> {
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
                    return Err(self.errors.shape_error(
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
                (RuleName::SubtractMean, None) => return Err(self.errors.value_error(
                    "selection.mean_count",
                    "rule = \"subtract-mean\" needs mean_count (M, the number of values averaged)",
                )),
                (_, Some(_)) => {
                    return Err(self.errors.value_error(
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
                        return Err(self.errors.shape_error(
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
            crop: values.crop,
        };
        // Camera, windows and selection first, so that map shapes are
        // checked against a sound camera and window list.
        config
            .validate()
            .map_err(|e| self.errors.explain(e, &config, &sources))?;

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
                        self.errors.value_error(
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
                    self.errors.value_error(
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
                return Err(self.errors.value_error(
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
                return Err(self.errors.shape_error(
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
                        return Err(self.errors.value_error(
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
                return Err(self.errors.value_error(
                    "centroid.min_flux_counts",
                    format!("{v} counts; the minimum flux must be finite and >= 0"),
                ));
            }
            config.min_flux = r as i64;
        }

        config
            .validate()
            .map_err(|e| self.errors.explain(e, &config, &sources))?;
        Ok(config)
    }

    fn grid_layout(&self, g: &GridValues) -> Result<GridLayout> {
        let mut seen = std::collections::HashSet::with_capacity(g.skip.len());
        for &[c, r] in &g.skip {
            if c >= g.columns || r >= g.rows {
                return Err(self.errors.value_error(
                    "subapertures.grid.skip",
                    format!(
                        "[{c}, {r}] is outside the {}x{} grid (columns 0..{}, rows 0..{})",
                        g.columns, g.rows, g.columns, g.rows
                    ),
                ));
            }
            if !seen.insert([c, r]) {
                return Err(self.errors.value_error(
                    "subapertures.grid.skip",
                    format!("[{c}, {r}] is listed twice"),
                ));
            }
        }
        for (key, pitch) in [("pitch_x", g.pitch_x), ("pitch_y", g.pitch_y)] {
            if pitch == Some(0) {
                return Err(self.errors.value_error(
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
            return Err(self.errors.error(
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
                return Err(self.errors.value_error(
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
    use super::super::test_support::*;
    use super::super::*;
    use crate::io::test_util::temp_dir;
    use crate::io::write_array;
    use brightpix_protocol::LevelFilter;

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
}
