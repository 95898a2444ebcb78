//! The Adaptive Optics Telemetry standard (AOT, version 2.0.0; `aotpy` is
//! its reference package): FITS files that describe an AO system's sensors,
//! correctors and loops in binary tables, their time series in image
//! extensions that table cells name (`INTREF<EXTNAME>`), rows naming other
//! tables' rows by `ROWREF<UID>`.
//!
//! - Writing ([`stage`], results whose path ends in `.aot.fits`): every
//!   table the standard requires, with one main telescope, one natural guide
//!   star, one Shack-Hartmann sensor (`WFS`) and its detector (`WFS CAMERA`),
//!   and one time row (`FRAMES`: frame numbers). The sensor's sub-aperture
//!   geometry is a `SUBAPERTURE_MASK` when the windows are square cells of a
//!   grid; the measurements are the slopes as `(frames, 2, sub-apertures)`
//!   pixels (x then y), reference slopes subtracted; the references are
//!   `REF_MEASUREMENTS`; flux is `SUBAPERTURE_INTENSITIES`. brightpix's
//!   provenance is the primary header's `BP*` keywords (non-AOT keywords,
//!   which readers keep as metadata), and what AOT has no field for is in
//!   two extra binary tables: `BP_VALID` (validity, a row per frame) and,
//!   for windows that are not a grid, `BP_WINDOWS` (x, y, width, height).
//!   docs/OUTPUTS.md has the map.
//! - Reading ([`locate_pixels`]): the detector pixel intensities of one
//!   Shack-Hartmann sensor, chosen by its `UID`, as the image HDU that
//!   [`super::FrameSource`] then reads like any FITS cube.

use std::ffi::{c_char, CString};
use std::path::{Path, PathBuf};

use brightpix_protocol::SubapertureWindow;
use fitsio::images::{ImageDescription, ImageType};
use fitsio::FitsFile;

use super::fits_out::fits_error;
use super::output::Staged;
use super::results::{Layout, Provenance, Results, Value};
use super::{FrameCube, IoError};

/// The AOT version written.
pub const VERSION: &str = "2.0.0";

/// Row names (UIDs) of what brightpix writes.
pub const SENSOR: &str = "WFS";
pub const DETECTOR: &str = "WFS CAMERA";
const SOURCE: &str = "GUIDE STAR";
const TELESCOPE: &str = "TELESCOPE";
const TIME: &str = "FRAMES";

/// Whether `path` names an AOT file to write: `*.aot.fits`, any case.
pub fn is_aot_name(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.to_ascii_lowercase().ends_with(".aot.fits"))
}

// ---------------------------------------------------------------- tables

/// AOT's column formats: fixed string, integer, float, variable-length list
/// of floats; and bytes (brightpix's validity).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Str,
    Int,
    Flt,
    Lst,
    Bytes,
}
use Kind::{Bytes, Flt, Int, Lst, Str};

type Schema = &'static [(&'static str, Kind, &'static str)];

// Every column of every table, in the standard's order and units: a
// missing column is something readers complain about.
const TIME_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TIMESTAMPS", Lst, "s"),
    ("FRAME_NUMBERS", Lst, "count"),
];
const ATMOSPHERE_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("WAVELENGTH", Flt, "m"),
    ("TIME_UID", Str, ""),
    ("R0", Lst, "m"),
    ("SEEING", Lst, "arcsec"),
    ("TAU0", Lst, "s"),
    ("THETA0", Lst, "rad"),
    ("LAYERS_REL_WEIGHT", Str, ""),
    ("LAYERS_HEIGHT", Str, ""),
    ("LAYERS_LO", Str, ""),
    ("LAYERS_WIND_SPEED", Str, ""),
    ("LAYERS_WIND_DIRECTION", Str, ""),
    ("TRANSFORMATION_MATRIX", Str, ""),
];
const ABERRATION_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("MODES", Str, ""),
    ("COEFFICIENTS", Str, ""),
    ("X_OFFSETS", Lst, "rad"),
    ("Y_OFFSETS", Lst, "rad"),
];
const TELESCOPE_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("LATITUDE", Flt, "deg"),
    ("LONGITUDE", Flt, "deg"),
    ("ELEVATION", Flt, "deg"),
    ("AZIMUTH", Flt, "deg"),
    ("PARALLACTIC", Flt, "deg"),
    ("PUPIL_MASK", Str, ""),
    ("PUPIL_ANGLE", Flt, "rad"),
    ("ENCLOSING_D", Flt, "m"),
    ("INSCRIBED_D", Flt, "m"),
    ("OBSTRUCTION_D", Flt, "m"),
    ("SEGMENT_TYPE", Str, ""),
    ("SEGMENT_SIZE", Flt, "m"),
    ("SEGMENTS_X", Lst, "m"),
    ("SEGMENTS_Y", Lst, "m"),
    ("TRANSFORMATION_MATRIX", Str, ""),
    ("ABERRATION_UID", Str, ""),
];
const SOURCE_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("RIGHT_ASCENSION", Flt, "deg"),
    ("DECLINATION", Flt, "deg"),
    ("ELEVATION_OFFSET", Flt, "deg"),
    ("AZIMUTH_OFFSET", Flt, "deg"),
    ("FWHM", Flt, "rad"),
];
const DETECTOR_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("SAMPLING_TECHNIQUE", Str, ""),
    ("SHUTTER_TYPE", Str, ""),
    ("FLAT_FIELD", Str, ""),
    ("READOUT_NOISE", Flt, "electron*s^-1*pix^-1"),
    ("PIXEL_INTENSITIES", Str, ""),
    ("FIELD_CENTRE_X", Flt, "pix"),
    ("FIELD_CENTRE_Y", Flt, "pix"),
    ("INTEGRATION_TIME", Flt, "s"),
    ("COADDS", Int, "count"),
    ("DARK", Str, ""),
    ("WEIGHT_MAP", Str, ""),
    ("QUANTUM_EFFICIENCY", Flt, ""),
    ("PIXEL_SCALE", Flt, "rad*pix^-1"),
    ("BINNING", Int, "count"),
    ("BANDWIDTH", Flt, "m"),
    ("TRANSMISSION_WAVELENGTH", Lst, "m"),
    ("TRANSMISSION", Lst, ""),
    ("SKY_BACKGROUND", Str, ""),
    ("GAIN", Flt, "electron"),
    ("EXCESS_NOISE", Flt, "electron"),
    ("FILTER", Str, ""),
    ("BAD_PIXEL_MAP", Str, ""),
    ("DYNAMIC_RANGE", Flt, "dB"),
    ("READOUT_RATE", Flt, "pix*s^-1"),
    ("FRAME_RATE", Flt, "frame*s^-1"),
    ("TRANSFORMATION_MATRIX", Str, ""),
];
const SCORING_CAMERA_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("PUPIL_MASK", Str, ""),
    ("WAVELENGTH", Flt, "m"),
    ("TRANSFORMATION_MATRIX", Str, ""),
    ("DETECTOR_UID", Str, ""),
    ("ABERRATION_UID", Str, ""),
];
const SENSOR_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("SOURCE_UID", Str, ""),
    ("DIMENSIONS", Int, "count"),
    ("N_VALID_SUBAPERTURES", Int, "count"),
    ("MEASUREMENTS", Str, ""),
    ("REF_MEASUREMENTS", Str, ""),
    ("SUBAPERTURE_MASK", Str, ""),
    ("MASK_X_OFFSETS", Lst, "pix"),
    ("MASK_Y_OFFSETS", Lst, "pix"),
    ("SUBAPERTURE_SIZE", Flt, "pix"),
    ("SUBAPERTURE_INTENSITIES", Str, ""),
    ("WAVELENGTH", Flt, "m"),
    ("OPTICAL_GAIN", Str, ""),
    ("TRANSFORMATION_MATRIX", Str, ""),
    ("DETECTOR_UID", Str, ""),
    ("ABERRATION_UID", Str, ""),
    ("NCPA_UID", Str, ""),
];
const SHACK_HARTMANN_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("CENTROIDING_ALGORITHM", Str, ""),
    ("CENTROID_GAINS", Str, ""),
    ("SPOT_FWHM", Str, ""),
];
const CORRECTOR_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("TELESCOPE_UID", Str, ""),
    ("N_VALID_ACTUATORS", Int, "count"),
    ("PUPIL_MASK", Str, ""),
    ("TFZ_NUM", Lst, ""),
    ("TFZ_DEN", Lst, ""),
    ("TRANSFORMATION_MATRIX", Str, ""),
    ("ABERRATION_UID", Str, ""),
];
const LOOP_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("COMMANDED_UID", Str, ""),
    ("TIME_UID", Str, ""),
    ("STATUS", Str, ""),
    ("COMMANDS", Str, ""),
    ("REF_COMMANDS", Str, ""),
    ("FRAMERATE", Flt, "Hz"),
    ("DELAY", Flt, "frame"),
    ("TIME_FILTER_NUM", Str, ""),
    ("TIME_FILTER_DEN", Str, ""),
];

// brightpix's own tables, for what AOT has no field for. Tables, not
// images: the reference package refuses a file with an image that no AOT
// field names, and keeps other tables aside.
const VALID_COLUMNS: Schema = &[("VALID", Bytes, "")];
const WINDOW_COLUMNS: Schema = &[
    ("X", Int, "pix"),
    ("Y", Int, "pix"),
    ("WIDTH", Int, "pix"),
    ("HEIGHT", Int, "pix"),
];

/// The null of AOT's integer columns (its `TNULL`).
const INT_NULL: i64 = -32768;

enum Cell {
    Str(String),
    Int(i64),
    Flt(f64),
    Lst(Vec<f64>),
    Bytes(Vec<u8>),
}

fn text(s: impl Into<String>) -> Cell {
    Cell::Str(s.into())
}
fn row_ref(uid: &str) -> Cell {
    Cell::Str(format!("ROWREF<{uid}>"))
}
fn image_ref(extname: &str) -> Cell {
    Cell::Str(format!("INTREF<{extname}>"))
}

/// One binary table: its columns, and rows of the cells that are not null.
struct Table {
    name: &'static str,
    columns: Schema,
    rows: Vec<Vec<(&'static str, Cell)>>,
}

fn c_string(path: &Path, s: &str) -> Result<CString, IoError> {
    CString::new(s).map_err(|_| IoError::malformed(path, format!("a NUL byte in {s:?}")))
}

fn cfitsio_status(path: &Path, what: &str, status: i32) -> Result<(), IoError> {
    if status == 0 {
        Ok(())
    } else {
        Err(IoError::malformed(
            path,
            format!("cfitsio status {status} writing {what}"),
        ))
    }
}

/// The cell of column `name` in `row`, if not null.
fn cell<'a>(row: &'a [(&str, Cell)], name: &str) -> Option<&'a Cell> {
    row.iter().find(|(n, _)| *n == name).map(|(_, c)| c)
}

/// Appends `table` as a binary table HDU (cfitsio directly: the `fitsio`
/// crate has no variable-length columns, which AOT's lists are).
fn write_table(file: &mut FitsFile, path: &Path, table: &Table) -> Result<(), IoError> {
    let mut names = Vec::new();
    let mut forms = Vec::new();
    let mut units = Vec::new();
    for &(name, kind, unit) in table.columns {
        let form = match kind {
            Str => {
                let width = table
                    .rows
                    .iter()
                    .filter_map(|r| match cell(r, name) {
                        Some(Cell::Str(s)) => Some(s.len()),
                        _ => None,
                    })
                    .max()
                    .unwrap_or(0)
                    .max(1);
                format!("{width}A")
            }
            Int => "1K".into(),
            Flt => "1D".into(),
            // 64-bit descriptors, as the reference package writes them;
            // "(0)" is the longest list so far, which cfitsio updates.
            Lst => "QD(0)".into(),
            Bytes => {
                let width = table
                    .rows
                    .iter()
                    .filter_map(|r| match cell(r, name) {
                        Some(Cell::Bytes(b)) => Some(b.len()),
                        _ => None,
                    })
                    .max()
                    .unwrap_or(0)
                    .max(1);
                format!("{width}B")
            }
        };
        names.push(c_string(path, name)?);
        forms.push(c_string(path, &form)?);
        units.push(c_string(path, unit)?);
    }
    let pointers = |v: &[CString]| -> Vec<*mut c_char> {
        v.iter().map(|c| c.as_ptr() as *mut c_char).collect()
    };
    let (mut ttype, mut tform, mut tunit) = (pointers(&names), pointers(&forms), pointers(&units));
    let extname = c_string(path, table.name)?;
    // SAFETY: the pointer is used only while `file` is open and borrowed.
    let fptr = unsafe { file.as_raw() };
    let mut status = 0;
    // SAFETY: `fptr` is the open file; the pointer arrays hold
    // `columns.len()` NUL-terminated strings that outlive the call (cfitsio
    // only reads them; an empty TUNIT is not written).
    unsafe {
        fitsio::sys::ffcrtb(
            fptr,
            fitsio::sys::BINARY_TBL as i32,
            table.rows.len() as i64,
            table.columns.len() as i32,
            ttype.as_mut_ptr(),
            tform.as_mut_ptr(),
            tunit.as_mut_ptr(),
            extname.as_ptr(),
            &mut status,
        );
    }
    cfitsio_status(path, table.name, status)?;
    for (k, &(name, kind, _)) in table.columns.iter().enumerate() {
        let column = (k + 1) as i32;
        if kind == Int {
            let key = c_string(path, &format!("TNULL{column}"))?;
            // SAFETY: as above; the key and an empty comment are C strings.
            unsafe {
                fitsio::sys::ffpkyj(fptr, key.as_ptr(), INT_NULL, c"".as_ptr(), &mut status);
            }
            cfitsio_status(path, table.name, status)?;
        }
        for (r, row) in table.rows.iter().enumerate() {
            let row_number = (r + 1) as i64;
            let what = || format!("{}.{name} row {r}", table.name);
            match (kind, cell(row, name)) {
                (Str, value) => {
                    let s = match value {
                        Some(Cell::Str(s)) => s.as_str(),
                        _ => "",
                    };
                    let s = c_string(path, s)?;
                    let mut one = [s.as_ptr() as *mut c_char];
                    // SAFETY: one C string, written to one cell.
                    unsafe {
                        fitsio::sys::ffpcls(
                            fptr,
                            column,
                            row_number,
                            1,
                            1,
                            one.as_mut_ptr(),
                            &mut status,
                        );
                    }
                }
                (Int, value) => {
                    let mut v = match value {
                        Some(Cell::Int(v)) => *v,
                        _ => INT_NULL,
                    };
                    // SAFETY: one value, written to one cell.
                    unsafe {
                        fitsio::sys::ffpcljj(fptr, column, row_number, 1, 1, &mut v, &mut status);
                    }
                }
                (Flt, value) => {
                    let mut v = match value {
                        Some(Cell::Flt(v)) => *v,
                        _ => f64::NAN,
                    };
                    // SAFETY: one value, written to one cell.
                    unsafe {
                        fitsio::sys::ffpcld(fptr, column, row_number, 1, 1, &mut v, &mut status);
                    }
                }
                (Lst, Some(Cell::Lst(list))) if !list.is_empty() => {
                    let mut list = list.clone();
                    // SAFETY: `list.len()` values, written as the row's
                    // variable-length array.
                    unsafe {
                        fitsio::sys::ffpcld(
                            fptr,
                            column,
                            row_number,
                            1,
                            list.len() as i64,
                            list.as_mut_ptr(),
                            &mut status,
                        );
                    }
                }
                // An empty list: the zeroed descriptor already says so.
                (Lst, _) => {}
                (Bytes, Some(Cell::Bytes(bytes))) if !bytes.is_empty() => {
                    let mut bytes = bytes.clone();
                    // SAFETY: `bytes.len()` values (at most the column's
                    // repeat), written to one cell.
                    unsafe {
                        fitsio::sys::ffpclb(
                            fptr,
                            column,
                            row_number,
                            1,
                            bytes.len() as i64,
                            bytes.as_mut_ptr(),
                            &mut status,
                        );
                    }
                }
                (Bytes, _) => {}
            }
            cfitsio_status(path, &what(), status)?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------- writing

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
trait Pixel: fitsio::images::WriteImage {
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

fn image<T: Pixel>(
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

fn write(
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

// ---------------------------------------------------------------- reading

/// Where a sensor's pixel intensities are: an image HDU of `file`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PixelsAt {
    /// The file holding the image (the AOT file, or the one a `FILEREF`
    /// names).
    pub file: PathBuf,
    /// The HDU: an `EXTNAME`, or an index in an external file (`None`: its
    /// first image).
    pub hdu: Option<String>,
    /// The sensor's `UID`.
    pub sensor: String,
}

/// Makes table `table` current (cfitsio directly: the `fitsio` crate
/// panics describing a table with variable-length columns) and returns its
/// row count.
fn table_rows(file: &mut FitsFile, path: &Path, table: &str) -> Result<usize, IoError> {
    let name = c_string(path, table)?;
    let (mut status, mut rows) = (0, 0i64);
    // SAFETY: the file is open; cfitsio only reads `name`.
    unsafe {
        let fptr = file.as_raw();
        fitsio::sys::ffmnhd(
            fptr,
            fitsio::sys::BINARY_TBL as i32,
            name.as_ptr() as *mut c_char,
            0,
            &mut status,
        );
        if status == 0 {
            fitsio::sys::ffgnrwll(fptr, &mut rows, &mut status);
        }
    }
    if status != 0 {
        return Err(IoError::unexpected(
            path,
            format!("an AOT file with no {table} table"),
            format!("the AOT tables, {table} among them"),
        ));
    }
    Ok(rows.max(0) as usize)
}

/// The number of column `column` of the current table.
fn column_number(
    file: &mut FitsFile,
    path: &Path,
    table: &str,
    column: &str,
) -> Result<i32, IoError> {
    let name = c_string(path, column)?;
    let (mut status, mut number) = (0, 0);
    // SAFETY: the file is open at `table`; cfitsio only reads `name`.
    unsafe {
        fitsio::sys::ffgcno(
            file.as_raw(),
            0,
            name.as_ptr() as *mut c_char,
            &mut number,
            &mut status,
        );
    }
    if status != 0 {
        return Err(IoError::unexpected(
            path,
            format!("{table} without a {column} column"),
            format!("the AOT column {table}.{column}"),
        ));
    }
    Ok(number)
}

/// A string column of an AOT table, each value trimmed.
fn strings(
    file: &mut FitsFile,
    path: &Path,
    table: &str,
    column: &str,
) -> Result<Vec<String>, IoError> {
    let rows = table_rows(file, path, table)?;
    let number = column_number(file, path, table, column)?;
    let (mut status, mut code, mut repeat, mut width) = (0, 0, 0i64, 0i64);
    // SAFETY: the file is open at `table`, which has column `number`.
    unsafe {
        fitsio::sys::ffgtclll(
            file.as_raw(),
            number,
            &mut code,
            &mut repeat,
            &mut width,
            &mut status,
        );
    }
    if status != 0 || code != fitsio::sys::TSTRING as i32 {
        return Err(IoError::unexpected(
            path,
            format!("{table}.{column} that is not a string column"),
            "a string (nA) column, as AOT defines it",
        ));
    }
    let mut values = Vec::with_capacity(rows);
    let mut buffer = vec![0 as c_char; repeat.max(1) as usize + 1];
    for row in 1..=rows as i64 {
        let mut pointers = [buffer.as_mut_ptr()];
        let mut any_null = 0;
        // SAFETY: one value of at most `repeat` characters and its NUL into
        // `buffer`, whose length is `repeat + 1`.
        unsafe {
            fitsio::sys::ffgcvs(
                file.as_raw(),
                number,
                row,
                1,
                1,
                c"".as_ptr() as *mut c_char,
                pointers.as_mut_ptr(),
                &mut any_null,
                &mut status,
            );
        }
        if status != 0 {
            return Err(IoError::malformed(
                path,
                format!("{table}.{column} row {row}: cfitsio status {status} reading it"),
            ));
        }
        // SAFETY: cfitsio wrote a NUL-terminated string into `buffer`.
        let value = unsafe { std::ffi::CStr::from_ptr(buffer.as_ptr()) };
        values.push(value.to_string_lossy().trim().to_string());
    }
    Ok(values)
}

/// `PREFIX<inner>rest` of an AOT reference, or `None`.
fn reference<'a>(value: &'a str, prefix: &str) -> Option<(&'a str, &'a str)> {
    let rest = value.strip_prefix(prefix)?.strip_prefix('<')?;
    let end = rest.rfind('>')?;
    Some((&rest[..end], &rest[end + 1..]))
}

/// If `path` is an AOT file (its primary header has `AOT-VERS`), where the
/// pixel intensities of its Shack-Hartmann sensor `sensor` are (the only
/// sensor when `None`); `Ok(None)` for any other FITS file. Every refusal
/// names the file and what it holds: no sensor, no sensor of that name
/// (with the names there are), a sensor that is not Shack-Hartmann, a
/// detector without pixel intensities.
pub fn locate_pixels(path: &Path, sensor: Option<&str>) -> Result<Option<PixelsAt>, IoError> {
    // Not readable as FITS: the ordinary reader says why.
    let Ok(mut file) = FitsFile::open(path) else {
        return Ok(None);
    };
    let version = match file.primary_hdu() {
        Ok(primary) => primary.read_key::<String>(&mut file, "AOT-VERS").ok(),
        Err(_) => None,
    };
    let Some(version) = version else {
        return Ok(None);
    };
    let uids = strings(&mut file, path, "AOT_WAVEFRONT_SENSORS", "UID")?;
    if uids.is_empty() {
        return Err(IoError::unexpected(
            path,
            format!("an AOT file (version {}) with no wavefront sensor (AOT_WAVEFRONT_SENSORS has no rows)", version.trim()),
            "a Shack-Hartmann sensor whose detector has pixel intensities",
        ));
    }
    let types = strings(&mut file, path, "AOT_WAVEFRONT_SENSORS", "TYPE")?;
    let detectors = strings(&mut file, path, "AOT_WAVEFRONT_SENSORS", "DETECTOR_UID")?;
    let listing = || {
        uids.iter()
            .zip(&types)
            .map(|(u, t)| format!("'{u}' ({t})"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let index = match sensor {
        Some(name) => uids
            .iter()
            .position(|u| u == name)
            .or_else(|| uids.iter().position(|u| u.eq_ignore_ascii_case(name)))
            .ok_or_else(|| {
                IoError::unexpected(
                    path,
                    format!("no wavefront sensor '{name}' (sensors: {})", listing()),
                    "--sensor: the UID of one of the file's wavefront sensors",
                )
            })?,
        None if uids.len() == 1 => 0,
        None => {
            return Err(IoError::unexpected(
                path,
                format!("{} wavefront sensors: {}", uids.len(), listing()),
                "one sensor, or --sensor (sensor= in Python) naming which",
            ))
        }
    };
    let name = uids[index].clone();
    if types[index] != "Shack-Hartmann" {
        return Err(IoError::unexpected(
            path,
            format!("wavefront sensor '{name}' of type '{}'", types[index]),
            "a Shack-Hartmann sensor",
        ));
    }
    let no_pixels = |why: String| {
        IoError::unexpected(
            path,
            format!("wavefront sensor '{name}' {why}"),
            "a sensor whose detector has PIXEL_INTENSITIES (the camera frames)",
        )
    };
    let Some((detector, _)) = reference(&detectors[index], "ROWREF") else {
        return Err(no_pixels("has no detector (DETECTOR_UID is empty)".into()));
    };
    let detector = detector.to_string();
    let detector_uids = strings(&mut file, path, "AOT_DETECTORS", "UID")?;
    let intensities = strings(&mut file, path, "AOT_DETECTORS", "PIXEL_INTENSITIES")?;
    let Some(row) = detector_uids.iter().position(|u| *u == detector) else {
        return Err(no_pixels(format!(
            "names detector '{detector}', which AOT_DETECTORS does not have"
        )));
    };
    let value = &intensities[row];
    if value.is_empty() {
        return Err(no_pixels(format!(
            "has detector '{detector}' without PIXEL_INTENSITIES"
        )));
    }
    let at = |file: PathBuf, hdu: &str| {
        Ok(Some(PixelsAt {
            file,
            hdu: (!hdu.is_empty()).then(|| hdu.to_string()),
            sensor: name.clone(),
        }))
    };
    if let Some((extname, _)) = reference(value, "INTREF") {
        return at(path.to_path_buf(), extname);
    }
    if let Some((external, index)) = reference(value, "FILEREF") {
        // Relative to the AOT file, as the file travels with it.
        let dir = path.parent().unwrap_or(Path::new(""));
        return at(dir.join(external), index);
    }
    Err(no_pixels(format!(
        "has detector '{detector}' whose PIXEL_INTENSITIES is '{value}' (a URL or unknown reference: brightpix reads INTREF and FILEREF images)"
    )))
}

#[cfg(test)]
mod tests {
    use super::super::test_util::temp_dir;
    use super::super::{read_frames, FrameShape, FrameSource, Raw};
    use super::*;

    fn window(x: u16, y: u16, side: u16) -> SubapertureWindow {
        SubapertureWindow {
            x,
            y,
            width: side,
            height: side,
        }
    }

    /// 3 sub-apertures, 2 frames; sub-aperture 1 of frame 1 invalid.
    fn sample(windows: Vec<SubapertureWindow>) -> (Results, Provenance) {
        let mut results = Results::new(3);
        for frame in 0..2i32 {
            for s in 0..3i32 {
                results.push(Some(Raw {
                    slope_x: (10 * frame + s) * 65536,
                    slope_y: -(10 * frame + s) * 32768,
                    flux: 16 * i64::from(100 + s),
                    valid: !(frame == 1 && s == 1),
                }));
            }
        }
        let mut provenance = Provenance::unknown_config("test", Some(7));
        provenance.rule = Some("subtract-next".into());
        provenance.pixels = Some(20);
        provenance.config_digest = Some(0x1234_abcd);
        provenance.first_frame = 5;
        provenance.windows = windows;
        provenance.reference_slopes = Some(vec![[65536, -32768], [0, 0], [16384, 8]]);
        (results, provenance)
    }

    fn cube(frames: usize) -> FrameCube {
        let shape = FrameShape {
            frames,
            height: 8,
            width: 12,
        };
        let pixels = (0..frames * 96).map(|i| (i * 37 % 4096) as u16).collect();
        FrameCube { shape, pixels }
    }

    fn image_f64(file: &mut FitsFile, name: &str) -> (Vec<usize>, Vec<f64>) {
        let hdu = file.hdu(name).unwrap();
        let shape = match &hdu.info {
            fitsio::hdu::HduInfo::ImageInfo { shape, .. } => shape.clone(),
            other => panic!("{other:?}"),
        };
        (shape, hdu.read_image(file).unwrap())
    }

    fn col_strings(file: &mut FitsFile, table: &str, name: &str) -> Vec<String> {
        strings(file, Path::new("t"), table, name).unwrap()
    }

    /// Row 1 of a numeric column, scalar or list.
    fn col_f64(file: &mut FitsFile, table: &str, name: &str) -> Vec<f64> {
        let path = Path::new("t");
        table_rows(file, path, table).unwrap();
        let number = column_number(file, path, table, name).unwrap();
        let (mut status, mut code, mut repeat, mut width) = (0, 0, 0i64, 0i64);
        let (mut length, mut offset) = (0i64, 0i64);
        unsafe {
            let fptr = file.as_raw();
            fitsio::sys::ffgtclll(
                fptr,
                number,
                &mut code,
                &mut repeat,
                &mut width,
                &mut status,
            );
            if code < 0 {
                fitsio::sys::ffgdesll(fptr, number, 1, &mut length, &mut offset, &mut status);
            } else {
                length = repeat;
            }
            let mut out = vec![0.0; length as usize];
            let mut any_null = 0;
            fitsio::sys::ffgcvd(
                fptr,
                number,
                1,
                1,
                length,
                f64::NAN,
                out.as_mut_ptr(),
                &mut any_null,
                &mut status,
            );
            assert_eq!(status, 0, "{table}.{name}");
            out
        }
    }

    #[test]
    fn writes_the_aot_tables_images_and_provenance() {
        let dir = temp_dir("aotw");
        let path = dir.join("r.aot.fits");
        // A 2x2 grid of 4-pixel windows with one cell empty, out of order.
        let (results, provenance) = sample(vec![window(6, 2, 4), window(2, 2, 4), window(2, 6, 4)]);
        stage(&path, &results, &provenance, Some(&cube(2)))
            .unwrap()
            .commit()
            .unwrap();
        let mut file = FitsFile::open(&path).unwrap();
        let primary = file.primary_hdu().unwrap();
        let key = |file: &mut FitsFile, k: &str| primary.read_key::<String>(file, k).unwrap();
        assert_eq!(key(&mut file, "AOT-VERS"), "2.0.0");
        assert_eq!(key(&mut file, "TIMESYS"), "UTC");
        assert_eq!(key(&mut file, "AO-MODE"), "SCAO");
        assert_eq!(key(&mut file, "BPRULE"), "subtract-next");
        assert_eq!(key(&mut file, "BPCFGDIG"), "0x1234abcd");
        assert_eq!(key(&mut file, "BPLAYOUT"), "vector");
        for table in [
            "AOT_TIME",
            "AOT_ATMOSPHERIC_PARAMETERS",
            "AOT_ABERRATIONS",
            "AOT_TELESCOPES",
            "AOT_SOURCES",
            "AOT_DETECTORS",
            "AOT_SCORING_CAMERAS",
            "AOT_WAVEFRONT_SENSORS",
            "AOT_WAVEFRONT_SENSORS_SHACK_HARTMANN",
            "AOT_WAVEFRONT_CORRECTORS",
            "AOT_LOOPS",
        ] {
            table_rows(&mut file, &path, table).unwrap_or_else(|e| panic!("{table}: {e}"));
        }
        let t = "AOT_WAVEFRONT_SENSORS";
        assert_eq!(col_strings(&mut file, t, "UID"), ["WFS"]);
        assert_eq!(col_strings(&mut file, t, "TYPE"), ["Shack-Hartmann"]);
        assert_eq!(
            col_strings(&mut file, t, "SOURCE_UID"),
            ["ROWREF<GUIDE STAR>"]
        );
        assert_eq!(col_f64(&mut file, t, "DIMENSIONS"), [2.0]);
        assert_eq!(col_f64(&mut file, t, "N_VALID_SUBAPERTURES"), [3.0]);
        assert_eq!(col_f64(&mut file, t, "SUBAPERTURE_SIZE"), [4.0]);
        assert_eq!(
            col_strings(&mut file, t, "MEASUREMENTS"),
            ["INTREF<MEASUREMENTS>"]
        );
        assert!(col_f64(&mut file, "AOT_TELESCOPES", "LATITUDE")[0].is_nan());
        assert_eq!(col_f64(&mut file, t, "MASK_X_OFFSETS"), [2.0]);
        assert_eq!(col_f64(&mut file, t, "MASK_Y_OFFSETS"), [2.0]);
        assert_eq!(col_f64(&mut file, "AOT_TIME", "FRAME_NUMBERS"), [5.0, 6.0]);
        assert!(col_f64(&mut file, "AOT_TIME", "TIMESTAMPS").is_empty());
        assert_eq!(
            col_strings(
                &mut file,
                "AOT_WAVEFRONT_SENSORS_SHACK_HARTMANN",
                "CENTROIDING_ALGORITHM"
            ),
            ["brightest pixels, subtract-next, N = 20"]
        );
        // Measurements: (frames, 2, sub-apertures), x then y.
        let (shape, m) = image_f64(&mut file, "MEASUREMENTS");
        assert_eq!(shape, [2, 2, 3]);
        assert_eq!(&m[..6], &[0.0, 1.0, 2.0, -0.0, -0.5, -1.0]);
        assert_eq!(&m[6..9], &[10.0, 11.0, 12.0]);
        let (shape, r) = image_f64(&mut file, "REF_MEASUREMENTS");
        assert_eq!(
            (shape, r),
            (vec![2, 3], vec![1.0, 0.0, 0.25, -0.5, 0.0, 8.0 / 65536.0])
        );
        let (shape, mask) = image_f64(&mut file, "SUBAPERTURE_MASK");
        assert_eq!((shape, mask), (vec![2, 2], vec![1.0, 0.0, 2.0, -1.0]));
        let (_, flux) = image_f64(&mut file, "SUBAPERTURE_INTENSITIES");
        assert_eq!(flux, results.flux);
        assert_eq!(col_f64(&mut file, "BP_VALID", "VALID"), [1.0, 1.0, 1.0]);
        assert_eq!(table_rows(&mut file, &path, "BP_VALID").unwrap(), 2);
        assert!(table_rows(&mut file, &path, "BP_WINDOWS").is_err());
        let hdu = file.hdu("MEASUREMENTS").unwrap();
        assert_eq!(hdu.read_key::<String>(&mut file, "BUNIT").unwrap(), "pix");
        assert_eq!(
            hdu.read_key::<String>(&mut file, "TIME_UID").unwrap(),
            "ROWREF<FRAMES>"
        );
        // The frames come back as the sensor's pixels.
        assert_eq!(read_frames(&path).unwrap(), cube(2));
        // Its tables (variable-length columns) are named or skipped, never
        // described by the fitsio crate, which would panic.
        let err = FrameSource::open_hdu(&path, Some("AOT_TIME")).unwrap_err();
        assert!(err.to_string().contains("('AOT_TIME') is a table"), "{err}");
        let err = FrameSource::open_hdu(&path, Some("NOPE")).unwrap_err();
        assert!(
            err.to_string().contains("1 'AOT_TIME': table of 1 rows"),
            "{err}"
        );
        assert_eq!(
            FrameSource::open_hdu(&path, Some("PIXEL_INTENSITIES"))
                .unwrap()
                .len(),
            2
        );
        let at = locate_pixels(&path, Some("wfs")).unwrap().unwrap();
        assert_eq!(
            (at.sensor.as_str(), at.hdu.as_deref()),
            ("WFS", Some("PIXEL_INTENSITIES"))
        );
    }

    #[test]
    fn windows_that_are_not_a_grid_are_listed() {
        let dir = temp_dir("aotnogrid");
        let path = dir.join("r.AOT.FITS");
        assert!(is_aot_name(&path));
        let (results, provenance) = sample(vec![window(0, 0, 4), window(5, 0, 4), window(0, 4, 4)]);
        stage(&path, &results, &provenance, None)
            .unwrap()
            .commit()
            .unwrap();
        let mut file = FitsFile::open(&path).unwrap();
        assert!(file.hdu("SUBAPERTURE_MASK").is_err());
        assert_eq!(table_rows(&mut file, &path, "BP_WINDOWS").unwrap(), 3);
        assert_eq!(col_f64(&mut file, "BP_WINDOWS", "X"), [0.0]);
        assert_eq!(col_f64(&mut file, "BP_WINDOWS", "WIDTH"), [4.0]);
        assert!(col_f64(&mut file, "AOT_WAVEFRONT_SENSORS", "SUBAPERTURE_SIZE")[0].is_nan());
        assert!(grid_of(&[window(0, 0, 4), window(0, 0, 4)]).is_none());
        assert!(grid_of(&[window(0, 0, 4), window(4, 0, 3)]).is_none());
    }

    #[test]
    fn bad_shapes_are_refused_before_writing() {
        let dir = temp_dir("aotshape");
        let path = dir.join("r.aot.fits");
        let (results, provenance) = sample(vec![window(0, 0, 4)]);
        let err = stage(&path, &results, &provenance, None).unwrap_err();
        assert!(err.to_string().contains("1 windows"), "{err}");
        let (results, provenance) = sample(Vec::new());
        let err = stage(&path, &results, &provenance, Some(&cube(3))).unwrap_err();
        assert!(err.to_string().contains("3 frames of pixels"), "{err}");
        assert!(!path.exists());
    }

    /// An AOT file of `sensors` (UID, TYPE, DETECTOR_UID) and `detectors`
    /// (UID, PIXEL_INTENSITIES), with one 2x3x4 image named `PIX`.
    fn crafted(path: &Path, sensors: &[(&str, &str, &str)], detectors: &[(&str, &str)]) {
        let mut file = FitsFile::create(path).open().unwrap();
        let primary = file.primary_hdu().unwrap();
        primary.write_key(&mut file, "AOT-VERS", "2.0.0").unwrap();
        let rows = |v: Vec<Vec<(&'static str, Cell)>>| v;
        write_table(
            &mut file,
            path,
            &Table {
                name: "AOT_WAVEFRONT_SENSORS",
                columns: SENSOR_COLUMNS,
                rows: rows(
                    sensors
                        .iter()
                        .map(|(u, t, d)| {
                            vec![
                                ("UID", text(*u)),
                                ("TYPE", text(*t)),
                                ("DETECTOR_UID", text(*d)),
                            ]
                        })
                        .collect(),
                ),
            },
        )
        .unwrap();
        write_table(
            &mut file,
            path,
            &Table {
                name: "AOT_DETECTORS",
                columns: DETECTOR_COLUMNS,
                rows: detectors
                    .iter()
                    .map(|(u, p)| vec![("UID", text(*u)), ("PIXEL_INTENSITIES", text(*p))])
                    .collect(),
            },
        )
        .unwrap();
        let data: Vec<f32> = (0..24).map(|v| v as f32).collect();
        image(&mut file, path, "PIX", &[2, 3, 4], &data, None, false).unwrap();
    }

    fn open_error(path: &Path, sensor: Option<&str>) -> String {
        let err = FrameSource::open_sensor(path, None, sensor).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        msg
    }

    #[test]
    fn reads_the_named_sensor_and_refuses_bad_input() {
        let dir = temp_dir("aotr");
        let path = dir.join("two.fits");
        crafted(
            &path,
            &[
                ("LGS", "Shack-Hartmann", "ROWREF<CAM1>"),
                ("NGS", "Shack-Hartmann", "ROWREF<CAM2>"),
                ("PYR", "Pyramid", "ROWREF<CAM2>"),
                ("DARK", "Shack-Hartmann", ""),
            ],
            &[("CAM1", ""), ("CAM2", "INTREF<PIX>")],
        );
        // Float pixels that are whole counts are frames.
        let mut source = FrameSource::open_sensor(&path, None, Some("NGS")).unwrap();
        assert_eq!(source.shape().frames, 2);
        assert_eq!(source.read_frame(1).unwrap()[..3], [12, 13, 14]);
        let msg = open_error(&path, None);
        assert!(
            msg.contains("4 wavefront sensors") && msg.contains("'LGS' (Shack-Hartmann)"),
            "{msg}"
        );
        let msg = open_error(&path, Some("TTS"));
        assert!(
            msg.contains("no wavefront sensor 'TTS'") && msg.contains("'NGS'"),
            "{msg}"
        );
        let msg = open_error(&path, Some("LGS"));
        assert!(
            msg.contains("'LGS' has detector 'CAM1' without PIXEL_INTENSITIES"),
            "{msg}"
        );
        let msg = open_error(&path, Some("PYR"));
        assert!(msg.contains("of type 'Pyramid'"), "{msg}");
        let msg = open_error(&path, Some("DARK"));
        assert!(msg.contains("has no detector"), "{msg}");

        // A file with no sensor at all.
        let empty = dir.join("empty.fits");
        crafted(&empty, &[], &[]);
        let msg = open_error(&empty, None);
        assert!(msg.contains("no wavefront sensor"), "{msg}");

        // A detector named but absent; an external file, by index.
        let missing = dir.join("missing.fits");
        crafted(&missing, &[("W", "Shack-Hartmann", "ROWREF<GONE>")], &[]);
        assert!(open_error(&missing, None).contains("'GONE', which AOT_DETECTORS does not have"));
        let external = dir.join("external.fits");
        crafted(
            &external,
            &[("W", "Shack-Hartmann", "ROWREF<C>")],
            &[("C", "FILEREF<two.fits>4")],
        );
        let at = locate_pixels(&external, None).unwrap().unwrap();
        assert_eq!(
            (at.file, at.hdu),
            (dir.join("two.fits"), Some("4".to_string()))
        );
        let url = dir.join("url.fits");
        crafted(
            &url,
            &[("W", "Shack-Hartmann", "ROWREF<C>")],
            &[("C", "URLREF<http://x/y.fits>")],
        );
        assert!(open_error(&url, None).contains("a URL or unknown reference"));

        // --sensor for a plain FITS cube, or with --hdu.
        let plain = dir.join("plain.fits");
        cube(1).write(&plain).unwrap();
        let msg = open_error(&plain, Some("WFS"));
        assert!(msg.contains("not AOT"), "{msg}");
        let err = FrameSource::open_sensor(&plain, Some("0"), Some("WFS")).unwrap_err();
        assert!(err.to_string().contains("with --hdu"), "{err}");
        // No AOT tables at all but the version keyword.
        let bare = dir.join("bare.fits");
        let mut file = FitsFile::create(&bare).open().unwrap();
        let primary = file.primary_hdu().unwrap();
        primary.write_key(&mut file, "AOT-VERS", "2.0.0").unwrap();
        drop(file);
        assert!(open_error(&bare, None).contains("no AOT_WAVEFRONT_SENSORS table"));
    }
}
