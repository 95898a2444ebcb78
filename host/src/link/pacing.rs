//! How long a slow link may keep the device silent: the wait for a frame's
//! results allows for the pixel bytes still in flight at the rate the link
//! has shown, so that only a silent device times out.
//!
//! A device sends nothing while the bytes of a frame's first results are
//! still on their way: over a UART at 115200 baud (or QEMU's, ~8 KB/s), a
//! camera whose first complete window is at the bottom (12 KB of pixels)
//! is seconds of silence with everything working. The operating system
//! cannot tell the host how much of what it wrote has left (TIOCOUTQ on a
//! pseudo-terminal always reads 0), so the client measures what the device
//! has consumed: a frame's bytes are consumed when its outcome arrives.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The slowest link assumed before a rate is measured (a 9600-baud UART
/// carries about 960 bytes/s): the first frames of a stream get this much
/// time for their bytes.
pub const FLOOR_BYTES_PER_SECOND: f64 = 900.0;

/// Measurements shorter than this are not a rate (outcomes that arrived
/// together).
const MIN_SPAN: Duration = Duration::from_millis(200);

#[derive(Debug, Default)]
pub(super) struct Pacing {
    /// Pixel bytes written since the client started.
    sent: u64,
    /// Where each frame in flight ends in `sent`.
    ends: VecDeque<(u32, u64)>,
    /// Bytes of frames whose outcome has arrived.
    consumed: u64,
    /// The first and latest (time, consumed) after an outcome.
    first: Option<(Instant, u64)>,
    last: Option<(Instant, u64)>,
}

impl Pacing {
    /// A new stream: whatever an earlier one left in flight is not waited for.
    pub fn restart(&mut self) {
        self.ends.clear();
        self.consumed = self.sent;
        self.first = None;
        self.last = None;
    }

    pub fn sent(&mut self, frame: u32, bytes: usize) {
        self.sent += bytes as u64;
        self.ends.push_back((frame, self.sent));
    }

    /// Frame `frame`'s outcome arrived: its bytes, and those before, are consumed.
    pub fn finished(&mut self, frame: u32) {
        let Some(k) = self.ends.iter().position(|&(f, _)| f == frame) else {
            return;
        };
        let end = self.ends[k].1;
        self.ends.drain(..=k);
        self.consumed = self.consumed.max(end);
        let now = (Instant::now(), self.consumed);
        self.first.get_or_insert(now);
        self.last = Some(now);
    }

    /// Bytes per second the device has consumed, once measurable.
    pub fn rate(&self) -> Option<f64> {
        let ((t0, b0), (t1, b1)) = (self.first?, self.last?);
        let span = t1.duration_since(t0);
        (span >= MIN_SPAN && b1 > b0).then(|| (b1 - b0) as f64 / span.as_secs_f64())
    }

    /// Time the bytes in flight may take: at half the measured rate (a
    /// margin for a link that slows down), never slower than the floor.
    pub fn allowance(&self) -> Duration {
        let in_flight = self.sent.saturating_sub(self.consumed) as f64;
        let rate = self.rate().map_or(FLOOR_BYTES_PER_SECOND, |r| {
            (r / 2.0).max(FLOOR_BYTES_PER_SECOND)
        });
        Duration::from_secs_f64((in_flight / rate).min(3600.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_in_flight_get_time_at_the_floor_until_a_rate_is_known() {
        let mut p = Pacing::default();
        p.sent(0, 9_000);
        p.sent(1, 9_000);
        assert_eq!(p.allowance(), Duration::from_secs(20));
        p.finished(0);
        assert_eq!(p.allowance(), Duration::from_secs(10));
        p.finished(1);
        assert_eq!(p.allowance(), Duration::ZERO);
        // A stale frame's outcome changes nothing.
        p.finished(7);
        p.sent(2, 900);
        p.restart();
        assert_eq!(p.allowance(), Duration::ZERO);
    }
}
