//! `brightpix devices`: the serial ports of this machine.

use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use serialport::SerialPortType;

use crate::link::{Client, ClientOptions};

#[derive(Args)]
#[command(
    about = "List serial ports (USB CDC-ACM devices such as the STM32H743 board appear as /dev/ttyACM*)",
    after_help = "Examples:\n  brightpix devices\n  brightpix devices --probe      # also ask each port whether a brightpix device answers\n\n\
Pseudo-terminals are not listed: `brightpix simulate-device` prints the /dev/pts/N of its device."
)]
pub struct DevicesArgs {
    /// Send Hello to every port and report the brightpix devices that answer.
    #[arg(long)]
    probe: bool,
}

pub fn run(args: DevicesArgs) -> Result<()> {
    let ports = serialport::available_ports().context("listing serial ports")?;
    if ports.is_empty() {
        println!("no serial ports found");
    }
    for port in ports {
        let kind = match &port.port_type {
            SerialPortType::UsbPort(usb) => format!(
                "USB {:04x}:{:04x}{}{}",
                usb.vid,
                usb.pid,
                usb.manufacturer
                    .as_deref()
                    .map(|m| format!(" {m}"))
                    .unwrap_or_default(),
                usb.product
                    .as_deref()
                    .map(|p| format!(" {p}"))
                    .unwrap_or_default()
            ),
            SerialPortType::PciPort => "PCI".into(),
            SerialPortType::BluetoothPort => "Bluetooth".into(),
            SerialPortType::Unknown => "unknown".into(),
        };
        print!("{}\t{kind}", port.port_name);
        if args.probe {
            let options = ClientOptions {
                connect_timeout: Duration::from_millis(1500),
                ..ClientOptions::default()
            };
            match Client::open_with(&port.port_name, options) {
                Ok(client) => print!("\tbrightpix: {}", client.info()),
                Err(e) => print!("\tnot a brightpix device ({e})"),
            }
        }
        println!();
    }
    Ok(())
}
