//! `brightpix configure`: upload a configuration to a device.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::config_file::ProcessingConfig;
use crate::link::Client;

#[derive(Args)]
#[command(
    about = "Upload a processing configuration to a device (chunked, then committed atomically)",
    after_help = "Examples:\n  brightpix configure --port /dev/ttyACM0 --config examples/canary.toml\n  brightpix configure --port /dev/pts/4 --config examples/canary-vignetted.toml\n  brightpix configure --port unix:/tmp/brightpix.sock --config my.toml\n\n\
If the upload fails part-way (a refused table, a lost link), the device keeps its previous\n\
configuration; the error names the device's reason (DeviceError::...)."
)]
pub struct ConfigureArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
    /// Processing configuration (TOML, see docs/CONFIG.md).
    #[arg(long)]
    config: PathBuf,
}

pub fn run(args: ConfigureArgs) -> Result<()> {
    let config = ProcessingConfig::load(&args.config)?;
    let mut client = Client::open(&args.port)?;
    let done = client
        .configure(&config.view())
        .with_context(|| format!("configuring {} with {}", args.port, args.config.display()))?;
    println!(
        "configuration {:#010x} active on {} ({}): {} sub-apertures on a {}x{} camera; \
         {} messages, {} table bytes in {:.1} ms; engine: {} open windows, {} pool entries",
        done.config_id,
        args.port,
        client.info().board,
        config.windows.len(),
        config.camera.width,
        config.camera.height,
        done.messages,
        done.table_bytes,
        done.elapsed.as_secs_f64() * 1e3,
        done.open_windows,
        done.pool_entries
    );
    Ok(())
}
