//! Results as FITS, written by cfitsio (the `fitsio` crate): an empty
//! primary HDU holding the provenance keywords, then the image extensions
//! `SLOPES` (float64, pixel), `FLUX` (float64, count) and `VALID` (uint8).

use std::path::Path;

use fitsio::images::{ImageDescription, ImageType};
use fitsio::FitsFile;

use super::results::{Results, Value};
use super::IoError;

pub(crate) fn fits_error(path: &Path, e: fitsio::errors::Error) -> IoError {
    IoError::malformed(path, format!("cfitsio: {e}"))
}

/// Writes a new FITS file at `path` (which must not exist).
pub(crate) fn write_results(
    path: &Path,
    keywords: &[(&str, Value, &str)],
    slopes_shape: &[usize],
    slopes: &[f64],
    results: &Results,
) -> Result<(), IoError> {
    let e = |err| fits_error(path, err);
    let mut file = FitsFile::create(path).open().map_err(e)?;
    let primary = file.primary_hdu().map_err(e)?;
    for (key, value, comment) in keywords {
        match value {
            Value::Int(v) => primary.write_key(&mut file, key, (*v, *comment)),
            Value::Text(t) => primary.write_key(&mut file, key, (t.as_str(), *comment)),
        }
        .map_err(e)?;
    }
    let frames = results.frames();
    let s = results.subapertures;
    let image = |file: &mut FitsFile, name: &str, data_type, shape: &[usize], unit: &str| {
        let hdu = file
            .create_image(
                name,
                &ImageDescription {
                    data_type,
                    dimensions: shape,
                },
            )
            .map_err(e)?;
        hdu.write_key(file, "BUNIT", (unit, "unit of the values"))
            .map_err(e)?;
        Ok::<_, IoError>(hdu)
    };
    let hdu = image(
        &mut file,
        "SLOPES",
        ImageType::Double,
        slopes_shape,
        "pixel",
    )?;
    hdu.write_image(&mut file, slopes).map_err(e)?;
    let hdu = image(&mut file, "FLUX", ImageType::Double, &[frames, s], "count")?;
    hdu.write_image(&mut file, &results.flux).map_err(e)?;
    let hdu = image(
        &mut file,
        "VALID",
        ImageType::UnsignedByte,
        &[frames, s],
        "",
    )?;
    hdu.write_image(&mut file, &results.valid).map_err(e)?;
    Ok(())
}

/// `stream --out x.fits`: the slopes are the primary image, appended frame
/// by frame; this adds the provenance keywords, `BUNIT`, and the `FLUX`
/// and `VALID` extensions.
pub(crate) fn add_to_streamed(
    path: &Path,
    keywords: &[(&str, Value, &str)],
    results: &Results,
) -> Result<(), IoError> {
    let e = |err| fits_error(path, err);
    let mut file = FitsFile::edit(path).map_err(e)?;
    let primary = file.primary_hdu().map_err(e)?;
    // Named as `process` names its slopes, so that `hdul["SLOPES"]`
    // (astropy) or `--hdu SLOPES` reads either file.
    primary
        .write_key(
            &mut file,
            "EXTNAME",
            ("SLOPES", "the slopes, appended as frames arrived"),
        )
        .map_err(e)?;
    primary
        .write_key(&mut file, "BUNIT", ("pixel", "unit of the slopes"))
        .map_err(e)?;
    for (key, value, comment) in keywords {
        match value {
            Value::Int(v) => primary.write_key(&mut file, key, (*v, *comment)),
            Value::Text(t) => primary.write_key(&mut file, key, (t.as_str(), *comment)),
        }
        .map_err(e)?;
    }
    let shape = [results.frames(), results.subapertures];
    let hdu = file
        .create_image(
            "FLUX",
            &ImageDescription {
                data_type: ImageType::Double,
                dimensions: &shape,
            },
        )
        .map_err(e)?;
    hdu.write_key(&mut file, "BUNIT", ("count", "unit of the values"))
        .map_err(e)?;
    hdu.write_image(&mut file, &results.flux).map_err(e)?;
    let hdu = file
        .create_image(
            "VALID",
            &ImageDescription {
                data_type: ImageType::UnsignedByte,
                dimensions: &shape,
            },
        )
        .map_err(e)?;
    hdu.write_image(&mut file, &results.valid).map_err(e)?;
    Ok(())
}
