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
//!
//! | module   | holds |
//! |----------|-------|
//! | `tables` | the tables' columns and units, and cfitsio's table I/O |
//! | `write`  | results as an AOT file |
//! | `read`   | a sensor's pixel intensities found |

mod read;
mod tables;
#[cfg(test)]
mod tests;
mod write;

use std::path::Path;

pub use read::{locate_pixels, PixelsAt};
pub use write::stage;

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
