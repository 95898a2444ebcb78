//! Results as an AOT file: one Shack-Hartmann sensor, its geometry,
//! measurements and time, brightpix's provenance.

use std::path::Path;

use brightpix_protocol::SubapertureWindow;
use fitsio::images::{ImageDescription, ImageType};
use fitsio::FitsFile;

use super::super::fits_out::fits_error;
use super::super::output::Staged;
use super::super::results::{Layout, Provenance, Results, Value};
use super::super::{FrameCube, IoError};
use super::tables::*;
use super::{DETECTOR, SENSOR, SOURCE, TELESCOPE, TIME, VERSION};

/// The windows as AOT's sub-aperture mask, if they are square cells of one
/// grid (the pitch their size): the mask (`side x side`, -1 or the window's
/// index), its lowest pixel `(x, y)`, and the cell size.
pub(crate) struct Grid {
    pub side: usize,
    pub mask: Vec<i32>,
    pub origin: (u16, u16),
    pub size: u16,
}

pub(crate) fn grid_of(windows: &[SubapertureWindow]) -> Option<Grid> {
    let size = windows.first()?.width;
    if size == 0 || windows.iter().any(|w| w.width != size || w.height != size) {
        return None;
    }
    let x0 = windows.iter().map(|w| w.x).min()?;
    let y0 = windows.iter().map(|w| w.y).min()?;
    let cells: Vec<(usize, usize)> = windows
        .iter()
        .map(|w| (w.x - x0, w.y - y0))
        .filter(|(dx, dy)| dx % size == 0 && dy % size == 0)
        .map(|(dx, dy)| ((dx / size) as usize, (dy / size) as usize))
        .collect();
    if cells.len() != windows.len() {
        return None;
    }
    // AOT's mask is square: a rectangular grid is padded with -1.
    let side = cells.iter().map(|&(c, r)| c.max(r) + 1).max()?;
    let mut mask = vec![-1i32; side * side];
    for (index, &(c, r)) in cells.iter().enumerate() {
        let cell = &mut mask[r * side + c];
        if *cell != -1 {
            return None; // two windows in one cell: not a grid
        }
        *cell = index as i32;
    }
    Some(Grid {
        side,
        mask,
        origin: (x0, y0),
        size,
    })
}

/// The element types of the images written, with their FITS type.
pub(super) trait Pixel: fitsio::images::WriteImage {
    const TYPE: ImageType;
}
impl Pixel for f64 {
    const TYPE: ImageType = ImageType::Double;
}
impl Pixel for f32 {
    const TYPE: ImageType = ImageType::Float;
}
impl Pixel for i32 {
    const TYPE: ImageType = ImageType::Long;
}
impl Pixel for u16 {
    // BITPIX 16, BZERO 32768.
    const TYPE: ImageType = ImageType::UnsignedShort;
}

pub(super) fn image<T: Pixel>(
    file: &mut FitsFile,
    path: &Path,
    name: &str,
    shape: &[usize],
    data: &[T],
    unit: Option<&str>,
    time: bool,
) -> Result<(), IoError> {
    let e = |err| fits_error(path, err);
    let hdu = file
        .create_image(
            name,
            &ImageDescription {
                data_type: T::TYPE,
                dimensions: shape,
            },
        )
        .map_err(e)?;
    if let Some(unit) = unit {
        hdu.write_key(file, "BUNIT", (unit, "unit of the values"))
            .map_err(e)?;
    }
    if time {
        hdu.write_key(
            file,
            "TIME_UID",
            (format!("ROWREF<{TIME}>").as_str(), "AOT_TIME row of axis 1"),
        )
        .map_err(e)?;
    }
    if !data.is_empty() {
        hdu.write_image(file, data).map_err(e)?;
    }
    Ok(())
}

/// Stages `results` as an AOT file at `path` (a temporary sibling, moved in
/// place by [`Staged::commit`]); `pixels`, if given, become the detector's
/// `PIXEL_INTENSITIES` (one frame per result frame).
pub fn stage(
    path: &Path,
    results: &Results,
    provenance: &Provenance,
    pixels: Option<&FrameCube>,
) -> Result<Staged, IoError> {
    let frames = results.frames();
    if let Some(cube) = pixels {
        if cube.shape.frames != frames {
            return Err(IoError::unexpected(
                path,
                format!("{} frames of pixels", cube.shape.frames),
                format!("one frame of pixels per frame of results ({frames})"),
            ));
        }
    }
    if !provenance.windows.is_empty() && provenance.windows.len() != results.subapertures {
        return Err(IoError::unexpected(
            path,
            format!("{} windows", provenance.windows.len()),
            format!("one window per sub-aperture ({})", results.subapertures),
        ));
    }
    Staged::write(path, |temp| write(temp, results, provenance, pixels))
}

pub(super) fn write(
    path: &Path,
    results: &Results,
    provenance: &Provenance,
    pixels: Option<&FrameCube>,
) -> Result<(), IoError> {
    let e = |err| fits_error(path, err);
    let (frames, s) = (results.frames(), results.subapertures);
    let keywords = provenance.keywords(results, Layout::Vector);
    let mut file = FitsFile::create(path).open().map_err(e)?;
    let primary = file.primary_hdu().map_err(e)?;
    let config = match (&provenance.rule, provenance.config_digest) {
        (Some(rule), Some(digest)) => format!("brightpix {rule}, digest {digest:#010x}"),
        _ => "brightpix".to_string(),
    };
    let header: [(&str, &str, &str); 5] = [
        ("AOT-VERS", VERSION, "Adaptive Optics Telemetry version"),
        ("TIMESYS", "UTC", "time scale"),
        ("AO-MODE", "SCAO", "one sensor"),
        ("SYS-NAME", "brightpix", "system"),
        ("CONFIG", &config, "configuration"),
    ];
    for (key, value, comment) in header {
        primary
            .write_key(&mut file, key, (value, comment))
            .map_err(e)?;
    }
    for (key, value, comment) in &keywords {
        match value {
            Value::Int(v) => primary.write_key(&mut file, key, (*v, *comment)),
            Value::Text(t) => primary.write_key(&mut file, key, (t.as_str(), *comment)),
        }
        .map_err(e)?;
    }

    let grid = grid_of(&provenance.windows);
    let algorithm = match (
        &provenance.rule,
        provenance.pixels,
        provenance.per_subaperture,
    ) {
        (Some(rule), _, true) => format!("brightest pixels, {rule}, N per sub-aperture"),
        (Some(rule), Some(n), false) => format!("brightest pixels, {rule}, N = {n}"),
        _ => "brightest pixels".to_string(),
    };
    let mut sensor = vec![
        ("UID", text(SENSOR)),
        ("TYPE", text("Shack-Hartmann")),
        ("SOURCE_UID", row_ref(SOURCE)),
        ("DIMENSIONS", Cell::Int(2)),
        ("N_VALID_SUBAPERTURES", Cell::Int(s as i64)),
        ("MEASUREMENTS", image_ref("MEASUREMENTS")),
        (
            "SUBAPERTURE_INTENSITIES",
            image_ref("SUBAPERTURE_INTENSITIES"),
        ),
        ("DETECTOR_UID", row_ref(DETECTOR)),
    ];
    if provenance.reference_slopes.is_some() {
        sensor.push(("REF_MEASUREMENTS", image_ref("REF_MEASUREMENTS")));
    }
    if let Some(g) = &grid {
        sensor.push(("SUBAPERTURE_MASK", image_ref("SUBAPERTURE_MASK")));
        sensor.push(("MASK_X_OFFSETS", Cell::Lst(vec![f64::from(g.origin.0)])));
        sensor.push(("MASK_Y_OFFSETS", Cell::Lst(vec![f64::from(g.origin.1)])));
        sensor.push(("SUBAPERTURE_SIZE", Cell::Flt(f64::from(g.size))));
    }
    let mut detector = vec![("UID", text(DETECTOR))];
    if pixels.is_some() {
        detector.push(("PIXEL_INTENSITIES", image_ref("PIXEL_INTENSITIES")));
    }
    let numbers: Vec<f64> = (0..frames)
        .map(|k| (provenance.first_frame + k as u64) as f64)
        .collect();
    let tables = [
        Table {
            name: "AOT_TIME",
            columns: TIME_COLUMNS,
            rows: vec![vec![
                ("UID", text(TIME)),
                ("FRAME_NUMBERS", Cell::Lst(numbers)),
            ]],
        },
        Table {
            name: "AOT_ATMOSPHERIC_PARAMETERS",
            columns: ATMOSPHERE_COLUMNS,
            rows: vec![],
        },
        Table {
            name: "AOT_ABERRATIONS",
            columns: ABERRATION_COLUMNS,
            rows: vec![],
        },
        Table {
            name: "AOT_TELESCOPES",
            columns: TELESCOPE_COLUMNS,
            rows: vec![vec![
                ("UID", text(TELESCOPE)),
                ("TYPE", text("Main Telescope")),
                ("SEGMENT_TYPE", text("Monolithic")),
            ]],
        },
        Table {
            name: "AOT_SOURCES",
            columns: SOURCE_COLUMNS,
            rows: vec![vec![
                ("UID", text(SOURCE)),
                ("TYPE", text("Natural Guide Star")),
            ]],
        },
        Table {
            name: "AOT_DETECTORS",
            columns: DETECTOR_COLUMNS,
            rows: vec![detector],
        },
        Table {
            name: "AOT_SCORING_CAMERAS",
            columns: SCORING_CAMERA_COLUMNS,
            rows: vec![],
        },
        Table {
            name: "AOT_WAVEFRONT_SENSORS",
            columns: SENSOR_COLUMNS,
            rows: vec![sensor],
        },
        Table {
            name: "AOT_WAVEFRONT_SENSORS_SHACK_HARTMANN",
            columns: SHACK_HARTMANN_COLUMNS,
            rows: vec![vec![
                ("UID", text(SENSOR)),
                ("CENTROIDING_ALGORITHM", text(algorithm)),
            ]],
        },
        Table {
            name: "AOT_WAVEFRONT_CORRECTORS",
            columns: CORRECTOR_COLUMNS,
            rows: vec![],
        },
        Table {
            name: "AOT_LOOPS",
            columns: LOOP_COLUMNS,
            rows: vec![],
        },
    ];
    for table in &tables {
        write_table(&mut file, path, table)?;
    }

    let (_, slopes) = results.slopes_in(Layout::Vector);
    image(
        &mut file,
        path,
        "MEASUREMENTS",
        &[frames, 2, s],
        &slopes,
        Some("pix"),
        true,
    )?;
    if let Some(reference) = &provenance.reference_slopes {
        let mut data: Vec<f64> = reference
            .iter()
            .map(|r| f64::from(r[0]) / 65536.0)
            .collect();
        data.extend(reference.iter().map(|r| f64::from(r[1]) / 65536.0));
        image(
            &mut file,
            path,
            "REF_MEASUREMENTS",
            &[2, s],
            &data,
            Some("pix"),
            false,
        )?;
    }
    if let Some(g) = &grid {
        image(
            &mut file,
            path,
            "SUBAPERTURE_MASK",
            &[g.side, g.side],
            &g.mask,
            None,
            false,
        )?;
    }
    image(
        &mut file,
        path,
        "SUBAPERTURE_INTENSITIES",
        &[frames, s],
        &results.flux,
        Some("ADU"),
        true,
    )?;
    if let Some(cube) = pixels {
        let sh = cube.shape;
        image(
            &mut file,
            path,
            "PIXEL_INTENSITIES",
            &[sh.frames, sh.height, sh.width],
            &cube.pixels,
            Some("ADU"),
            true,
        )?;
    }
    // Outside the standard: tables, which readers keep aside.
    let mut extra = vec![Table {
        name: "BP_VALID",
        columns: VALID_COLUMNS,
        rows: results
            .valid
            .chunks(s.max(1))
            .map(|frame| vec![("VALID", Cell::Bytes(frame.to_vec()))])
            .collect(),
    }];
    if grid.is_none() && !provenance.windows.is_empty() {
        extra.push(Table {
            name: "BP_WINDOWS",
            columns: WINDOW_COLUMNS,
            rows: provenance
                .windows
                .iter()
                .map(|w| {
                    vec![
                        ("X", Cell::Int(w.x.into())),
                        ("Y", Cell::Int(w.y.into())),
                        ("WIDTH", Cell::Int(w.width.into())),
                        ("HEIGHT", Cell::Int(w.height.into())),
                    ]
                })
                .collect(),
        });
    }
    for table in &extra {
        write_table(&mut file, path, table)?;
    }
    Ok(())
}
