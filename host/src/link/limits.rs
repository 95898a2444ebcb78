//! What a device can hold, and whether a configuration fits it, offline.
//!
//! A device reports its limits in `HelloReply.capabilities`; the boards'
//! are also known here by name, so a configuration can be checked before a
//! device is at hand. [`check`] runs the device's own acceptance code
//! (`brightpix_firmware::device::vet`: the capacity checks of `ConfigBegin`,
//! `Config::validate`, the engine's memory plan `Engine::check`, and the
//! result queue) against those limits: what it says is what an upload
//! would end in. docs/CONFIG.md, "Device limits", explains each limit.

use std::fmt;
use std::path::Path;

use brightpix_firmware::device::vet;
use brightpix_firmware::engine::MemorySize;
use brightpix_protocol::wire::{Capabilities, DeviceError, PixelSourceKind};
use brightpix_protocol::Config;
use serde::Deserialize;

use super::DeviceInfo;

/// A device's limits: the numbers of `HelloReply.capabilities`.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceLimits {
    /// Board name, as the device reports it.
    pub board: String,
    /// Sub-aperture windows per configuration.
    pub max_subapertures: u32,
    /// Pixels of the background and gain maps (0: no maps).
    pub max_camera_pixels: u32,
    /// Windows that one camera row may cross.
    pub max_open_windows: u32,
    /// Entries of the engine's candidate pool.
    pub pool_entries: u32,
    /// Camera pixels of the engine's row history.
    pub history_pixels: u32,
    /// Entries of the engine's rescan scratch.
    pub scratch_entries: u32,
    /// Sub-apertures that may end in one camera row.
    pub max_results_per_row: u32,
}

/// The boards whose limits are known by name.
pub const KNOWN_DEVICES: [&str; 3] = ["qemu", "stm32h743", "in-process"];

impl DeviceLimits {
    /// The limits of a known board: `qemu` (the `mps2-an386` firmware,
    /// `firmware/boards/qemu/src/storage.rs`), `stm32h743`
    /// (`firmware/boards/stm32h743/src/storage.rs`), `in-process` (the
    /// simulated device, `sim_device::SimSizes`).
    pub fn named(name: &str) -> Option<DeviceLimits> {
        let (board, s, p, o, e, h, c, r) = match name {
            // 6400 sub-apertures (80x80), maps of 256x256, 256 open windows,
            // a pool for 256 windows of 16x16 (256 x 271), a history of 64
            // rows of 4096, scratch for a 64x64 window, 1024 results/row.
            "qemu" => (
                "qemu-mps2-an386",
                6400,
                256 * 256,
                256,
                256 * 271,
                64 * 4096,
                64 * 64,
                1024,
            ),
            "stm32h743" => (
                "stm32h743-nucleo",
                1600,
                240 * 240,
                128,
                3072,
                16 * 240,
                256,
                64,
            ),
            "in-process" => {
                let z = crate::sim_device::SimSizes::default();
                return Some(DeviceLimits {
                    board: "brightpix-sim (in-process)".into(),
                    max_subapertures: z.subapertures as u32,
                    max_camera_pixels: z.map_pixels as u32,
                    max_open_windows: z.open_windows as u32,
                    pool_entries: z.pool_entries as u32,
                    history_pixels: z.history_pixels as u32,
                    scratch_entries: z.scratch_entries as u32,
                    max_results_per_row: z.results_per_row as u32,
                });
            }
            _ => return None,
        };
        Some(DeviceLimits {
            board: board.into(),
            max_subapertures: s,
            max_camera_pixels: p,
            max_open_windows: o,
            pool_entries: e,
            history_pixels: h,
            scratch_entries: c,
            max_results_per_row: r,
        })
    }

    /// A board name, or a TOML file with the fields of [`DeviceLimits`].
    pub fn from_name_or_file(spec: &str) -> anyhow::Result<DeviceLimits> {
        if let Some(limits) = Self::named(spec) {
            return Ok(limits);
        }
        let path = Path::new(spec);
        if !path.exists() {
            anyhow::bail!(
                "{spec}: neither a known device ({}) nor a file",
                KNOWN_DEVICES.join(", ")
            );
        }
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// What a connected device reported.
    pub fn of(info: &DeviceInfo) -> DeviceLimits {
        DeviceLimits {
            board: info.board.clone(),
            max_subapertures: info.max_subapertures,
            max_camera_pixels: info.max_camera_pixels,
            max_open_windows: info.max_open_windows,
            pool_entries: info.pool_entries,
            history_pixels: info.history_pixels,
            scratch_entries: info.scratch_entries,
            max_results_per_row: info.max_results_per_row,
        }
    }

    fn capabilities(&self) -> Capabilities<'_> {
        Capabilities {
            max_subapertures: self.max_subapertures,
            max_camera_pixels: self.max_camera_pixels,
            max_open_windows: self.max_open_windows,
            pool_entries: self.pool_entries,
            history_pixels: self.history_pixels,
            scratch_entries: self.scratch_entries,
            max_results_per_row: self.max_results_per_row,
            max_frame_bytes: brightpix_protocol::wire::MAX_FRAME_LEN as u32,
            pixel_source: PixelSourceKind::Link,
            board: &self.board,
        }
    }
}

impl fmt::Display for DeviceLimits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {} sub-apertures, maps of {} pixels, {} open windows, {} pool entries, {} history pixels, {} scratch entries, {} results per camera row",
            self.board,
            self.max_subapertures,
            self.max_camera_pixels,
            self.max_open_windows,
            self.pool_entries,
            self.history_pixels,
            self.scratch_entries,
            self.max_results_per_row
        )
    }
}

/// Whether `config` fits a device with `limits`, by the device's own code:
/// the engine memory it would use, or the error the upload would end in.
pub fn check(config: &Config<'_>, limits: &DeviceLimits) -> Result<MemorySize, DeviceError> {
    let n = config.windows.len();
    let (mut order, mut scratch) = (vec![0u16; n], vec![0u16; n]);
    vet::check_offline(config, &limits.capabilities(), &mut order, &mut scratch)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config_file::ProcessingConfig;
    use brightpix_firmware::engine::select::{least_capacity, preferred_capacity};
    use brightpix_protocol::wire::CapacityKind;
    use brightpix_protocol::{Camera, MemoryKind, RegularGrid};

    fn grid(columns: u16, rows: u16, side: u16) -> ProcessingConfig {
        let camera = Camera {
            width: (columns * side).max(1),
            height: (rows * side).max(1),
            bit_depth: 12,
        };
        let grid = RegularGrid {
            x: 0,
            y: 0,
            columns,
            rows,
            width: side,
            height: side,
            pitch_x: side,
            pitch_y: side,
        };
        ProcessingConfig::from_grid(camera, grid, &[])
    }

    /// Issue 10, fault 7: the device's refusals, known before an upload.
    #[test]
    fn configurations_are_checked_against_a_devices_limits() {
        let canary = crate::sil::canary_config();
        for name in KNOWN_DEVICES {
            let limits = DeviceLimits::named(name).unwrap();
            let needed = check(&canary.view(), &limits).unwrap();
            assert_eq!(needed.open_windows, 7, "{name}");
        }
        // The 6,400 sub-aperture cap of the QEMU board.
        let qemu = DeviceLimits::named("qemu").unwrap();
        check(&grid(80, 80, 2).view(), &qemu).unwrap();
        assert_eq!(
            check(&grid(81, 80, 2).view(), &qemu).unwrap_err(),
            DeviceError::Capacity {
                what: CapacityKind::Subapertures,
                needed: 6480,
                available: 6400
            }
        );
        // The STM32H743: 64x64 windows need more row history and scratch
        // than it has; a row of 16x16 windows fits, each window's buffer
        // what the pool holds up to its preferred size, and a pool below
        // every window's least buffer is refused.
        let h7 = DeviceLimits::named("stm32h743").unwrap();
        assert!(matches!(
            check(&grid(4, 1, 64).view(), &h7).unwrap_err(),
            DeviceError::Config(_)
        ));
        let row = grid(15, 1, 16);
        let needed = check(&row.view(), &h7).unwrap();
        let view = row.view();
        let (rule, n) = (view.selection.rule, view.pixel_count(0));
        let least = least_capacity(rule, n, 256) as usize;
        let preferred = preferred_capacity(rule, n, 256) as usize;
        assert_eq!(
            needed.pool_entries,
            15 * preferred.min(h7.pool_entries as usize / 15)
        );
        let enough = DeviceLimits {
            pool_entries: (15 * least) as u32,
            ..h7.clone()
        };
        assert_eq!(
            check(&row.view(), &enough).unwrap().pool_entries,
            15 * least
        );
        let tight = DeviceLimits {
            pool_entries: (15 * least) as u32 - 1,
            ..h7.clone()
        };
        match check(&row.view(), &tight).unwrap_err() {
            DeviceError::Config(f) => assert!(
                matches!(
                    brightpix_protocol::ConfigError::from(f),
                    brightpix_protocol::ConfigError::MemoryBudget {
                        what: MemoryKind::SelectionEntries,
                        ..
                    }
                ),
                "{f}"
            ),
            other => panic!("{other}"),
        }
        // Maps bigger than the map buffers.
        let mut big = grid(32, 32, 8);
        big.background = Some(vec![0; 256 * 256]);
        assert!(matches!(
            check(&big.view(), &h7).unwrap_err(),
            DeviceError::Capacity {
                what: CapacityKind::CameraPixels,
                ..
            }
        ));
        // More windows than open windows in one row.
        assert!(check(&grid(129, 1, 1).view(), &h7).is_err());
        // A limits file.
        let dir = std::env::temp_dir().join(format!("brightpix-limits-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("board.toml");
        std::fs::write(
            &file,
            "board = \"mine\"\nmax_subapertures = 10\nmax_camera_pixels = 0\n\
             max_open_windows = 4\npool_entries = 100\nhistory_pixels = 4096\n\
             scratch_entries = 256\nmax_results_per_row = 4\n",
        )
        .unwrap();
        let mine = DeviceLimits::from_name_or_file(file.to_str().unwrap()).unwrap();
        assert_eq!(mine.max_open_windows, 4);
        assert!(check(&canary.view(), &mine).is_err());
        assert!(DeviceLimits::from_name_or_file("no-such-board").is_err());
        let _ = std::fs::remove_dir_all(dir);
    }
}
