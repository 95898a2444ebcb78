//! [`InProcessDevice`]: the firmware library's device loop on threads of
//! this process, its pixels on the link, from a FIFO, or from its own
//! simulated camera (`camera.rs`).

use std::io::{self, Read as _};
use std::os::unix::net::UnixListener;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use brightpix_firmware::camera::SimulatedCamera;
use brightpix_firmware::device::{Device, LinkOnly, PixelRowsStream, PixelSource};
use brightpix_protocol::wire::{MAX_FRAME_LEN, MAX_PIXEL_BYTES};
use serialport::{SerialPort, TTYPort};

use super::camera::{CameraOptions, CameraRing, InProcessCamera, IN_PROCESS_BUS};
use super::link::{
    block_on, read_fifo, serve_unix, Inbox, InboxReader, Outlet, PtyWriter, SimLink,
};
use super::{make_fifo, spawn, HeapDeviceStorage, SimSizes};

/// Words (two pixels each) of one run the camera source hands the device.
const CAMERA_RUN_WORDS: usize = 4096;

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
    /// The device's own simulated camera (`capture`); not with `pixels_fifo`.
    pub camera: Option<CameraOptions>,
    /// Reported in `HelloReply`.
    pub board: &'static str,
    /// The pseudo-terminal's bytes reach the device at most this fast (a
    /// slow serial link, for tests); `None`: as fast as they come.
    pub link_bytes_per_second: Option<u32>,
}

impl Default for InProcessOptions {
    fn default() -> Self {
        InProcessOptions {
            sizes: SimSizes::default(),
            link: SimLinkKind::Pty,
            pixels_fifo: None,
            camera: None,
            board: "brightpix-sim (in-process)",
            link_bytes_per_second: None,
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
    camera: Option<InProcessCamera>,
}

impl InProcessDevice {
    /// A device on a pseudo-terminal, the default sizes, pixels on the link.
    pub fn start_pty() -> io::Result<InProcessDevice> {
        Self::start(InProcessOptions::default())
    }

    pub fn start(options: InProcessOptions) -> io::Result<InProcessDevice> {
        if options.camera.is_some() && options.pixels_fifo.is_some() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "a simulated device has either a camera or a pixel FIFO, not both",
            ));
        }
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
                // A slow link: a piece every 20 ms (what is not read yet
                // waits in the pseudo-terminal, as behind a UART).
                let (piece, pause) = match options.link_bytes_per_second {
                    Some(rate) => (
                        (rate as usize / 50).clamp(1, 4096),
                        Duration::from_millis(20),
                    ),
                    None => (4096, Duration::ZERO),
                };
                threads.push(spawn("brightpix-sim-pty", move || {
                    let _ = reader.set_timeout(Duration::from_millis(100));
                    let mut buf = [0u8; 4096];
                    while !stop.load(Ordering::Relaxed) {
                        match reader.read(&mut buf[..piece]) {
                            Ok(n) if n > 0 => {
                                inbox.push(&buf[..n]);
                                thread::sleep(pause);
                            }
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
        let ring = options.camera.as_ref().map(|_| Arc::new(CameraRing::new()));
        let camera = match (&ring, options.camera.clone()) {
            (Some(ring), Some(camera)) => Some(InProcessCamera::start(ring.clone(), camera)?),
            _ => None,
        };
        threads.push(spawn("brightpix-sim-device", move || {
            let mut storage = HeapDeviceStorage::new(sizes);
            match (fifo_inbox, ring) {
                (_, Some(ring)) => {
                    let mut words = vec![0u32; CAMERA_RUN_WORDS];
                    let mut pixels = vec![0u16; 2 * CAMERA_RUN_WORDS];
                    let source =
                        SimulatedCamera::new(&ring, IN_PROCESS_BUS, &mut words, &mut pixels);
                    run_device(Device::new(link, source, storage.buffers(), board))
                }
                (None, None) => run_device(Device::new(link, LinkOnly, storage.buffers(), board)),
                (Some(inbox), None) => {
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
            camera,
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

    /// Whether the device has its own (simulated) camera.
    pub fn has_camera(&self) -> bool {
        self.camera.is_some()
    }

    fn shutdown(&mut self) {
        self.camera = None;
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

fn run_device<C: PixelSource>(mut device: Device<'_, SimLink, C>) {
    // Returns only when the link is stopped (the inbox never ends otherwise).
    let _ = block_on(device.run());
}
