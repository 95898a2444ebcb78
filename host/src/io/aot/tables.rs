//! AOT's tables: every column of every table, in the standard's order and
//! units, and the binary-table I/O, through cfitsio directly (the `fitsio`
//! crate has no variable-length columns, which AOT's lists are, and panics
//! describing a table that has them).

use std::ffi::{c_char, CString};
use std::path::Path;

use fitsio::FitsFile;

use super::super::IoError;

/// AOT's column formats: fixed string, integer, float, variable-length list
/// of floats; and bytes (brightpix's validity).
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    Str,
    Int,
    Flt,
    Lst,
    Bytes,
}
pub(super) use Kind::{Bytes, Flt, Int, Lst, Str};

pub(super) type Schema = &'static [(&'static str, Kind, &'static str)];

// Every column of every table, in the standard's order and units: a
// missing column is something readers complain about.
pub(super) const TIME_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TIMESTAMPS", Lst, "s"),
    ("FRAME_NUMBERS", Lst, "count"),
];
pub(super) const ATMOSPHERE_COLUMNS: Schema = &[
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
pub(super) const ABERRATION_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("MODES", Str, ""),
    ("COEFFICIENTS", Str, ""),
    ("X_OFFSETS", Lst, "rad"),
    ("Y_OFFSETS", Lst, "rad"),
];
pub(super) const TELESCOPE_COLUMNS: Schema = &[
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
pub(super) const SOURCE_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("TYPE", Str, ""),
    ("RIGHT_ASCENSION", Flt, "deg"),
    ("DECLINATION", Flt, "deg"),
    ("ELEVATION_OFFSET", Flt, "deg"),
    ("AZIMUTH_OFFSET", Flt, "deg"),
    ("FWHM", Flt, "rad"),
];
pub(super) const DETECTOR_COLUMNS: Schema = &[
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
pub(super) const SCORING_CAMERA_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("PUPIL_MASK", Str, ""),
    ("WAVELENGTH", Flt, "m"),
    ("TRANSFORMATION_MATRIX", Str, ""),
    ("DETECTOR_UID", Str, ""),
    ("ABERRATION_UID", Str, ""),
];
pub(super) const SENSOR_COLUMNS: Schema = &[
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
pub(super) const SHACK_HARTMANN_COLUMNS: Schema = &[
    ("UID", Str, ""),
    ("CENTROIDING_ALGORITHM", Str, ""),
    ("CENTROID_GAINS", Str, ""),
    ("SPOT_FWHM", Str, ""),
];
pub(super) const CORRECTOR_COLUMNS: Schema = &[
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
pub(super) const LOOP_COLUMNS: Schema = &[
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
pub(super) const VALID_COLUMNS: Schema = &[("VALID", Bytes, "")];
pub(super) const WINDOW_COLUMNS: Schema = &[
    ("X", Int, "pix"),
    ("Y", Int, "pix"),
    ("WIDTH", Int, "pix"),
    ("HEIGHT", Int, "pix"),
];

/// The null of AOT's integer columns (its `TNULL`).
pub(super) const INT_NULL: i64 = -32768;

pub(super) enum Cell {
    Str(String),
    Int(i64),
    Flt(f64),
    Lst(Vec<f64>),
    Bytes(Vec<u8>),
}

pub(super) fn text(s: impl Into<String>) -> Cell {
    Cell::Str(s.into())
}
pub(super) fn row_ref(uid: &str) -> Cell {
    Cell::Str(format!("ROWREF<{uid}>"))
}
pub(super) fn image_ref(extname: &str) -> Cell {
    Cell::Str(format!("INTREF<{extname}>"))
}

/// One binary table: its columns, and rows of the cells that are not null.
pub(super) struct Table {
    pub name: &'static str,
    pub columns: Schema,
    pub rows: Vec<Vec<(&'static str, Cell)>>,
}

pub(super) fn c_string(path: &Path, s: &str) -> Result<CString, IoError> {
    CString::new(s).map_err(|_| IoError::malformed(path, format!("a NUL byte in {s:?}")))
}

pub(super) fn cfitsio_status(path: &Path, what: &str, status: i32) -> Result<(), IoError> {
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
pub(super) fn cell<'a>(row: &'a [(&str, Cell)], name: &str) -> Option<&'a Cell> {
    row.iter().find(|(n, _)| *n == name).map(|(_, c)| c)
}

/// Appends `table` as a binary table HDU (cfitsio directly: the `fitsio`
/// crate has no variable-length columns, which AOT's lists are).
pub(super) fn write_table(file: &mut FitsFile, path: &Path, table: &Table) -> Result<(), IoError> {
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

/// Makes table `table` current (cfitsio directly: the `fitsio` crate
/// panics describing a table with variable-length columns) and returns its
/// row count.
pub(super) fn table_rows(file: &mut FitsFile, path: &Path, table: &str) -> Result<usize, IoError> {
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
pub(super) fn column_number(
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
pub(super) fn strings(
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
