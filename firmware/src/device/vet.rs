//! The checks a device makes before it accepts a configuration, as plain
//! functions of the configuration and the device's [`Capabilities`]: the
//! device loop runs them during an upload, and a host runs the very same
//! code offline (`brightpix check-config`) to learn whether a configuration
//! fits a device before it has one at hand.

use brightpix_protocol::wire::{Capabilities, CapacityKind, ConfigHeader, DeviceError};
use brightpix_protocol::{Config, SubapertureWindow};

use crate::engine::{Engine, MemorySize};

/// At `ConfigBegin`: the windows fit the device's tables, and the maps (if
/// any) its map buffers.
pub fn check_header(
    header: &ConfigHeader,
    capabilities: &Capabilities<'_>,
) -> Result<(), DeviceError> {
    let capacity = capabilities.max_subapertures;
    if header.windows > capacity {
        return Err(DeviceError::Capacity {
            what: CapacityKind::Subapertures,
            needed: header.windows,
            available: capacity,
        });
    }
    let pixels = header.camera.pixel_count();
    let available = capabilities.max_camera_pixels;
    if (header.background.needs_map() || header.gain) && pixels > available as usize {
        return Err(DeviceError::Capacity {
            what: CapacityKind::CameraPixels,
            needed: saturate(pixels),
            available,
        });
    }
    Ok(())
}

/// At `ConfigCommit`, on the complete configuration: it is valid
/// (`Config::validate`), the engine's plan fits the device's memory
/// (`Engine::check`: open windows, candidate pool, row history, scratch), and no camera row ends
/// more windows than the result queue holds. Returns the engine memory the
/// configuration uses. `order` and `scratch` need `config.windows.len()`
/// entries each.
pub fn check_config(
    config: &Config<'_>,
    capabilities: &Capabilities<'_>,
    order: &mut [u16],
    scratch: &mut [u16],
) -> Result<MemorySize, DeviceError> {
    let capacity = MemorySize {
        subapertures: capabilities.max_subapertures as usize,
        open_windows: capabilities.max_open_windows as usize,
        pool_entries: capabilities.pool_entries as usize,
        history_pixels: capabilities.history_pixels as usize,
        scratch_entries: capabilities.scratch_entries as usize,
    };
    let needed = Engine::check(config, capacity, order, scratch)
        .map_err(|e| DeviceError::Config(e.into()))?;
    let per_row = results_per_row(config.windows, scratch);
    if per_row > capabilities.max_results_per_row as usize {
        return Err(DeviceError::Capacity {
            what: CapacityKind::ResultsPerRow,
            needed: saturate(per_row),
            available: capabilities.max_results_per_row,
        });
    }
    Ok(needed)
}

/// Both checks, in the device's order: what an upload of `config` to a
/// device with `capabilities` would end in.
pub fn check_offline(
    config: &Config<'_>,
    capabilities: &Capabilities<'_>,
    order: &mut [u16],
    scratch: &mut [u16],
) -> Result<MemorySize, DeviceError> {
    check_header(&ConfigHeader::of(config), capabilities)?;
    check_config(config, capabilities, order, scratch)
}

/// The most windows that end in one camera row (`windows` valid).
fn results_per_row(windows: &[SubapertureWindow], scratch: &mut [u16]) -> usize {
    let n = windows.len().min(scratch.len());
    let rows = &mut scratch[..n];
    for (r, w) in rows.iter_mut().zip(windows) {
        *r = w.last_row();
    }
    rows.sort_unstable();
    let mut most = 0;
    let mut run = 0;
    for k in 0..n {
        run = if k > 0 && rows[k] == rows[k - 1] {
            run + 1
        } else {
            1
        };
        most = most.max(run);
    }
    most
}

fn saturate(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}
