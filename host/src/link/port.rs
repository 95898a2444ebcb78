//! The byte link under a [`Client`](super::Client): anything `Read + Write`
//! that can bound how long a read or a write waits.

use std::io::{self, Read, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;

use serialport::{ClearBuffer, SerialPort, TTYPort};

/// A byte link to a device: a serial port, a pseudo-terminal, a Unix socket,
/// or anything a test makes up.
///
/// The client relies on two behaviours:
/// - after [`set_io_timeout`](Port::set_io_timeout)`(t)`, `read` returns
///   `Err(TimedOut | WouldBlock)` when nothing arrived within `t`
///   (`t = 0`: at once), and `write` gives up the same way when the device
///   takes nothing for `t`;
/// - `read` returning `Ok(0)`, or an error other than those, means the
///   port is gone.
pub trait Port: Read + Write + Send {
    /// How long `read` and `write` may wait; `Duration::ZERO`: not at all.
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()>;

    /// The port's name, for messages.
    fn describe(&self) -> String;

    /// Drops bytes received but not read yet (e.g. left over from an earlier
    /// session). The client also skips stale frames, so this may do nothing.
    fn discard_input(&mut self) -> io::Result<()> {
        Ok(())
    }
}

fn serial_timeout(port: &mut dyn SerialPort, timeout: Duration) -> io::Result<()> {
    port.set_timeout(timeout).map_err(io::Error::from)
}

impl Port for TTYPort {
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        serial_timeout(self, timeout)
    }

    fn describe(&self) -> String {
        SerialPort::name(self).unwrap_or_else(|| "serial port".into())
    }

    fn discard_input(&mut self) -> io::Result<()> {
        self.clear(ClearBuffer::Input).map_err(io::Error::from)
    }
}

impl Port for Box<dyn SerialPort> {
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        serial_timeout(self.as_mut(), timeout)
    }

    fn describe(&self) -> String {
        self.name().unwrap_or_else(|| "serial port".into())
    }

    fn discard_input(&mut self) -> io::Result<()> {
        self.clear(ClearBuffer::Input).map_err(io::Error::from)
    }
}

/// A Unix socket, e.g. QEMU's `-serial unix:PATH,server=on`.
pub struct UnixPort {
    stream: UnixStream,
    path: String,
}

impl UnixPort {
    pub fn connect(path: &str) -> io::Result<Self> {
        Ok(UnixPort {
            stream: UnixStream::connect(path)?,
            path: path.to_string(),
        })
    }
}

impl Read for UnixPort {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.stream.read(buf)
    }
}

impl Write for UnixPort {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.stream.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.stream.flush()
    }
}

impl Port for UnixPort {
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        if timeout.is_zero() {
            self.stream.set_nonblocking(true)
        } else {
            self.stream.set_nonblocking(false)?;
            self.stream.set_read_timeout(Some(timeout))?;
            self.stream.set_write_timeout(Some(timeout))
        }
    }

    fn describe(&self) -> String {
        format!("unix:{}", self.path)
    }
}

/// Opens `name`: a serial device (`/dev/ttyACM0`, `/dev/pts/3`, `COM3`) or
/// `unix:PATH` for a Unix socket. Serial ports are opened raw, 8N1, at
/// 115200 baud (ignored by USB CDC-ACM and pseudo-terminals).
pub fn open_port(name: &str) -> io::Result<Box<dyn Port>> {
    if let Some(path) = name.strip_prefix("unix:") {
        return Ok(Box::new(UnixPort::connect(path)?));
    }
    if !std::path::Path::new(name).exists() && !name.to_ascii_uppercase().starts_with("COM") {
        // serialport's own text for this repeats itself ("No such file or
        // directory: No such file or directory").
        return Err(io::Error::new(
            io::ErrorKind::NotFound,
            "no such port (`brightpix devices` lists the serial ports)",
        ));
    }
    let port = serialport::new(name, 115_200)
        .timeout(Duration::from_millis(100))
        .open_native()
        .map_err(io::Error::from)?;
    Ok(Box::new(port))
}
