//! The view's server: std::net, a small HTTP handler for the page's three
//! built-in assets, and a WebSocket (`tungstenite`) per open page that
//! sends what is new in the [`Hub`] at the display rate.
//!
//! Each connection has its own thread, which only reads the hub's slots:
//! a slow or stuck page slows nothing but itself (its socket's writes time
//! out and it is closed). Nothing the page sends is acted on (the view is
//! read-only); only its Close is heeded.

use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use tungstenite::{Message, WebSocket};

use super::encode::{self, Totals};
use super::hub::{Hub, PixelSample, Seen, Setup};
use super::page;
use crate::reference::Reference;

/// How often a connection looks at the hub: 50 Hz, so that a 60 Hz data
/// path shows at >= 25 Hz whatever the phase.
const TICK: Duration = Duration::from_millis(20);
/// Pages served at once (each has a thread); more are answered 503.
const MAX_CONNECTIONS: usize = 16;
/// Pixel messages are limited to about this many bytes a second (a
/// 1280x1280 camera is 4.9 MB a frame): the rest are skipped.
const PIXEL_BYTES_PER_S: f64 = 40e6;

/// The running server; stops (and closes its pages) when dropped.
pub struct Server {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Server {
    /// Serves `hub` on `listener` (see [`super::address::bind`]).
    pub fn start(listener: TcpListener, hub: Arc<Hub>) -> io::Result<Server> {
        let addr = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = thread::Builder::new()
            .name("brightpix-view".into())
            .spawn(move || accept_loop(&listener, &hub, &flag))?;
        Ok(Server {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn accept_loop(listener: &TcpListener, hub: &Arc<Hub>, stop: &Arc<AtomicBool>) {
    let open = Arc::new(AtomicUsize::new(0));
    let mut handlers: Vec<JoinHandle<()>> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        handlers.retain(|h| !h.is_finished());
        match listener.accept() {
            Ok((stream, _)) => {
                if open.load(Ordering::Relaxed) >= MAX_CONNECTIONS {
                    let _ = respond(
                        &stream,
                        "503 Service Unavailable",
                        "text/plain",
                        b"too many pages open on this view\n",
                    );
                    continue;
                }
                open.fetch_add(1, Ordering::Relaxed);
                let (hub, stop, count) = (hub.clone(), stop.clone(), open.clone());
                let spawned = thread::Builder::new()
                    .name("brightpix-view-page".into())
                    .spawn(move || {
                        let _ = handle(stream, &hub, &stop);
                        count.fetch_sub(1, Ordering::Relaxed);
                    });
                match spawned {
                    Ok(h) => handlers.push(h),
                    Err(_) => {
                        open.fetch_sub(1, Ordering::Relaxed);
                    }
                }
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => thread::sleep(TICK),
            Err(_) => thread::sleep(TICK),
        }
    }
    for h in handlers {
        let _ = h.join();
    }
}

/// The request line's method and path, once the head has arrived (peeked,
/// not consumed: a WebSocket handshake reads it again).
fn peek_request(stream: &TcpStream) -> io::Result<(String, String, usize)> {
    let mut buf = [0u8; 8192];
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let n = stream.peek(&mut buf)?;
        if n == 0 {
            return Err(io::ErrorKind::UnexpectedEof.into());
        }
        if let Some(end) = buf[..n].windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&buf[..end]);
            let mut words = head.lines().next().unwrap_or("").split_whitespace();
            let method = words.next().unwrap_or("").to_string();
            let path = words.next().unwrap_or("").to_string();
            return Ok((method, path, end + 4));
        }
        if n == buf.len() || Instant::now() > deadline {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "request head too long or too slow",
            ));
        }
        thread::sleep(Duration::from_millis(5));
    }
}

fn handle(mut stream: TcpStream, hub: &Hub, stop: &AtomicBool) -> io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    stream.set_write_timeout(Some(Duration::from_secs(5)))?;
    stream.set_nodelay(true)?;
    let (method, path, head) = peek_request(&stream)?;
    let path = path.split('?').next().unwrap_or("").to_string();
    if path == "/ws" {
        let ws = tungstenite::accept(stream).map_err(|e| io::Error::other(e.to_string()))?;
        return serve_page(ws, hub, stop);
    }
    // The head is consumed; a GET has no body.
    let mut head_bytes = vec![0u8; head];
    stream.read_exact(&mut head_bytes)?;
    if method != "GET" && method != "HEAD" {
        return respond(
            &stream,
            "405 Method Not Allowed",
            "text/plain",
            b"the view is read-only: GET only\n",
        );
    }
    if path == "/favicon.ico" {
        return respond(&stream, "204 No Content", "text/plain", b"");
    }
    match page::asset(&path) {
        Some((kind, body)) => {
            let body = if method == "HEAD" { &[][..] } else { body };
            respond(&stream, "200 OK", kind, body)
        }
        None => respond(&stream, "404 Not Found", "text/plain", b"not found\n"),
    }
}

fn respond(mut stream: &TcpStream, status: &str, kind: &str, body: &[u8]) -> io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes())?;
    stream.write_all(body)?;
    stream.flush()
}

/// Frames per second from the host's frame count, over windows of about a
/// second.
struct RateMeter {
    since: Instant,
    frames: u64,
    rate: f64,
}

impl RateMeter {
    fn new(frames: u64) -> RateMeter {
        RateMeter {
            since: Instant::now(),
            frames,
            rate: 0.0,
        }
    }

    fn update(&mut self, frames: u64) -> f64 {
        let dt = self.since.elapsed().as_secs_f64();
        if dt >= 0.5 {
            self.rate = frames.saturating_sub(self.frames) as f64 / dt;
            self.since = Instant::now();
            self.frames = frames;
        }
        self.rate
    }
}

/// One open page: everything new in the hub, at most every [`TICK`].
fn serve_page(mut ws: WebSocket<TcpStream>, hub: &Hub, stop: &AtomicBool) -> io::Result<()> {
    // Short reads: the loop only polls for the page's Close.
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_millis(1)))?;
    let mut seen = Seen::default();
    let mut setup: Option<Arc<Setup>> = None;
    let mut encoder = PixelEncoder::start()?;
    let mut meter = RateMeter::new(hub.frames_seen());
    let mut next_pixels = Instant::now();
    let result = (|| -> Result<(), tungstenite::Error> {
        send(&mut ws, Message::text(encode::waiting_message()))?;
        while !stop.load(Ordering::Relaxed) {
            let tick = Instant::now();
            match ws.read() {
                Ok(Message::Close(_)) => return Ok(()),
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(e),
            }
            if let Some(new) = hub.setup_if_newer(&mut seen) {
                match new {
                    Some(s) => {
                        send(&mut ws, Message::text(encode::setup_message(&s)))?;
                        setup = Some(s);
                    }
                    None => send(&mut ws, Message::text(encode::waiting_message()))?,
                }
            }
            if let Some(text) = hub.message_if_newer(&mut seen) {
                send(
                    &mut ws,
                    Message::text(encode::message_message(text.as_deref())),
                )?;
            }
            if let Some(h) = hub.health_if_newer(&mut seen) {
                send(&mut ws, Message::text(encode::health_message(&h)))?;
            }
            let rate = meter.update(hub.frames_seen());
            if let Some(s) = &setup {
                if let Some(sample) = hub.results_if_newer(&mut seen) {
                    let totals = Totals {
                        frames_seen: hub.frames_seen(),
                        frames_dropped: hub.frames_dropped(),
                        frames_per_second: rate,
                    };
                    let n = s.windows().len();
                    send(
                        &mut ws,
                        Message::binary(encode::results_message(&sample, n, totals)),
                    )?;
                }
                if let Some((made_for, m)) = encoder.finished() {
                    // Not the pixels of a geometry the page no longer has.
                    if Arc::ptr_eq(&made_for, s) && !m.is_empty() {
                        next_pixels = Instant::now()
                            + Duration::from_secs_f64(m.len() as f64 / PIXEL_BYTES_PER_S);
                        send(&mut ws, Message::binary(m))?;
                    }
                }
                if encoder.idle() && Instant::now() >= next_pixels {
                    if let Some(p) = hub.pixels_if_newer(&mut seen) {
                        encoder.submit(s.clone(), p);
                    }
                }
            }
            if let Some(rest) = TICK.checked_sub(tick.elapsed()) {
                thread::sleep(rest);
            }
        }
        let _ = ws.close(None);
        let _ = ws.flush();
        Ok(())
    })();
    match result {
        Ok(()) | Err(tungstenite::Error::ConnectionClosed) => Ok(()),
        Err(e) => Err(io::Error::other(e.to_string())),
    }
}

/// Builds pixel messages on a thread of its own: each window's selection
/// by the reference is the costly part (tens of milliseconds for a
/// 1280x1280 camera), and results keep flowing meanwhile. One job at a
/// time; pixels sampled meanwhile wait in the hub, where the latest wins.
struct PixelEncoder {
    jobs: Option<mpsc::SyncSender<(Arc<Setup>, Arc<PixelSample>)>>,
    done: mpsc::Receiver<(Arc<Setup>, Vec<u8>)>,
    busy: bool,
    thread: Option<JoinHandle<()>>,
}

impl PixelEncoder {
    fn start() -> io::Result<PixelEncoder> {
        let (jobs, inbox) = mpsc::sync_channel::<(Arc<Setup>, Arc<PixelSample>)>(1);
        let (outbox, done) = mpsc::channel();
        let thread = thread::Builder::new()
            .name("brightpix-view-pixels".into())
            .spawn(move || {
                let mut reference: Option<(Arc<Setup>, Reference)> = None;
                for (setup, sample) in inbox {
                    if !reference
                        .as_ref()
                        .is_some_and(|(s, _)| Arc::ptr_eq(s, &setup))
                    {
                        reference = Reference::new(&setup.config.view())
                            .ok()
                            .map(|r| (setup.clone(), r));
                    }
                    let message = reference
                        .as_ref()
                        .and_then(|(_, r)| encode::pixels_message(r, &setup, &sample))
                        .unwrap_or_default();
                    if outbox.send((setup, message)).is_err() {
                        return;
                    }
                }
            })?;
        Ok(PixelEncoder {
            jobs: Some(jobs),
            done,
            busy: false,
            thread: Some(thread),
        })
    }

    fn idle(&self) -> bool {
        !self.busy
    }

    fn submit(&mut self, setup: Arc<Setup>, sample: Arc<PixelSample>) {
        if let Some(jobs) = &self.jobs {
            self.busy = jobs.try_send((setup, sample)).is_ok();
        }
    }

    /// A message built (empty if the frame did not fit the geometry).
    fn finished(&mut self) -> Option<(Arc<Setup>, Vec<u8>)> {
        let m = self.done.try_recv().ok()?;
        self.busy = false;
        Some(m)
    }
}

impl Drop for PixelEncoder {
    fn drop(&mut self) {
        // Closing the queue ends the thread after its current job.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn send(ws: &mut WebSocket<TcpStream>, message: Message) -> Result<(), tungstenite::Error> {
    ws.send(message)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::view::address;
    use crate::view::hub::Setup;
    use brightpix_protocol::wire::SlopeEntry;

    fn get(addr: SocketAddr, path: &str) -> String {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        out
    }

    #[test]
    fn serves_the_page_and_refuses_what_it_has_not() {
        let hub = Hub::new();
        let server = Server::start(
            address::bind("127.0.0.1:0".parse().unwrap(), false).unwrap(),
            hub,
        )
        .unwrap();
        let page = get(server.addr(), "/");
        assert!(page.starts_with("HTTP/1.1 200 OK"), "{page}");
        assert!(page.contains("<canvas"), "the page is built in");
        assert!(get(server.addr(), "/view.js").contains("WebSocket"));
        assert!(get(server.addr(), "/../etc/passwd").starts_with("HTTP/1.1 404"));
        let mut s = TcpStream::connect(server.addr()).unwrap();
        write!(s, "POST / HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        assert!(out.starts_with("HTTP/1.1 405"), "{out}");
    }

    #[test]
    fn a_page_receives_setup_health_results_and_pixels() {
        let hub = Hub::new();
        let server = Server::start(
            address::bind("127.0.0.1:0".parse().unwrap(), false).unwrap(),
            hub.clone(),
        )
        .unwrap();
        let (mut ws, _) = tungstenite::connect(format!("ws://{}/ws", server.addr())).unwrap();
        hub.set_setup(Setup::new(
            "test".into(),
            "canary".into(),
            crate::sil::canary_config(),
        ));
        hub.set_health(Default::default());
        let entry = SlopeEntry {
            index: 0,
            slope_x: 0,
            slope_y: 0,
            flux: 16,
            valid: true,
        };
        let frame = vec![60u16; 112 * 112];
        hub.offer(3, false, || vec![Some(entry)], Some(&frame));
        let mut kinds = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(5);
        let done =
            |k: &[String]| k.iter().any(|x| x == "results") && k.iter().any(|x| x == "pixels");
        while Instant::now() < deadline && !done(&kinds) {
            match ws.read().unwrap() {
                Message::Text(t) => {
                    let v: serde_json::Value = serde_json::from_str(t.as_str()).unwrap();
                    kinds.push(v["type"].as_str().unwrap().to_string());
                }
                Message::Binary(b) if b[0] == encode::KIND_RESULTS => {
                    assert_eq!(b.len(), 40 + 13 * 49);
                    assert_eq!(b[40 + 12 * 49], 2, "sub-aperture 0 valid");
                    kinds.push("results".into());
                }
                Message::Binary(b) => {
                    // Built on the connection's encoder thread.
                    assert_eq!(b[0], encode::KIND_PIXELS);
                    assert_eq!(b.len(), 24 + 3 * 112 * 112);
                    kinds.push("pixels".into());
                }
                _ => {}
            }
        }
        assert_eq!(kinds.first().map(String::as_str), Some("waiting"));
        for k in ["setup", "health", "results", "pixels"] {
            assert!(kinds.iter().any(|x| x == k), "{k} missing from {kinds:?}");
        }
        drop(server);
    }
}
