//! The QEMU board's pixel sources: none ([`LinkOnly`], pixels come in
//! `PixelRows` messages on UART0), `PixelRows` frames read from a host
//! file or FIFO through semihosting ([`PixelRowsStream`] over
//! [`HostPixels`]), about 40x faster than the emulated UART, or the
//! simulated camera ([`crate::camera`]).
//!
//! A semihosting read is synchronous: the whole emulated CPU (and QEMU's
//! device emulation) waits in it, so UART0 cannot receive or send
//! meanwhile (nothing is lost: QEMU holds the bytes). [`HostPixels`] keeps
//! that wait short:
//! - each read asks for at most [`READ_CHUNK`] bytes and returns whatever
//!   the host has already written (a read blocks only while a FIFO is empty
//!   *and* open for writing); between reads the device serves UART0;
//! - end of file is not the end of the stream: the reader retries every
//!   [`EOF_POLL_MS`] ms, serving UART0 in between. A FIFO whose writer closed
//!   reads as end of file, so a host may open and close the FIFO any number
//!   of times; a regular file may be appended to.
//!
//! The trade-off: a host that keeps the FIFO open without writing stalls the
//! device (and its UART) until it writes or closes it. Smaller reads would
//! not help there; larger ones save semihosting calls (one read of 4 KiB
//! carries about four `PixelRows` messages).

use brightpix_firmware::camera::SimulatedCamera;
use brightpix_firmware::device::{CameraRefused, LinkOnly, PixelRowsStream, PixelRun, PixelSource};
use brightpix_protocol::wire::{CaptureStart, CropFault, PixelSourceKind, SyncFault};
use brightpix_protocol::{Camera, Crop};
use embassy_time::Timer;
use embedded_io_async::{ErrorKind, ErrorType, Read};

use crate::camera::RING_WORDS;
use crate::hostfs::HostFile;

/// Most bytes one semihosting read asks for.
pub const READ_CHUNK: usize = 4096;
/// Retry period at end of file.
pub const EOF_POLL_MS: u64 = 1;

/// A host file or FIFO as an endless async byte stream (see the module docs).
pub struct HostPixels {
    file: HostFile,
    /// Reads that returned data, and bytes read.
    pub reads: u32,
    pub bytes: u64,
}

impl HostPixels {
    pub fn new(file: HostFile) -> Self {
        HostPixels {
            file,
            reads: 0,
            bytes: 0,
        }
    }
}

impl ErrorType for HostPixels {
    type Error = ErrorKind;
}

impl Read for HostPixels {
    /// Cancel-safe: a read either completes within one poll or waits in a
    /// timer having consumed nothing.
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        if buf.is_empty() {
            return Ok(0);
        }
        let len = buf.len().min(READ_CHUNK);
        loop {
            match self.file.read(&mut buf[..len]) {
                Ok(0) => Timer::after_millis(EOF_POLL_MS).await,
                Ok(n) => {
                    self.reads = self.reads.wrapping_add(1);
                    self.bytes += n as u64;
                    return Ok(n);
                }
                Err(e) => {
                    defmt::error!(
                        "pixels: read failed ({}); the pixel stream stops",
                        defmt::Debug2Format(&e)
                    );
                    return Err(ErrorKind::Other);
                }
            }
        }
    }
}

/// The board's pixel source, chosen at boot by the command line.
pub enum BoardSource {
    Link(LinkOnly),
    Stream(PixelRowsStream<'static, HostPixels>),
    Camera(SimulatedCamera<'static, 'static, RING_WORDS>),
}

impl PixelSource for BoardSource {
    fn kind(&self) -> PixelSourceKind {
        match self {
            BoardSource::Link(s) => s.kind(),
            BoardSource::Stream(s) => s.kind(),
            BoardSource::Camera(s) => s.kind(),
        }
    }

    fn check_crop(&self, camera: Camera, crop: Crop) -> Result<(), CropFault> {
        match self {
            BoardSource::Link(s) => s.check_crop(camera, crop),
            BoardSource::Stream(s) => s.check_crop(camera, crop),
            BoardSource::Camera(s) => s.check_crop(camera, crop),
        }
    }

    fn start(&mut self, camera: Camera, crop: Option<Crop>) -> Result<(), CameraRefused> {
        match self {
            BoardSource::Link(s) => s.start(camera, crop),
            BoardSource::Stream(s) => s.start(camera, crop),
            BoardSource::Camera(s) => s.start(camera, crop),
        }
    }

    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        match self {
            BoardSource::Link(s) => s.set_start(start),
            BoardSource::Stream(s) => s.set_start(start),
            BoardSource::Camera(s) => s.set_start(start),
        }
    }

    fn armed(&self) -> bool {
        match self {
            BoardSource::Link(s) => s.armed(),
            BoardSource::Stream(s) => s.armed(),
            BoardSource::Camera(s) => s.armed(),
        }
    }

    fn stop(&mut self) {
        match self {
            BoardSource::Link(s) => s.stop(),
            BoardSource::Stream(s) => s.stop(),
            BoardSource::Camera(s) => s.stop(),
        }
    }

    async fn next(&mut self) -> PixelRun<'_> {
        match self {
            BoardSource::Link(s) => s.next().await,
            BoardSource::Stream(s) => s.next().await,
            BoardSource::Camera(s) => s.next().await,
        }
    }
}
