//! A Shack-Hartmann sensor's detector pixel intensities, found in an AOT
//! file: the image HDU that `FrameSource` then reads like any FITS cube.

use std::path::{Path, PathBuf};

use fitsio::FitsFile;

use super::super::IoError;
use super::tables::strings;

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
