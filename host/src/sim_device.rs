//! Simulated devices on the desktop, for `brightpix simulate-device`,
//! `brightpix demo` and the simulation-in-loop tests:
//!
//! - [`InProcessDevice`]: the firmware library's device loop
//!   (`brightpix_firmware::device::Device`, the code the boards run) on a
//!   thread of this process, speaking over one end of a pseudo-terminal
//!   pair (or a Unix socket); any serial client opens the other end;
//! - [`QemuDevice`]: the real firmware ELF (`brightpix-qemu`) in
//!   `qemu-system-arm` (mps2-an386 Cortex-M4, or mps2-an500 Cortex-M7: [`QemuCpu`]), its UART0 on a pseudo-terminal or a
//!   Unix socket, its pixels optionally from a FIFO that the host writes
//!   (read by semihosting, much faster than the emulated UART).
//!
//! Both optionally read `PixelRows` frames from a FIFO as well
//! ([`PixelSink::Fifo`](crate::link::PixelSink) on the client side).

use std::collections::VecDeque;
use std::ffi::CString;
use std::fs::File;
use std::future::Future;
use std::io::{self, Read as _, Write as _};
use std::os::unix::ffi::OsStrExt;
use std::os::unix::io::AsRawFd;
use std::os::unix::net::UnixListener;
use std::path::{Path, PathBuf};
use std::pin::pin;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::task::{Context, Poll, Wake, Waker};
use std::thread::{self, JoinHandle, Thread};
use std::time::{Duration, Instant};

use crate::engine_runner::EngineBuffers;
use anyhow::{bail, Context as _};
use brightpix_firmware::device::embedded_io_async::{self as eio, ErrorType};
use brightpix_firmware::device::{
    ConfigSlot, Device, DeviceBuffers, LinkOnly, PixelRowsStream, PixelSource,
};
use brightpix_firmware::engine::MemorySize;
use brightpix_firmware::engine::SubapertureResult;
use brightpix_protocol::wire::{MAX_FRAME_LEN, MAX_PIXEL_BYTES};
use brightpix_protocol::SubapertureWindow;
use serialport::{SerialPort, TTYPort};

// --- sizes ---------------------------------------------------------------------

/// The in-process device's buffers (the QEMU board's limits by default).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SimSizes {
    pub subapertures: usize,
    /// Camera pixels of background and gain maps.
    pub map_pixels: usize,
    pub open_windows: usize,
    pub pool_entries: usize,
    /// Camera pixels of the engine's row history.
    pub history_pixels: usize,
    /// The engine's scratch entries (pixels of the largest selecting window).
    pub scratch_entries: usize,
    pub results_per_row: usize,
}

impl Default for SimSizes {
    fn default() -> Self {
        SimSizes {
            subapertures: 6400,
            map_pixels: 256 * 256,
            open_windows: 256,
            pool_entries: 256 * 271,
            history_pixels: 64 * 4096,
            scratch_entries: 64 * 64,
            results_per_row: 1024,
        }
    }
}

struct SlotVecs {
    windows: Vec<SubapertureWindow>,
    counts: Vec<u16>,
    references: Vec<[i32; 2]>,
    background: Vec<i32>,
    gain: Vec<u16>,
}

/// A device's storage on the heap: what a board keeps in statics, for the
/// in-process device and for tests of the device loop.
pub struct HeapDeviceStorage {
    slots: [SlotVecs; 2],
    engine: EngineBuffers,
    vet_order: Vec<u16>,
    vet_scratch: Vec<u16>,
    results: Vec<SubapertureResult>,
    rx: Vec<u8>,
    tx: Vec<u8>,
    pixels: Vec<u16>,
}

impl HeapDeviceStorage {
    pub fn new(z: SimSizes) -> Self {
        let slot = || SlotVecs {
            windows: vec![
                SubapertureWindow {
                    x: 0,
                    y: 0,
                    width: 0,
                    height: 0
                };
                z.subapertures
            ],
            counts: vec![0; z.subapertures],
            references: vec![[0; 2]; z.subapertures],
            background: vec![0; z.map_pixels],
            gain: vec![0; z.map_pixels],
        };
        let none = SubapertureResult {
            index: 0,
            slope_x: 0,
            slope_y: 0,
            flux: 0,
            valid: false,
        };
        HeapDeviceStorage {
            slots: [slot(), slot()],
            engine: EngineBuffers::with_capacity(MemorySize {
                subapertures: z.subapertures,
                open_windows: z.open_windows,
                pool_entries: z.pool_entries,
                history_pixels: z.history_pixels,
                scratch_entries: z.scratch_entries,
            }),
            vet_order: vec![0; z.subapertures],
            vet_scratch: vec![0; z.subapertures],
            results: vec![none; z.results_per_row],
            rx: vec![0; MAX_FRAME_LEN],
            tx: vec![0; MAX_FRAME_LEN],
            pixels: vec![0; MAX_PIXEL_BYTES / 2],
        }
    }

    /// The buffers for `Device::new`.
    pub fn buffers(&mut self) -> DeviceBuffers<'_> {
        fn slot(s: &mut SlotVecs) -> ConfigSlot<'_> {
            ConfigSlot::new(
                &mut s.windows,
                &mut s.counts,
                &mut s.references,
                &mut s.background,
                &mut s.gain,
            )
        }
        let [a, b] = &mut self.slots;
        DeviceBuffers {
            slots: [slot(a), slot(b)],
            engine: self.engine.memory(),
            order: &mut self.vet_order,
            scratch: &mut self.vet_scratch,
            results: &mut self.results,
            rx: &mut self.rx,
            tx: &mut self.tx,
            pixels: &mut self.pixels,
        }
    }
}

// --- a minimal executor and byte queues ------------------------------------------

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
struct Inbox(Mutex<InboxState>);

impl Inbox {
    fn push(&self, bytes: &[u8]) {
        let mut s = self.0.lock().unwrap();
        s.bytes.extend(bytes);
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    }

    fn close(&self) {
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

struct InboxReader(Arc<Inbox>);

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
type Outlet = Arc<Mutex<Option<Box<dyn io::Write + Send>>>>;

/// The device's link: bytes in from an [`Inbox`], bytes out to an [`Outlet`].
struct SimLink {
    rx: InboxReader,
    tx: Outlet,
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
struct PtyWriter {
    port: TTYPort,
    dropping: bool,
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

// --- the in-process device ---------------------------------------------------------

/// How a simulated device is reached.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum SimLinkKind {
    /// A pseudo-terminal: the device prints `/dev/pts/N`.
    #[default]
    Pty,
    /// A Unix socket at this path (the port name is `unix:PATH`).
    Unix(PathBuf),
}

/// Options of an [`InProcessDevice`].
#[derive(Clone, Debug)]
pub struct InProcessOptions {
    pub sizes: SimSizes,
    pub link: SimLinkKind,
    /// Also read `PixelRows` frames from this FIFO (created if missing).
    pub pixels_fifo: Option<PathBuf>,
    /// Reported in `HelloReply`.
    pub board: &'static str,
}

impl Default for InProcessOptions {
    fn default() -> Self {
        InProcessOptions {
            sizes: SimSizes::default(),
            link: SimLinkKind::Pty,
            pixels_fifo: None,
            board: "brightpix-sim (in-process)",
        }
    }
}

/// The firmware's device loop on a thread of this process (see the module
/// docs). Stops when dropped.
pub struct InProcessDevice {
    port: String,
    fifo: Option<PathBuf>,
    stop: Arc<AtomicBool>,
    inboxes: Vec<Arc<Inbox>>,
    threads: Vec<JoinHandle<()>>,
    /// Keeps the pty's device end open (so reads on the master never fail
    /// while no client is connected).
    _slave: Option<TTYPort>,
    socket: Option<PathBuf>,
}

impl InProcessDevice {
    /// A device on a pseudo-terminal, the default sizes, pixels on the link.
    pub fn start_pty() -> io::Result<InProcessDevice> {
        Self::start(InProcessOptions::default())
    }

    pub fn start(options: InProcessOptions) -> io::Result<InProcessDevice> {
        let stop = Arc::new(AtomicBool::new(false));
        let link_inbox = Arc::new(Inbox::default());
        let outlet: Outlet = Arc::new(Mutex::new(None));
        let mut threads = Vec::new();
        let mut slave = None;
        let mut socket = None;
        let port = match &options.link {
            SimLinkKind::Pty => {
                let (master, pty_slave) = TTYPort::pair().map_err(io::Error::from)?;
                let name = SerialPort::name(&pty_slave)
                    .ok_or_else(|| io::Error::other("the pseudo-terminal has no name"))?;
                let mut reader = master.try_clone_native().map_err(io::Error::from)?;
                *outlet.lock().unwrap() = Some(Box::new(PtyWriter {
                    port: master,
                    dropping: false,
                }));
                slave = Some(pty_slave);
                let (inbox, stop) = (link_inbox.clone(), stop.clone());
                threads.push(spawn("brightpix-sim-pty", move || {
                    let _ = reader.set_timeout(Duration::from_millis(100));
                    let mut buf = [0u8; 4096];
                    while !stop.load(Ordering::Relaxed) {
                        match reader.read(&mut buf) {
                            Ok(n) if n > 0 => inbox.push(&buf[..n]),
                            Ok(_) => thread::sleep(Duration::from_millis(10)),
                            Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                            Err(_) => thread::sleep(Duration::from_millis(10)),
                        }
                    }
                })?);
                name
            }
            SimLinkKind::Unix(path) => {
                let _ = std::fs::remove_file(path);
                let listener = UnixListener::bind(path)?;
                listener.set_nonblocking(true)?;
                socket = Some(path.clone());
                let (inbox, stop, outlet) = (link_inbox.clone(), stop.clone(), outlet.clone());
                threads.push(spawn("brightpix-sim-unix", move || {
                    serve_unix(listener, inbox, outlet, stop)
                })?);
                format!("unix:{}", path.display())
            }
        };
        let mut inboxes = vec![link_inbox.clone()];
        let fifo_inbox = match &options.pixels_fifo {
            Some(path) => {
                make_fifo(path)?;
                let inbox = Arc::new(Inbox::default());
                inboxes.push(inbox.clone());
                let (path, stop, feed) = (path.clone(), stop.clone(), inbox.clone());
                threads.push(spawn("brightpix-sim-fifo", move || {
                    read_fifo(&path, &feed, &stop)
                })?);
                Some(inbox)
            }
            None => None,
        };
        let link = SimLink {
            rx: InboxReader(link_inbox),
            tx: outlet,
        };
        let (sizes, board) = (options.sizes, options.board);
        threads.push(spawn("brightpix-sim-device", move || {
            let mut storage = HeapDeviceStorage::new(sizes);
            match fifo_inbox {
                None => run_device(Device::new(link, LinkOnly, storage.buffers(), board)),
                Some(inbox) => {
                    let mut frame_buffer = vec![0u8; MAX_FRAME_LEN];
                    let mut pixels = vec![0u16; MAX_PIXEL_BYTES / 2];
                    let source =
                        PixelRowsStream::new(InboxReader(inbox), &mut frame_buffer, &mut pixels);
                    run_device(Device::new(link, source, storage.buffers(), board))
                }
            }
        })?);
        Ok(InProcessDevice {
            port,
            fifo: options.pixels_fifo,
            stop,
            inboxes,
            threads,
            _slave: slave,
            socket,
        })
    }

    /// The port a client opens: `/dev/pts/N` or `unix:PATH`.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// The FIFO the device reads pixels from, if any.
    pub fn pixels_fifo(&self) -> Option<&Path> {
        self.fifo.as_deref()
    }

    /// Stops the device and waits for its threads.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for inbox in &self.inboxes {
            inbox.close();
        }
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        if let Some(path) = self.socket.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

impl Drop for InProcessDevice {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn spawn(name: &str, f: impl FnOnce() + Send + 'static) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name(name.into())
        .stack_size(4 << 20)
        .spawn(f)
}

fn run_device<C: PixelSource>(mut device: Device<'_, SimLink, C>) {
    // Returns only when the link is stopped (the inbox never ends otherwise).
    let _ = block_on(device.run());
}

fn serve_unix(listener: UnixListener, inbox: Arc<Inbox>, outlet: Outlet, stop: Arc<AtomicBool>) {
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

/// Creates a FIFO at `path` unless something is there already.
pub fn make_fifo(path: &Path) -> io::Result<()> {
    if path.exists() {
        return Ok(());
    }
    let c = CString::new(path.as_os_str().as_bytes())
        .map_err(|_| io::Error::other("FIFO path contains a NUL byte"))?;
    // SAFETY: `c` is a valid NUL-terminated path.
    if unsafe { libc::mkfifo(c.as_ptr(), 0o600) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// Reads the FIFO into `feed` until `stop`; a writer that closes is not the
/// end (the FIFO is reopened for the next one).
fn read_fifo(path: &Path, feed: &Inbox, stop: &AtomicBool) {
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

// --- QEMU -------------------------------------------------------------------------------

/// The firmware workspace (`firmware/` beside `host/`).
pub fn firmware_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or_else(|| PathBuf::from("firmware"), |root| root.join("firmware"))
}

/// The core QEMU emulates, and the code generation the firmware is built
/// for: the same ELF contract on both (firmware/README.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum QemuCpu {
    /// Cortex-M4F on `mps2-an386`: the firmware's default build.
    #[default]
    M4,
    /// Cortex-M7 on `mps2-an500`, built with `-C target-cpu=cortex-m7` into
    /// `firmware/target/cortex-m7` (the STM32H743's code generation; a
    /// separate target directory keeps the M4 build valid).
    M7,
}

impl QemuCpu {
    /// QEMU's `-cpu`.
    pub fn cpu(self) -> &'static str {
        match self {
            QemuCpu::M4 => "cortex-m4",
            QemuCpu::M7 => "cortex-m7",
        }
    }

    /// QEMU's `-machine`.
    pub fn machine(self) -> &'static str {
        match self {
            QemuCpu::M4 => "mps2-an386",
            QemuCpu::M7 => "mps2-an500",
        }
    }

    /// The firmware's target directory.
    fn target_dir(self) -> PathBuf {
        match self {
            QemuCpu::M4 => firmware_dir().join("target"),
            QemuCpu::M7 => firmware_dir().join("target/cortex-m7"),
        }
    }

    /// Extra `cargo --config` of its build.
    fn cargo_config(self) -> Option<&'static str> {
        match self {
            QemuCpu::M4 => None,
            QemuCpu::M7 => {
                Some(r#"target.thumbv7em-none-eabihf.rustflags=["-C","target-cpu=cortex-m7"]"#)
            }
        }
    }

    /// Where [`build_qemu_elf_for`] puts the ELF.
    pub fn default_elf(self) -> PathBuf {
        self.target_dir()
            .join("thumbv7em-none-eabihf/release/brightpix-qemu")
    }
}

/// Where `cargo build --release -p brightpix-board-qemu` puts the ELF.
pub fn default_qemu_elf() -> PathBuf {
    QemuCpu::M4.default_elf()
}

/// Builds the QEMU firmware (`cargo build --release -p brightpix-board-qemu`
/// in `firmware/`, with the calling cargo's `CARGO_*` variables removed so
/// that they do not leak into the thumb build). Output goes to stderr.
pub fn build_qemu_elf() -> anyhow::Result<PathBuf> {
    build_qemu_elf_for(QemuCpu::M4)
}

/// [`build_qemu_elf`] for `cpu`: the M7 build is `cargo build --release -p
/// brightpix-board-qemu --bin brightpix-qemu --target-dir target/cortex-m7
/// --config 'target.thumbv7em-none-eabihf.rustflags=["-C","target-cpu=cortex-m7"]'`
/// (the pattern of `boards/qemu/scripts/run-bench m7`).
pub fn build_qemu_elf_for(cpu: QemuCpu) -> anyhow::Result<PathBuf> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut command = Command::new(cargo);
    command
        .args(["build", "--release", "-p", "brightpix-board-qemu"])
        .current_dir(firmware_dir());
    if let Some(config) = cpu.cargo_config() {
        command
            .args(["--bin", "brightpix-qemu", "--target-dir"])
            .arg(cpu.target_dir())
            .args(["--config", config]);
    }
    for (key, _) in std::env::vars_os() {
        let key_str = key.to_string_lossy();
        if (key_str.starts_with("CARGO_") && key_str != "CARGO_HOME")
            || key_str == "RUSTFLAGS"
            || key_str == "CARGO_ENCODED_RUSTFLAGS"
        {
            command.env_remove(&key);
        }
    }
    let status = command
        .stdout(Stdio::null())
        .status()
        .context("running cargo to build the QEMU firmware")?;
    if !status.success() {
        bail!(
            "building the QEMU firmware ({}) failed ({status}); try: cd {} && cargo build --release -p brightpix-board-qemu",
            cpu.cpu(),
            firmware_dir().display()
        );
    }
    let elf = cpu.default_elf();
    if !elf.exists() {
        bail!("the firmware build did not produce {}", elf.display());
    }
    Ok(elf)
}

/// The QEMU firmware ELF: `elf` if given, else the default one, built if missing.
pub fn qemu_elf(elf: Option<&Path>) -> anyhow::Result<PathBuf> {
    qemu_elf_for(elf, QemuCpu::M4)
}

/// [`qemu_elf`] for `cpu`.
pub fn qemu_elf_for(elf: Option<&Path>, cpu: QemuCpu) -> anyhow::Result<PathBuf> {
    match elf {
        Some(e) if e.exists() => Ok(e.to_path_buf()),
        Some(e) => bail!("firmware ELF {} does not exist", e.display()),
        None if cpu.default_elf().exists() => Ok(cpu.default_elf()),
        None => {
            eprintln!(
                "brightpix: building the QEMU firmware ({} is missing; about a minute)",
                cpu.default_elf().display()
            );
            build_qemu_elf_for(cpu)
        }
    }
}

/// Options of a [`QemuDevice`].
#[derive(Clone, Debug, Default)]
pub struct QemuOptions {
    /// The firmware ELF (default: [`qemu_elf`]`(None)`).
    pub elf: Option<PathBuf>,
    pub link: SimLinkKind,
    /// Give the board a FIFO to read pixels from (`--pixels PATH`).
    pub pixels_fifo: bool,
    /// Where QEMU's stdout (the raw defmt log) goes (default: a file in the
    /// device's temporary directory).
    pub log: Option<PathBuf>,
    /// `qemu-system-arm` (default: from PATH).
    pub qemu: Option<PathBuf>,
    /// The core and machine (the ELF must be built for it).
    pub cpu: QemuCpu,
}

/// The firmware in `qemu-system-arm`. Stops (kills QEMU) when dropped, and
/// QEMU dies with this process even if it is killed (`PR_SET_PDEATHSIG`;
/// strictly, with the thread that launched it: launch from a thread that
/// lives as long as the device).
pub struct QemuDevice {
    child: Child,
    port: String,
    fifo: Option<PathBuf>,
    log: PathBuf,
    elf: PathBuf,
    cpu: QemuCpu,
    dir: PathBuf,
    stdout: Option<JoinHandle<()>>,
}

static DIR_COUNTER: AtomicU64 = AtomicU64::new(0);

/// A fresh private directory under the system's temporary directory.
pub fn temp_dir(prefix: &str) -> io::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!(
        "{prefix}-{}-{}",
        std::process::id(),
        DIR_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

impl QemuDevice {
    pub fn launch(options: QemuOptions) -> anyhow::Result<QemuDevice> {
        let elf = qemu_elf_for(options.elf.as_deref(), options.cpu)?;
        let dir = temp_dir("brightpix-qemu")?;
        let log = options.log.clone().unwrap_or_else(|| dir.join("defmt.log"));
        let qemu = options
            .qemu
            .clone()
            .unwrap_or_else(|| PathBuf::from("qemu-system-arm"));
        let mut command = Command::new(&qemu);
        command.args([
            "-cpu",
            options.cpu.cpu(),
            "-machine",
            options.cpu.machine(),
            "-display",
            "none",
            "-monitor",
            "none",
            "-serial",
        ]);
        let socket = match &options.link {
            SimLinkKind::Pty => {
                command.arg("pty");
                None
            }
            SimLinkKind::Unix(path) => {
                let _ = std::fs::remove_file(path);
                command.arg(format!("unix:{},server=on,wait=on", path.display()));
                Some(path.clone())
            }
        };
        let fifo = if options.pixels_fifo {
            let path = dir.join("pixels.fifo");
            make_fifo(&path)?;
            if path.to_string_lossy().contains(char::is_whitespace) {
                bail!("the FIFO path {} contains blanks", path.display());
            }
            Some(path)
        } else {
            None
        };
        let mut semihosting = String::from("enable=on,target=native");
        if let Some(path) = &fifo {
            semihosting.push_str(&format!(
                ",arg=brightpix-qemu,arg=--pixels,arg={}",
                path.display()
            ));
        }
        command
            .args(["-semihosting-config", &semihosting, "-kernel"])
            .arg(&elf)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        // Its own process group: Ctrl-C in a terminal reaches this process,
        // which then stops QEMU, rather than QEMU directly.
        std::os::unix::process::CommandExt::process_group(&mut command, 0);
        // And QEMU dies with this process, however it ends (SIGKILL too):
        // the kernel sends it SIGKILL when the thread that started it exits.
        let parent = std::process::id() as libc::pid_t;
        // SAFETY: between fork and exec the closure calls only
        // async-signal-safe functions (prctl, getppid, _exit).
        unsafe {
            std::os::unix::process::CommandExt::pre_exec(&mut command, move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(io::Error::last_os_error());
                }
                // The parent may have died before the prctl took effect.
                if libc::getppid() != parent {
                    libc::_exit(1);
                }
                Ok(())
            });
        }
        let mut child = command.spawn().with_context(|| {
            format!(
                "cannot start {} (install it: apt-get install qemu-system-arm)",
                qemu.display()
            )
        })?;
        let (tx, rx) = mpsc::channel::<String>();
        let stdout = child.stdout.take().expect("piped stdout");
        let log_file = File::create(&log).with_context(|| format!("creating {}", log.display()))?;
        let tx = socket.is_none().then_some(tx);
        let stdout_thread = spawn("brightpix-qemu-stdout", move || {
            copy_qemu_stdout(stdout, log_file, tx)
        })?;
        let stderr = child.stderr.take().expect("piped stderr");
        let (err_tx, err_rx) = mpsc::channel::<String>();
        spawn("brightpix-qemu-stderr", move || {
            let mut text = String::new();
            let _ = io::BufReader::new(stderr).read_to_string(&mut text);
            let _ = err_tx.send(text);
        })?;
        let mut device = QemuDevice {
            child,
            port: String::new(),
            fifo,
            log,
            elf,
            cpu: options.cpu,
            dir,
            stdout: Some(stdout_thread),
        };
        let started = Instant::now();
        device.port = match socket {
            None => loop {
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(path) => break path,
                    Err(_) => {
                        if let Some(status) = device.child.try_wait()? {
                            let err = err_rx
                                .recv_timeout(Duration::from_millis(500))
                                .unwrap_or_default();
                            bail!("QEMU exited at start ({status}): {}", err.trim());
                        }
                        if started.elapsed() > Duration::from_secs(10) {
                            bail!("QEMU did not report its pseudo-terminal within 10 s");
                        }
                    }
                }
            },
            Some(path) => {
                while !path.exists() {
                    if let Some(status) = device.child.try_wait()? {
                        let err = err_rx
                            .recv_timeout(Duration::from_millis(500))
                            .unwrap_or_default();
                        bail!("QEMU exited at start ({status}): {}", err.trim());
                    }
                    if started.elapsed() > Duration::from_secs(10) {
                        bail!("QEMU did not create {} within 10 s", path.display());
                    }
                    thread::sleep(Duration::from_millis(10));
                }
                format!("unix:{}", path.display())
            }
        };
        Ok(device)
    }

    /// Opens the pixel FIFO once and closes it: the board's semihosting open
    /// of a FIFO returns only when a writer has opened it.
    pub fn release_fifo(&self, wait: Duration) -> anyhow::Result<()> {
        if let Some(path) = &self.fifo {
            crate::link::FifoWriter::open(path, wait).with_context(|| {
                format!(
                    "the firmware did not open its pixel FIFO {}",
                    path.display()
                )
            })?;
        }
        Ok(())
    }

    /// [`QemuDevice::release_fifo`] on a thread, for when the board opens
    /// the FIFO only later (with `-serial unix:..,wait=on` QEMU starts the
    /// firmware only once a client has connected).
    pub fn release_fifo_in_background(&self, wait: Duration) {
        if let Some(path) = self.fifo.clone() {
            let _ = spawn("brightpix-qemu-fifo", move || {
                let _ = crate::link::FifoWriter::open(&path, wait);
            });
        }
    }

    /// The port a client opens: `/dev/pts/N` or `unix:PATH`.
    pub fn port(&self) -> &str {
        &self.port
    }

    pub fn pixels_fifo(&self) -> Option<&Path> {
        self.fifo.as_deref()
    }

    /// QEMU's stdout: the firmware's raw defmt frames.
    pub fn log_path(&self) -> &Path {
        &self.log
    }

    pub fn elf(&self) -> &Path {
        &self.elf
    }

    /// The core and machine QEMU emulates.
    pub fn cpu(&self) -> QemuCpu {
        self.cpu
    }

    /// QEMU's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// QEMU's exit status, if it has exited.
    pub fn exit_status(&mut self) -> Option<ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// What an exit status means for the firmware.
    pub fn describe_exit(status: ExitStatus) -> String {
        match status.code() {
            Some(0) => "exited normally (0)".into(),
            Some(101) => "panicked (exit code 101)".into(),
            Some(102) => "HardFault (exit code 102)".into(),
            Some(c) => format!("exited with code {c}"),
            None => format!("ended by a signal ({status})"),
        }
    }

    /// The defmt log decoded by `defmt-print`, if it is installed.
    pub fn decoded_log(&self) -> Option<String> {
        let log = File::open(&self.log).ok()?;
        let out = Command::new("defmt-print")
            .arg("-e")
            .arg(&self.elf)
            .stdin(log)
            .stderr(Stdio::null())
            .output()
            .ok()?;
        Some(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// Kills QEMU and removes its temporary files (the log too, unless it
    /// was given in the options).
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Some(t) = self.stdout.take() {
            let _ = t.join();
        }
        if let Some(path) = self.port.strip_prefix("unix:") {
            let _ = std::fs::remove_file(path);
        }
        if !self.log.starts_with(&self.dir) || std::env::var_os("BRIGHTPIX_KEEP_QEMU_LOG").is_some()
        {
            if let Some(f) = &self.fifo {
                let _ = std::fs::remove_file(f);
            }
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

impl Drop for QemuDevice {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Finds `char device redirected to /dev/pts/N (label serial0)` in QEMU's
/// stdout, sends the path, and copies everything else (defmt frames) to `log`.
/// (With `tx` `None`, QEMU prints no such line: everything is log.)
fn copy_qemu_stdout(mut stdout: impl io::Read, mut log: File, tx: Option<mpsc::Sender<String>>) {
    const MARK: &[u8] = b"char device redirected to ";
    let mut head = Vec::new();
    let mut buf = [0u8; 4096];
    let mut found = tx.is_none();
    loop {
        let n = match stdout.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        if found {
            let _ = log.write_all(&buf[..n]);
            continue;
        }
        head.extend_from_slice(&buf[..n]);
        if let Some(at) = find(&head, MARK) {
            if let Some(end) = head[at..].iter().position(|&b| b == b'\n') {
                let line = String::from_utf8_lossy(&head[at + MARK.len()..at + end]).into_owned();
                let path = line.split_whitespace().next().unwrap_or("").to_string();
                if let Some(tx) = &tx {
                    let _ = tx.send(path);
                }
                let _ = log.write_all(&head[..at]);
                let _ = log.write_all(&head[at + end + 1..]);
                found = true;
            }
        }
    }
    if !found {
        let _ = log.write_all(&head);
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

// --- Ctrl-C -------------------------------------------------------------------------

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// Catches SIGINT and SIGTERM from now on; [`interrupted`] tells whether
/// one arrived.
pub fn catch_interrupts() {
    let handler = on_signal as extern "C" fn(libc::c_int);
    // SAFETY: the handler only stores to an atomic (async-signal-safe).
    unsafe {
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
        libc::signal(libc::SIGTERM, handler as libc::sighandler_t);
    }
}

/// Whether SIGINT or SIGTERM arrived since [`catch_interrupts`].
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}
