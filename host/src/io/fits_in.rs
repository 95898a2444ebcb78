//! FITS images read by cfitsio (the `fitsio` crate): the primary HDU or an
//! image extension, tile-compressed images included, `BSCALE`/`BZERO`
//! applied and `BLANK` pixels as NaN.

use std::path::Path;

use fitsio::hdu::HduInfo;
use fitsio::images::ImageType;
use fitsio::FitsFile;

use super::{shape_string, IoError};

/// One image HDU of an open FITS file, made current.
pub(crate) struct FitsImage {
    file: FitsFile,
    /// NumPy order, slowest axis first.
    pub shape: Vec<usize>,
    /// Stored as integers (with any BSCALE/BZERO, cfitsio's equivalent type).
    pub integer: bool,
    /// How the HDU was found, for messages: "HDU 1 ('SCI')".
    pub describe: String,
}

fn cfitsio(path: &Path, what: &str, e: fitsio::errors::Error) -> IoError {
    IoError::malformed(path, format!("{what} (cfitsio: {e})"))
}

/// One line per HDU: index, name, kind and shape.
fn inventory(file: &mut FitsFile) -> String {
    let count = file.num_hdus().unwrap_or(0);
    let mut lines = Vec::new();
    for index in 0..count {
        let Ok(hdu) = file.hdu(index) else { break };
        let name = hdu.name(file).unwrap_or_default();
        let kind = match &hdu.info {
            HduInfo::ImageInfo { shape, .. } if shape.is_empty() => "no data".to_string(),
            HduInfo::ImageInfo { shape, .. } => format!("image {}", shape_string(shape)),
            HduInfo::TableInfo { num_rows, .. } => format!("table of {num_rows} rows"),
            HduInfo::AnyInfo => "other".to_string(),
        };
        let name = if name.is_empty() {
            String::new()
        } else {
            format!(" '{name}'")
        };
        lines.push(format!("{index}{name}: {kind}"));
    }
    lines.join("; ")
}

/// Refuses a file whose first card is `SIMPLE = F`: the standard's mark of
/// a file that does not conform to FITS, which cfitsio would read as if it
/// did. Anything else (a file too short, another first keyword) is left to
/// cfitsio, which names what it finds wrong.
fn check_conforming(path: &Path) -> Result<(), IoError> {
    use std::io::Read;
    let mut card = [0u8; 80];
    let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut filled = 0;
    while filled < card.len() {
        match file.read(&mut card[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(IoError::io(path, e)),
        }
    }
    let card = &card[..filled];
    // Keyword in columns 1-8, "= " in 9-10, the logical value in 11-80
    // (fixed format: column 30) before any comment.
    if card.len() < 11 || &card[..10] != b"SIMPLE  = " {
        return Ok(());
    }
    let value = card[10..].split(|&b| b == b'/').next().unwrap_or_default();
    if value.trim_ascii() == b"F" {
        return Err(IoError::unexpected(
            path,
            format!(
                "a first card that says the file does not conform to the FITS standard: '{}'",
                String::from_utf8_lossy(card).trim_end()
            ),
            "a FITS file (SIMPLE = T)",
        ));
    }
    Ok(())
}

/// Opens `path` at the HDU named by `hdu` (an index, 0 the primary, or an
/// `EXTNAME`), or else at the first HDU holding an image with data.
pub(crate) fn open_image(path: &Path, hdu: Option<&str>) -> Result<FitsImage, IoError> {
    if !path.exists() {
        return Err(IoError::io(
            path,
            std::io::Error::from(std::io::ErrorKind::NotFound),
        ));
    }
    check_conforming(path)?;
    let mut file =
        FitsFile::open(path).map_err(|e| cfitsio(path, "not a readable FITS file", e))?;
    let count = file
        .num_hdus()
        .map_err(|e| cfitsio(path, "cannot count its HDUs", e))?;
    let index = match hdu {
        Some(wanted) => {
            let found = match wanted.parse::<usize>() {
                Ok(index) if index < count => Some(index),
                Ok(_) => None,
                Err(_) => (0..count).find(|&i| {
                    file.hdu(i)
                        .and_then(|h| h.name(&mut file))
                        .is_ok_and(|name| name.trim().eq_ignore_ascii_case(wanted.trim()))
                }),
            };
            found.ok_or_else(|| {
                IoError::unexpected(
                    path,
                    format!("no HDU '{wanted}' (HDUs: {})", inventory(&mut file)),
                    "--hdu: an HDU index (0: primary) or EXTNAME of the file",
                )
            })?
        }
        None => {
            let image = |file: &mut FitsFile, i: usize, with_data: bool| {
                file.hdu(i).is_ok_and(|h| {
                    matches!(&h.info, HduInfo::ImageInfo { shape, .. }
                        if !shape.is_empty() && (!with_data || shape.iter().all(|&d| d > 0)))
                })
            };
            // The first image with data; else the first with axes (an
            // empty cube is still a cube).
            (0..count)
                .find(|&i| image(&mut file, i, true))
                .or_else(|| (0..count).find(|&i| image(&mut file, i, false)))
                .ok_or_else(|| {
                    IoError::unexpected(
                        path,
                        format!(
                            "no image with data in any HDU (HDUs: {})",
                            inventory(&mut file)
                        ),
                        "an image in the primary HDU or an image extension",
                    )
                })?
        }
    };
    let h = file
        .hdu(index)
        .map_err(|e| cfitsio(path, "cannot move to the HDU", e))?;
    let name = h.name(&mut file).unwrap_or_default();
    let describe = if name.is_empty() {
        format!("HDU {index}")
    } else {
        format!("HDU {index} ('{}')", name.trim())
    };
    let (shape, image_type) = match &h.info {
        HduInfo::ImageInfo { shape, image_type } => (shape.clone(), *image_type),
        _ => {
            return Err(IoError::unexpected(
                path,
                format!("{describe} is a table"),
                "an image HDU",
            ))
        }
    };
    let integer = !matches!(image_type, ImageType::Float | ImageType::Double);
    Ok(FitsImage {
        file,
        shape,
        integer,
        describe,
    })
}

impl FitsImage {
    /// Values `start .. start + count` in file order, physical (scaled),
    /// BLANK pixels as NaN.
    pub(crate) fn read(
        &mut self,
        path: &Path,
        start: usize,
        count: usize,
        out: &mut Vec<f64>,
    ) -> Result<(), IoError> {
        out.clear();
        out.resize(count, 0.0);
        if count == 0 {
            return Ok(());
        }
        let mut status = 0;
        let mut any_null = 0;
        // SAFETY: the file is open and at this image HDU (made current by
        // `open_image`, never moved since); `out` holds `count` values.
        unsafe {
            fitsio::sys::ffgpvd(
                self.file.as_raw(),
                1,
                (start + 1) as i64,
                count as i64,
                f64::NAN,
                out.as_mut_ptr(),
                &mut any_null,
                &mut status,
            );
        }
        if status != 0 {
            return Err(IoError::malformed(
                path,
                format!(
                    "{}: reading values {start}..{} failed (cfitsio status {status}; the file may be truncated or corrupt)",
                    self.describe,
                    start + count,
                ),
            ));
        }
        Ok(())
    }
}

/// A whole image as `f64` (maps and other arrays).
pub(crate) fn read_array(path: &Path) -> Result<super::Array, IoError> {
    let mut image = open_image(path, None)?;
    let count = image.shape.iter().product();
    let mut data = Vec::new();
    image.read(path, 0, count, &mut data)?;
    Ok(super::Array {
        shape: image.shape,
        data,
    })
}
