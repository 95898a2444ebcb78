//! `brightpix status`: a device's identity, limits and counters.

use anyhow::Result;
use clap::Args;

use crate::link::Client;

#[derive(Args)]
#[command(
    about = "Show a device's identity, limits, counters and what its engine did",
    after_help = "Examples:\n  brightpix status --port /dev/ttyACM0\n  brightpix status --port /dev/pts/4"
)]
pub struct StatusArgs {
    /// Serial port of the device (/dev/ttyACM0, /dev/pts/N, COM3) or unix:PATH.
    #[arg(long)]
    port: String,
}

pub fn run(args: StatusArgs) -> Result<()> {
    let mut client = Client::open(&args.port)?;
    let s = client.status()?;
    println!("device: {}", client.info());
    println!("{}", super::demo::format_status(&s));
    println!("{}", super::demo::format_engine(&s));
    Ok(())
}
