//! One simulated camera seen by several simulated boards (a rig on one
//! camera's fanned-out bus): one timeline of frames and one sync line.
//!
//! - The camera runs freely from its creation: frame `k` starts at
//!   `t0 + k / fps` and is the same pixels for every board (the simulator's
//!   frame `k` of the seed, [`CameraFrames`](super::CameraFrames)). A board
//!   begins with whatever frame starts next when its own start happens, so
//!   boards started at different moments begin on different camera frames,
//!   as real boards do.
//! - [`SharedCamera::with_start_delays`] is the test knob for that: board
//!   `b`'s start happens `delays[b]` frame periods after its request
//!   reached its camera (USB latency, the host's scheduling).
//! - The sync line ([`SharedCamera::with_sync_line`]): a follower arms
//!   ([`SharedCamera::arm`]) and waits for the next rising edge
//!   ([`SharedCamera::wait_edge`]); the leader waits for a frame start `j`
//!   and raises the line ([`SharedCamera::drive`]); every armed board and
//!   the leader begin with frame `j + 1`. A board armed after the edge
//!   never sees it. The line goes low when the leader's capture ends
//!   ([`SharedCamera::lower`]).
//!
//! The in-process boards' camera threads and the QEMU boards' frame
//! servers (`camera.rs`) play their boards' DMA and sync glue on it.

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use super::camera::{CameraOptions, CameraSpec};

/// See the module docs.
#[derive(Debug)]
pub struct SharedCamera {
    spec: CameraSpec,
    fps: u32,
    t0: Instant,
    sync_line: bool,
    delays: Vec<u32>,
    line: Mutex<Line>,
    changed: Condvar,
}

#[derive(Debug, Default)]
struct Line {
    /// Rising edges so far.
    edges: u64,
    /// The frame the last edge followed the start of.
    edge_frame: u64,
    high: bool,
}

/// A follower's arming: the edges it has already missed.
#[derive(Clone, Copy, Debug)]
pub struct Armed {
    edges: u64,
}

/// How often a wait looks at its `quit` condition.
const POLL: Duration = Duration::from_millis(20);

impl SharedCamera {
    /// A camera of `spec` at `fps` frames a second (at least 1), frame 0
    /// starting now; no sync line, no start delays.
    pub fn new(spec: CameraSpec, fps: u32) -> SharedCamera {
        SharedCamera {
            spec,
            fps: fps.max(1),
            t0: Instant::now(),
            sync_line: false,
            delays: Vec::new(),
            line: Mutex::new(Line::default()),
            changed: Condvar::new(),
        }
    }

    /// With a sync line wired to every board.
    pub fn with_sync_line(mut self) -> SharedCamera {
        self.sync_line = true;
        self
    }

    /// Board `b`'s start happens `delays[b]` frame periods late (boards
    /// past the list: none).
    pub fn with_start_delays(mut self, delays: Vec<u32>) -> SharedCamera {
        self.delays = delays;
        self
    }

    pub fn spec(&self) -> CameraSpec {
        self.spec
    }

    pub fn fps(&self) -> u32 {
        self.fps
    }

    pub fn has_sync_line(&self) -> bool {
        self.sync_line
    }

    /// Board `board`'s camera options: this camera, seen by that board.
    pub fn board(self: &Arc<Self>, board: usize) -> CameraOptions {
        CameraOptions {
            spec: self.spec,
            fps: self.fps,
            shared: Some((self.clone(), board)),
        }
    }

    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / f64::from(self.fps))
    }

    /// When frame `k` starts.
    pub fn frame_start(&self, k: u64) -> Instant {
        self.t0 + self.period().mul_f64(k as f64)
    }

    /// The frame that starts next after `now`.
    pub fn next_frame_after(&self, now: Instant) -> u64 {
        let elapsed = now.saturating_duration_since(self.t0).as_secs_f64();
        (elapsed * f64::from(self.fps)).floor() as u64 + 1
    }

    /// Board `board`'s start delay (the test knob).
    pub fn start_delay(&self, board: usize) -> Duration {
        self.period()
            .mul_f64(f64::from(self.delays.get(board).copied().unwrap_or(0)))
    }

    /// Arms a follower: from now on it sees the next rising edge.
    pub fn arm(&self) -> Armed {
        Armed {
            edges: self.lock().edges,
        }
    }

    /// Waits for the first rising edge after `armed`, while `quit` is
    /// false: the frame it followed the start of (the board begins with the
    /// next one).
    pub fn wait_edge(&self, armed: Armed, quit: &dyn Fn() -> bool) -> Option<u64> {
        let mut line = self.lock();
        loop {
            if line.edges > armed.edges {
                return Some(line.edge_frame);
            }
            if quit() {
                return None;
            }
            line = match self.changed.wait_timeout(line, POLL) {
                Ok((guard, _)) => guard,
                Err(poisoned) => poisoned.into_inner().0,
            };
        }
    }

    /// The leader: waits for the next frame start `j`, raises the line and
    /// returns `j` (`None` if `quit` first).
    pub fn drive(&self, quit: &dyn Fn() -> bool) -> Option<u64> {
        let j = self.next_frame_after(Instant::now());
        if !sleep_until(self.frame_start(j), quit) {
            return None;
        }
        let mut line = self.lock();
        line.edges += 1;
        line.edge_frame = j;
        line.high = true;
        drop(line);
        self.changed.notify_all();
        Some(j)
    }

    /// The leader's capture ended: the line goes low.
    pub fn lower(&self) {
        self.lock().high = false;
    }

    /// Whether the line is high now.
    pub fn line_high(&self) -> bool {
        self.lock().high
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Line> {
        self.line.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Sleeps until `at` unless `quit` first (looked at every 20 ms); true
/// if `at` came.
pub fn sleep_until(at: Instant, quit: &dyn Fn() -> bool) -> bool {
    loop {
        if quit() {
            return false;
        }
        let now = Instant::now();
        if now >= at {
            return true;
        }
        std::thread::sleep((at - now).min(POLL));
    }
}

/// Where a board's capture begins on a camera's timeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Begin {
    /// The camera frame its frame 0 is.
    pub camera_frame: u64,
    /// It began on a sync edge.
    pub synced: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(fps: u32) -> SharedCamera {
        SharedCamera::new(CameraSpec { seed: 1 }, fps)
    }

    #[test]
    fn frames_follow_the_clock_from_creation() {
        let c = camera(100);
        assert_eq!(c.next_frame_after(c.t0), 1);
        assert_eq!(c.next_frame_after(c.t0 + Duration::from_millis(15)), 2);
        assert_eq!(c.frame_start(3) - c.t0, Duration::from_millis(30));
        let c = c.with_start_delays(vec![0, 2]);
        assert_eq!(c.start_delay(1), Duration::from_millis(20));
        assert_eq!(c.start_delay(5), Duration::ZERO);
    }

    /// A follower armed before the edge sees it; one armed after does not.
    #[test]
    fn only_boards_armed_before_the_edge_see_it() {
        let c = Arc::new(camera(200).with_sync_line());
        let early = c.arm();
        let leader = {
            let c = c.clone();
            std::thread::spawn(move || c.drive(&|| false))
        };
        let j = leader.join().unwrap().unwrap();
        assert!(c.line_high());
        assert_eq!(c.wait_edge(early, &|| false), Some(j));
        let late = c.arm();
        let waited = Instant::now();
        assert_eq!(
            c.wait_edge(late, &|| waited.elapsed() > Duration::from_millis(60)),
            None
        );
        c.lower();
        assert!(!c.line_high());
    }
}
