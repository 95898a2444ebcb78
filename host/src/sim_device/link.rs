//! The in-process device's transports: a small executor that sleeps
//! ([`block_on`]), byte queues that threads fill and the device loop reads
//! ([`Inbox`]), the device's link over them ([`SimLink`]), and the threads
//! that serve a pseudo-terminal, a Unix socket or a pixel FIFO.

use std::collections::VecDeque;
use std::future::Future;
use std::io::{self, Read as _, Write as _};
use std::os::unix::io::AsRawFd;
use std::os::unix::net::UnixListener;
use std::path::Path;
use std::pin::pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Wake, Waker};
use std::thread::{self, JoinHandle, Thread};
use std::time::Duration;

use brightpix_firmware::device::embedded_io_async::{self as eio, ErrorType};
use serialport::{SerialPort, TTYPort};

use super::spawn;

struct ThreadWaker(Thread);

impl Wake for ThreadWaker {
    fn wake(self: Arc<Self>) {
        self.0.unpark();
    }
    fn wake_by_ref(self: &Arc<Self>) {
        self.0.unpark();
    }
}

/// Runs `future` on this thread, sleeping until it is woken (unlike
/// `embassy_futures::block_on`, which spins).
pub fn block_on<F: Future>(future: F) -> F::Output {
    let waker = Waker::from(Arc::new(ThreadWaker(thread::current())));
    let mut cx = Context::from_waker(&waker);
    let mut future = pin!(future);
    loop {
        if let Poll::Ready(v) = future.as_mut().poll(&mut cx) {
            return v;
        }
        thread::park();
    }
}

#[derive(Default)]
struct InboxState {
    bytes: VecDeque<u8>,
    waker: Option<Waker>,
    closed: bool,
}

/// Bytes that threads push and an async reader takes (cancel-safe: a read
/// that is dropped has taken nothing).
#[derive(Default)]
pub(super) struct Inbox(Mutex<InboxState>);

impl Inbox {
    pub(super) fn push(&self, bytes: &[u8]) {
        let mut s = self.0.lock().unwrap();
        s.bytes.extend(bytes);
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    }

    pub(super) fn close(&self) {
        let mut s = self.0.lock().unwrap();
        s.closed = true;
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    }
}

/// The error of the simulated link: it was stopped.
#[derive(Debug)]
pub struct Stopped;

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the simulated device was stopped")
    }
}

impl std::error::Error for Stopped {}

impl eio::Error for Stopped {
    fn kind(&self) -> eio::ErrorKind {
        eio::ErrorKind::NotConnected
    }
}

pub(super) struct InboxReader(pub(super) Arc<Inbox>);

impl ErrorType for InboxReader {
    type Error = Stopped;
}

impl eio::Read for InboxReader {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Stopped> {
        std::future::poll_fn(|cx| {
            let mut s = self.0 .0.lock().unwrap();
            if !s.bytes.is_empty() {
                let n = buf.len().min(s.bytes.len());
                for (b, v) in buf.iter_mut().zip(s.bytes.drain(..n)) {
                    *b = v;
                }
                Poll::Ready(Ok(n))
            } else if s.closed {
                Poll::Ready(Err(Stopped))
            } else {
                s.waker = Some(cx.waker().clone());
                Poll::Pending
            }
        })
        .await
    }
}

/// Where the device's bytes go: the current connection, if any. Like a
/// UART with nobody listening, bytes that cannot be delivered are dropped.
pub(super) type Outlet = Arc<Mutex<Option<Box<dyn io::Write + Send>>>>;

/// The device's link: bytes in from an [`Inbox`], bytes out to an [`Outlet`].
pub(super) struct SimLink {
    pub(super) rx: InboxReader,
    pub(super) tx: Outlet,
}

impl ErrorType for SimLink {
    type Error = Stopped;
}

impl eio::Read for SimLink {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Stopped> {
        self.rx.read(buf).await
    }
}

impl eio::Write for SimLink {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Stopped> {
        let mut tx = self.tx.lock().unwrap();
        if let Some(w) = tx.as_mut() {
            if w.write_all(buf).is_err() {
                *tx = None;
            }
        }
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Stopped> {
        Ok(())
    }
}

/// Writes to the pty master; once a write times out (nobody reads the
/// other end), drops bytes without waiting until one gets through again.
pub(super) struct PtyWriter {
    pub(super) port: TTYPort,
    pub(super) dropping: bool,
}

impl io::Write for PtyWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let wait = if self.dropping {
            Duration::ZERO
        } else {
            Duration::from_millis(200)
        };
        let _ = self.port.set_timeout(wait);
        let mut rest = buf;
        while !rest.is_empty() {
            match self.port.write(rest) {
                Ok(n) => rest = &rest[n..],
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => {
                    self.dropping = true;
                    return Ok(buf.len());
                }
            }
        }
        self.dropping = false;
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

pub(super) fn serve_unix(
    listener: UnixListener,
    inbox: Arc<Inbox>,
    outlet: Outlet,
    stop: Arc<AtomicBool>,
) {
    let mut readers: Vec<JoinHandle<()>> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, _)) => {
                let _ = stream.set_nonblocking(false);
                let _ = stream.set_write_timeout(Some(Duration::from_millis(500)));
                if let Ok(writer) = stream.try_clone() {
                    *outlet.lock().unwrap() = Some(Box::new(writer));
                }
                let (inbox, stop) = (inbox.clone(), stop.clone());
                let mut stream = stream;
                let _ = stream.set_read_timeout(Some(Duration::from_millis(100)));
                if let Ok(t) = spawn("brightpix-sim-unix-conn", move || {
                    let mut buf = [0u8; 4096];
                    while !stop.load(Ordering::Relaxed) {
                        match stream.read(&mut buf) {
                            Ok(0) => break,
                            Ok(n) => inbox.push(&buf[..n]),
                            Err(e)
                                if matches!(
                                    e.kind(),
                                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                                ) => {}
                            Err(_) => break,
                        }
                    }
                }) {
                    readers.push(t);
                }
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                thread::sleep(Duration::from_millis(20))
            }
            Err(_) => thread::sleep(Duration::from_millis(20)),
        }
    }
    for r in readers {
        let _ = r.join();
    }
}

/// Reads the FIFO into `feed` until `stop`; a writer that closes is not the
/// end (the FIFO is reopened for the next one).
pub(super) fn read_fifo(path: &Path, feed: &Inbox, stop: &AtomicBool) {
    use std::os::unix::fs::OpenOptionsExt;
    let mut buf = vec![0u8; 64 * 1024];
    while !stop.load(Ordering::Relaxed) {
        let Ok(mut file) = std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(path)
        else {
            thread::sleep(Duration::from_millis(100));
            continue;
        };
        'open: while !stop.load(Ordering::Relaxed) {
            let mut fd = libc::pollfd {
                fd: file.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            // SAFETY: one valid pollfd.
            let ready = unsafe { libc::poll(&mut fd, 1, 100) };
            if ready <= 0 {
                continue;
            }
            loop {
                match file.read(&mut buf) {
                    Ok(0) => break 'open, // the writer closed: reopen
                    Ok(n) => feed.push(&buf[..n]),
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(_) => break 'open,
                }
            }
        }
    }
}
