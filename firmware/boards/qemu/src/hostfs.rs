//! Reading host files through semihosting (SYS_OPEN / SYS_READ / SYS_FLEN).
//!
//! Much faster than the UART under QEMU, and works on a FIFO too (a read blocks
//! the whole emulated CPU while the FIFO is empty and open for writing; see
//! `pixels.rs`).
//! Paths are relative to QEMU's working directory.

use core::ffi::CStr;

use semihosting::fs::File;
use semihosting::io::{self, Read};

/// Longest path accepted by [`HostFile::open_str`], in bytes.
pub const MAX_PATH: usize = 255;

/// A host file opened for reading.
pub struct HostFile {
    file: File,
}

impl HostFile {
    /// Open `path` read-only (binary mode).
    pub fn open(path: &CStr) -> io::Result<Self> {
        Ok(Self {
            file: File::open(path)?,
        })
    }

    /// Open a path given as `&str` (copied into a NUL-terminated buffer).
    pub fn open_str(path: &str) -> io::Result<Self> {
        let mut buf = [0u8; MAX_PATH + 1];
        let bytes = path.as_bytes();
        if bytes.len() > MAX_PATH || bytes.contains(&0) {
            return Err(io::ErrorKind::InvalidInput.into());
        }
        buf[..bytes.len()].copy_from_slice(bytes);
        let cstr = CStr::from_bytes_until_nul(&buf)
            .map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
        Self::open(cstr)
    }

    /// Read up to `buf.len()` bytes; `Ok(0)` at end of file.
    pub fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.file.read(buf)
    }

    /// Fill `buf` completely, or fail (`UnexpectedEof` if the file ends first).
    pub fn read_exact(&mut self, buf: &mut [u8]) -> io::Result<()> {
        self.file.read_exact(buf)
    }

    /// File length in bytes (SYS_FLEN; not meaningful for a FIFO).
    pub fn size(&self) -> io::Result<u64> {
        Ok(self.file.metadata()?.len())
    }
}

/// Length and FNV-1a (32-bit) hash of a whole host file, read in `chunk`-sized
/// pieces: the smoke check the QEMU board runs when given a path.
/// Also returns the length SYS_FLEN reports, for comparison.
pub fn digest(path: &str, chunk: &mut [u8]) -> io::Result<(u64, u64, u32)> {
    let mut file = HostFile::open_str(path)?;
    let flen = file.size()?;
    let mut total = 0u64;
    let mut hash = 0x811c_9dc5u32;
    loop {
        let n = file.read(chunk)?;
        if n == 0 {
            return Ok((flen, total, hash));
        }
        total += n as u64;
        for &b in &chunk[..n] {
            hash = (hash ^ u32::from(b)).wrapping_mul(0x0100_0193);
        }
    }
}
