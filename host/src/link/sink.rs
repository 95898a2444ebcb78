//! Where a [`Client`](super::Client) writes pixels: the link itself, or a
//! separate stream that the device reads (a FIFO that QEMU's board reads
//! through semihosting, far faster than its emulated UART).

use std::fs::{File, OpenOptions};
use std::io::{self, ErrorKind, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where `PixelRows` frames go.
#[derive(Debug, Default)]
pub enum PixelSink {
    /// Over the link, between the other messages (every device).
    #[default]
    Link,
    /// Into a FIFO (or file) that the device reads as its pixel stream
    /// (`PixelSourceKind::Stream`); results still come over the link.
    ///
    /// The client opens it for each stream of frames and closes it before
    /// any other request: a device may wait in a read of an open, empty
    /// FIFO (QEMU's semihosting does, and stops its UART meanwhile).
    Fifo(PathBuf),
}

/// The writing end of a named pipe, non-blocking (the client reads the
/// link while the device drains the pipe).
#[derive(Debug)]
pub struct FifoWriter {
    file: File,
    path: PathBuf,
}

impl FifoWriter {
    /// Opens `path` for writing. A FIFO can only be opened for writing once
    /// its reader has opened it: this retries until then, for `wait` at most.
    pub fn open(path: &Path, wait: Duration) -> io::Result<FifoWriter> {
        let started = Instant::now();
        loop {
            match OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_NONBLOCK)
                .open(path)
            {
                Ok(file) => {
                    return Ok(FifoWriter {
                        file,
                        path: path.to_path_buf(),
                    })
                }
                // ENXIO: no reader yet.
                Err(e) if e.raw_os_error() == Some(libc::ENXIO) && started.elapsed() < wait => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Err(e) if e.raw_os_error() == Some(libc::ENXIO) => {
                    return Err(io::Error::new(
                        ErrorKind::TimedOut,
                        format!("no reader opened the FIFO within {wait:?}"),
                    ))
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Writes what fits now (`WouldBlock` when the pipe is full).
    pub fn try_write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        self.file.write(bytes)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}
