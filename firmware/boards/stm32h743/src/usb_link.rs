//! The host link: a byte stream (`embedded_io_async::{Read, Write}`) over
//! the packets of a USB CDC-ACM class.
//!
//! - Read returns what is left of the last packet, or waits for the next.
//!   Cancel-safe: a packet is only taken from the endpoint in the poll that
//!   completes the read (embassy-usb-synopsys-otg copies it out then), and
//!   the device loop races this read against the camera.
//! - Write collects bytes into a full-size packet and sends it when full;
//!   `flush` (the device loop flushes before it waits) sends what is
//!   collected, or a zero-length packet after a run of full ones, so the
//!   host's driver hands the data on at once.
//! - A disconnected or unconfigured endpoint is [`Disconnected`]: the device
//!   loop returns, and `main` waits for the next connection and runs it
//!   again (configuration and counters are kept).

use brightpix_firmware::device::embedded_io_async::{self, ErrorKind, ErrorType, Read, Write};
use embassy_stm32::peripherals::USB_OTG_FS;
use embassy_stm32::usb::Driver;
use embassy_usb::class::cdc_acm::CdcAcmClass;
use embassy_usb::driver::EndpointError;

/// Full-speed bulk packet size.
pub const PACKET: usize = 64;

type Class<'d> = CdcAcmClass<'d, Driver<'d, USB_OTG_FS>>;

/// The USB device is not connected (or not configured) any more.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Disconnected;

impl defmt::Format for Disconnected {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "USB disconnected")
    }
}

impl core::fmt::Display for Disconnected {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("USB disconnected")
    }
}

impl core::error::Error for Disconnected {}

impl embedded_io_async::Error for Disconnected {
    fn kind(&self) -> ErrorKind {
        ErrorKind::NotConnected
    }
}

impl From<EndpointError> for Disconnected {
    fn from(_: EndpointError) -> Self {
        // `BufferOverflow` cannot happen (reads take whole packets into
        // PACKET-sized buffers); treat it as a broken link all the same.
        Disconnected
    }
}

pub struct UsbLink<'d> {
    class: Class<'d>,
    rx: [u8; PACKET],
    rx_start: usize,
    rx_end: usize,
    tx: [u8; PACKET],
    tx_len: usize,
    /// The last packet sent was full: the transfer needs ending.
    zlp_due: bool,
}

impl<'d> UsbLink<'d> {
    pub fn new(class: Class<'d>) -> Self {
        assert_eq!(class.max_packet_size() as usize, PACKET);
        UsbLink {
            class,
            rx: [0; PACKET],
            rx_start: 0,
            rx_end: 0,
            tx: [0; PACKET],
            tx_len: 0,
            zlp_due: false,
        }
    }

    /// Waits until the host has configured the device; forgets anything
    /// buffered from a previous connection.
    pub async fn wait_connection(&mut self) {
        self.class.wait_connection().await;
        self.rx_start = 0;
        self.rx_end = 0;
        self.tx_len = 0;
        self.zlp_due = false;
    }

    async fn send(&mut self, len: usize) -> Result<(), Disconnected> {
        self.class.write_packet(&self.tx[..len]).await?;
        self.zlp_due = len == PACKET;
        self.tx_len = 0;
        Ok(())
    }
}

impl ErrorType for UsbLink<'_> {
    type Error = Disconnected;
}

impl Read for UsbLink<'_> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Disconnected> {
        if buf.is_empty() {
            return Ok(0);
        }
        // A zero-length packet from the host is no data (returning 0 would
        // mean the end of the stream): wait for the next.
        while self.rx_start == self.rx_end {
            if buf.len() >= PACKET {
                // Straight into the caller's buffer.
                let n = self.class.read_packet(buf).await?;
                if n > 0 {
                    return Ok(n);
                }
                continue;
            }
            let n = self.class.read_packet(&mut self.rx).await?;
            self.rx_start = 0;
            self.rx_end = n;
        }
        let n = buf.len().min(self.rx_end - self.rx_start);
        buf[..n].copy_from_slice(&self.rx[self.rx_start..self.rx_start + n]);
        self.rx_start += n;
        Ok(n)
    }
}

impl Write for UsbLink<'_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Disconnected> {
        let n = buf.len().min(PACKET - self.tx_len);
        self.tx[self.tx_len..self.tx_len + n].copy_from_slice(&buf[..n]);
        self.tx_len += n;
        if self.tx_len == PACKET {
            self.send(PACKET).await?;
        }
        Ok(n)
    }

    async fn flush(&mut self) -> Result<(), Disconnected> {
        if self.tx_len > 0 {
            self.send(self.tx_len).await
        } else if self.zlp_due {
            self.send(0).await
        } else {
            Ok(())
        }
    }
}
