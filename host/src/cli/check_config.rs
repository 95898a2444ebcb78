//! `brightpix check-config`: whether a configuration fits a device, before
//! any device is at hand (or asking a connected one for its limits).

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::link::limits::{self, DeviceLimits, KNOWN_DEVICES};
use crate::link::Client;

#[derive(Args)]
#[command(
    about = "Check a configuration against a device's limits (pool, open windows, sub-apertures, maps), offline",
    after_help = "Examples:\n  brightpix check-config --config examples/canary.toml --device stm32h743\n  brightpix check-config --config big.toml --device qemu\n  brightpix check-config --config big.toml --device limits.toml   # your board's numbers\n  brightpix check-config --config big.toml --port /dev/ttyACM0    # ask the device\n\n\
The check is the device's own acceptance code (brightpix_firmware::device::vet: the capacity\n\
checks of ConfigBegin, Config::validate, the engine's memory plan Engine::check, the result\n\
queue), so it says exactly what an upload would end in. Devices known by name: qemu,\n\
stm32h743, in-process. A limits file is TOML with the keys board, max_subapertures,\n\
max_camera_pixels, max_open_windows, pool_entries, history_pixels, scratch_entries,\n\
max_results_per_row (the fields of the device line of `brightpix status`). Exit status 0 if it fits, 1 if not. See docs/CONFIG.md,\n\
\"Device limits\"."
)]
pub struct CheckConfigArgs {
    /// Processing configuration (TOML, see docs/CONFIG.md).
    #[arg(long)]
    config: PathBuf,
    /// A known device (qemu, stm32h743, in-process) or a TOML file of limits.
    #[arg(long, value_name = "NAME|FILE", required_unless_present = "port")]
    device: Option<String>,
    /// Ask the device on this port for its limits instead.
    #[arg(long, conflicts_with = "device")]
    port: Option<String>,
}

pub fn run(args: CheckConfigArgs) -> Result<()> {
    let limits = match (&args.device, &args.port) {
        (Some(spec), _) => DeviceLimits::from_name_or_file(spec)?,
        (None, Some(port)) => DeviceLimits::of(Client::open(port)?.info()),
        (None, None) => bail!("give --device ({}) or --port", KNOWN_DEVICES.join(", ")),
    };
    let config = ProcessingConfig::load(&args.config)?;
    let view = config.view();
    println!("device: {limits}");
    match limits::check(&view, &limits) {
        Ok(needed) => {
            println!(
                "{}: fits: {} sub-apertures (of {}), {} open windows (of {}), {} pool entries (of {})",
                args.config.display(),
                view.windows.len(),
                limits.max_subapertures,
                needed.open_windows,
                limits.max_open_windows,
                needed.pool_entries,
                limits.pool_entries
            );
            Ok(())
        }
        Err(e) => bail!(
            "{}: does not fit {}: {e} [DeviceError::{e:?}]",
            args.config.display(),
            limits.board
        ),
    }
}
