//! A device with a camera of its own as the view's source: configured (or
//! its configuration checked), then captured from in chunks, its `Status`
//! read between chunks. When the device disappears the page and the
//! terminal say so, and the source reconnects once it answers again.
//!
//! A simulated camera's pixels are not on the link: for display, the
//! frames of its seed are made again on a thread of their own, a few a
//! second, for the frame numbers the results sample shows.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use brightpix_protocol::wire::tables::config_digest;
use brightpix_protocol::wire::DeviceError;

use super::hub::{Health, Hub, Setup};
use crate::config_file::ProcessingConfig;
use crate::link::{Client, LinkError};
use crate::sim_device::CameraFrames;

/// What to watch.
#[derive(Clone)]
pub struct DeviceSource {
    pub port: String,
    pub config: ProcessingConfig,
    pub config_name: String,
    /// Upload the configuration (else check that the device runs it).
    pub configure: bool,
    /// Frames per capture request: the status is read between two.
    pub chunk: u32,
    /// The seed of a simulated camera, whose frames the view can remake.
    pub sim_seed: Option<u64>,
    /// How the source is described on the page.
    pub label: String,
}

/// Why a session with the device ended.
enum End {
    /// Asked to stop.
    Stopped,
    /// The device went away or stopped answering: try again.
    Lost(String),
    /// Trying again will not help (another configuration on the device).
    Fatal(String),
}

/// Runs until `stop()`; returns an error only for what reconnecting
/// cannot cure.
pub fn run(source: &DeviceSource, hub: &Arc<Hub>, stop: &dyn Fn() -> bool) -> anyhow::Result<()> {
    let _maker = source
        .sim_seed
        .map(|seed| PixelMaker::start(hub.clone(), source.config.camera, seed));
    sessions(source, hub, stop)
}

fn sessions(source: &DeviceSource, hub: &Hub, stop: &dyn Fn() -> bool) -> anyhow::Result<()> {
    let mut gone_since: Option<Instant> = None;
    loop {
        match session(source, hub, stop, gone_since.is_some()) {
            End::Stopped => return Ok(()),
            End::Fatal(text) => {
                hub.set_message(Some(text.clone()));
                anyhow::bail!(text);
            }
            End::Lost(why) => {
                let first = gone_since.is_none();
                let since = *gone_since.get_or_insert_with(Instant::now);
                let text = format!(
                    "the device at {} is gone or not answering ({why}); reconnecting every second (for {:.0} s now)",
                    source.port,
                    since.elapsed().as_secs_f64()
                );
                if first {
                    eprintln!("brightpix: view: {text}");
                }
                hub.set_message(Some(text));
            }
        }
        let until = Instant::now() + Duration::from_secs(1);
        while Instant::now() < until {
            if stop() {
                return Ok(());
            }
            thread::sleep(Duration::from_millis(50));
        }
    }
}

fn session(source: &DeviceSource, hub: &Hub, stop: &dyn Fn() -> bool, again: bool) -> End {
    if stop() {
        return End::Stopped;
    }
    let mut client = match Client::open(&source.port) {
        Ok(c) => c,
        Err(e) => return End::Lost(e.to_string()),
    };
    let view = source.config.view();
    if source.configure {
        if let Err(e) = client.configure(&view) {
            return lost_or_fatal(e);
        }
    } else {
        let expected = config_digest(&view);
        match client.status() {
            Ok(s) if s.config_digest == Some(expected) => client.assume_configured(&view),
            Ok(s) => {
                return End::Fatal(format!(
                    "the device at {} runs configuration digest {}, not {} ({expected:#010x}): drop --no-configure to upload it",
                    source.port,
                    s.config_digest.map_or("none".into(), |d| format!("{d:#010x}")),
                    source.config_name
                ))
            }
            Err(e) => return lost_or_fatal(e),
        }
    }
    let mut setup = Setup::new(
        source.label.clone(),
        source.config_name.clone(),
        source.config.clone(),
    );
    setup.pixels = source.sim_seed.is_some();
    hub.set_setup(setup);
    hub.set_message(None);
    if again {
        eprintln!("brightpix: view: the device at {} is back", source.port);
    }
    let n = source.config.windows.len();
    loop {
        if stop() {
            return End::Stopped;
        }
        match client.status() {
            Ok(s) => hub.set_health(Health::from_status(&s)),
            Err(e) => return lost_or_fatal(e),
        }
        let captured = client.capture_with(source.chunk, &mut |o| {
            super::offer_outcome(hub, o, n, None);
        });
        match captured {
            Ok(_) => {}
            Err(i) => match i.error {
                LinkError::Device {
                    error: DeviceError::NoCamera,
                    ..
                } => return status_only(source, &mut client, hub, stop),
                e => return lost_or_fatal(e),
            },
        }
    }
}

/// A device without a camera of its own: its status only, and why.
fn status_only(
    source: &DeviceSource,
    client: &mut Client,
    hub: &Hub,
    stop: &dyn Fn() -> bool,
) -> End {
    hub.set_message(Some(format!(
        "the device at {} has no camera of its own: only its health is shown; send it frames with `brightpix stream --view` to see slopes",
        source.port
    )));
    while !stop() {
        match client.status() {
            Ok(s) => hub.set_health(Health::from_status(&s)),
            Err(e) => return lost_or_fatal(e),
        }
        thread::sleep(Duration::from_millis(250));
    }
    End::Stopped
}

fn lost_or_fatal(e: LinkError) -> End {
    match e {
        LinkError::Interrupted => End::Stopped,
        LinkError::Version(_) => End::Fatal(e.to_string()),
        LinkError::Device { .. } => End::Fatal(e.to_string()),
        e => End::Lost(e.to_string()),
    }
}

/// Remakes a simulated camera's frame of the latest results sample, a few
/// times a second, on a thread of its own (off the data path), for
/// sources whose pixels are not on the link. Stops when dropped.
pub struct PixelMaker {
    running: Arc<AtomicBool>,
    thread: Option<thread::JoinHandle<()>>,
}

impl PixelMaker {
    pub fn start(hub: Arc<Hub>, camera: brightpix_protocol::Camera, seed: u64) -> PixelMaker {
        let running = Arc::new(AtomicBool::new(true));
        let flag = running.clone();
        let thread = thread::Builder::new()
            .name("brightpix-view-pixels".into())
            .spawn(move || {
                let frames = CameraFrames::new(camera, seed);
                let mut last = None;
                while flag.load(Ordering::Relaxed) {
                    if let Some(frame) = hub.latest_frame().filter(|f| Some(*f) != last) {
                        if let Some(pixels) = frames.frames(frame, 1).pop() {
                            hub.offer_pixels(frame, pixels);
                        }
                        last = Some(frame);
                    }
                    thread::sleep(Duration::from_millis(200));
                }
            })
            .ok();
        PixelMaker { running, thread }
    }
}

impl Drop for PixelMaker {
    fn drop(&mut self) {
        self.running.store(false, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim_device::{
        CameraOptions, CameraSpec, InProcessDevice, InProcessOptions, SimLinkKind,
    };
    use crate::view::hub::Seen;

    fn device(socket: &std::path::Path) -> InProcessDevice {
        InProcessDevice::start(InProcessOptions {
            link: SimLinkKind::Unix(socket.to_path_buf()),
            camera: Some(CameraOptions::own(CameraSpec { seed: 3 }, 200)),
            ..InProcessOptions::default()
        })
        .unwrap()
    }

    fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
        let deadline = Instant::now() + Duration::from_secs(60);
        while !done() {
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            thread::sleep(Duration::from_millis(20));
        }
    }

    /// The device disappears: the hub says so; it comes back on the same
    /// port: the view reconnects, reconfigures and frames flow again.
    #[test]
    fn reconnects_when_the_device_comes_back() {
        let dir = crate::sim_device::temp_dir("brightpix-view-test").unwrap();
        let socket = dir.join("uart.sock");
        let first = device(&socket);
        let hub = Hub::new();
        let source = DeviceSource {
            port: first.port().to_string(),
            config: crate::sil::canary_config(),
            config_name: "canary".into(),
            configure: true,
            chunk: 20,
            sim_seed: Some(3),
            label: "test".into(),
        };
        let stop = Arc::new(AtomicBool::new(false));
        let runner = {
            let (hub, stop) = (hub.clone(), stop.clone());
            thread::spawn(move || run(&source, &hub, &|| stop.load(Ordering::Relaxed)))
        };
        wait_for("frames", || hub.frames_seen() >= 30);
        let mut seen = Seen::default();
        wait_for("pixels", || hub.pixels_if_newer(&mut seen).is_some());
        drop(first);
        let mut message = None;
        wait_for("the message that the device is gone", || {
            if let Some(m) = hub.message_if_newer(&mut seen) {
                message = m;
            }
            message.as_deref().is_some_and(|m| m.contains("is gone"))
        });
        let before = hub.frames_seen();
        let _second = device(&socket);
        wait_for("the message to clear", || {
            if let Some(m) = hub.message_if_newer(&mut seen) {
                message = m;
            }
            message.is_none()
        });
        wait_for("frames again", || hub.frames_seen() >= before + 20);
        stop.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
        let _ = std::fs::remove_dir_all(dir);
    }
}
