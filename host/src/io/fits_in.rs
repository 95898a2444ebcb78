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

/// What HDU `index` (0-based) is, asked of cfitsio directly: the `fitsio`
/// crate panics describing a table with variable-length columns (as AOT's
/// tables have), so it is only asked about images.
pub(crate) struct HduKind {
    /// An image (tile-compressed included); else a table.
    pub image: bool,
    /// `EXTNAME`, trimmed (empty if none).
    pub name: String,
    /// Rows, for a table.
    pub rows: i64,
}

pub(crate) fn hdu_kind(file: &mut FitsFile, index: usize) -> Option<HduKind> {
    let (mut status, mut kind, mut rows) = (0, 0, 0i64);
    let mut name = [0 as std::ffi::c_char; 81];
    // SAFETY: the file is open; `name` has room for any keyword value
    // (68 characters) and its NUL. A missing EXTNAME only sets `status`,
    // which is then cleared.
    unsafe {
        let fptr = file.as_raw();
        fitsio::sys::ffmahd(fptr, index as i32 + 1, &mut kind, &mut status);
        fitsio::sys::ffghdt(fptr, &mut kind, &mut status);
        if status != 0 {
            return None;
        }
        fitsio::sys::ffgkys(
            fptr,
            c"EXTNAME".as_ptr(),
            name.as_mut_ptr(),
            std::ptr::null_mut(),
            &mut status,
        );
        status = 0;
        let image = kind == fitsio::sys::IMAGE_HDU as i32;
        if !image {
            fitsio::sys::ffgnrwll(fptr, &mut rows, &mut status);
        }
        let name = std::ffi::CStr::from_ptr(name.as_ptr())
            .to_string_lossy()
            .trim()
            .to_string();
        Some(HduKind { image, name, rows })
    }
}

/// One line per HDU: index, name, kind and shape.
fn inventory(file: &mut FitsFile) -> String {
    let count = file.num_hdus().unwrap_or(0);
    let mut lines = Vec::new();
    for index in 0..count {
        let Some(h) = hdu_kind(file, index) else {
            break;
        };
        let kind = if h.image {
            match file.hdu(index).map(|hdu| hdu.info) {
                Ok(HduInfo::ImageInfo { shape, .. }) if shape.is_empty() => "no data".to_string(),
                Ok(HduInfo::ImageInfo { shape, .. }) => format!("image {}", shape_string(&shape)),
                _ => "other".to_string(),
            }
        } else {
            format!("table of {} rows", h.rows)
        };
        let name = if h.name.is_empty() {
            String::new()
        } else {
            format!(" '{}'", h.name)
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
                    hdu_kind(&mut file, i)
                        .is_some_and(|h| h.name.eq_ignore_ascii_case(wanted.trim()))
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
                hdu_kind(file, i).is_some_and(|h| h.image)
                    && file.hdu(i).is_ok_and(|h| {
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
    let kind = hdu_kind(&mut file, index).ok_or_else(|| {
        IoError::malformed(path, format!("HDU {index}: cfitsio cannot move to it"))
    })?;
    let describe = if kind.name.is_empty() {
        format!("HDU {index}")
    } else {
        format!("HDU {index} ('{}')", kind.name)
    };
    if !kind.image {
        return Err(IoError::unexpected(
            path,
            format!("{describe} is a table"),
            "an image HDU",
        ));
    }
    let h = file
        .hdu(index)
        .map_err(|e| cfitsio(path, "cannot move to the HDU", e))?;
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

/// The most values [`read_array`] reads (512 MiB as `f64`): maps and
/// tables are at most a camera (2048 x 2048, PROTOCOL.md) or a few per
/// sub-aperture, and a header may claim any shape (a compressed image's
/// data need not be in the file), so the shape is checked before the
/// allocation (found by fuzz/'s fits_reader: a 2.7 GB allocation).
const MAX_ARRAY_VALUES: usize = 1 << 26;

/// A whole image as `f64` (maps and other arrays).
pub(crate) fn read_array(path: &Path) -> Result<super::Array, IoError> {
    let mut image = open_image(path, None)?;
    let count = image
        .shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= MAX_ARRAY_VALUES)
        .ok_or_else(|| {
            IoError::malformed(
                path,
                format!(
                    "{}: its shape {:?} holds more values than a map or table brightpix reads whole ({MAX_ARRAY_VALUES})",
                    image.describe, image.shape
                ),
            )
        })?;
    let mut data = Vec::new();
    image.read(path, 0, count, &mut data)?;
    Ok(super::Array {
        shape: image.shape,
        data,
    })
}
