//! The link test (PROTOCOL.md §15): the device sends fill bytes as fast as
//! its link takes them; the client checks that they arrive intact and in
//! order and times their arrival. A board's results leave on that link, so
//! its rate is what `rig plan --link-rate` takes.

use std::time::{Duration, Instant};

use brightpix_protocol::wire::{link_fill, Ack, HostMessage, MessageKind, MAX_LINK_FILL};

use super::errors::unexpected;
use super::requests::Reply;
use super::{Client, LinkError};

/// Below this span between the first and the last arrival the rate is not
/// given: the fill arrived in a read or two, too quickly to time.
const MIN_SPAN: Duration = Duration::from_millis(50);

/// What a link test measured.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkTestReport {
    /// Fill bytes asked for and received (equal, or the test failed).
    pub bytes: u32,
    /// Fill bytes a message.
    pub chunk: u16,
    /// `LinkFill` messages received.
    pub messages: u32,
    /// Bytes on the link of those messages: every frame, its COBS, CRC and
    /// delimiter included (what a board's results take, PROTOCOL.md §2).
    pub link_bytes: u64,
    /// From the first read that brought fill to the last.
    pub span: Duration,
    /// Link bytes per second after the first read (what the link carried
    /// while the device kept it busy); `None` below 50 ms of arrivals.
    pub link_bytes_per_s: Option<f64>,
    /// Fill bytes per second, likewise.
    pub fill_bytes_per_s: Option<f64>,
}

/// The fill as it arrives (kept by the transport while a test runs).
#[derive(Debug, Default)]
pub(super) struct Tally {
    messages: u32,
    /// The next offset expected, and fill bytes received.
    next: u32,
    link_bytes: u64,
    /// When the first read brought fill, and what it brought.
    first: Option<(Instant, u64, u64)>,
    last: Option<Instant>,
    /// The first message that was out of order or not the fill.
    fault: Option<String>,
}

impl Tally {
    /// A `LinkFill` of `fill` at `offset`, `frame_bytes` on the link, read
    /// at `at`.
    pub(super) fn arrived(&mut self, offset: u32, fill: &[u8], frame_bytes: usize, at: Instant) {
        if self.fault.is_none() {
            if offset != self.next {
                self.fault = Some(format!(
                    "fill message {} began at byte {offset}, not {}: bytes lost or repeated",
                    self.messages + 1,
                    self.next
                ));
            } else if fill.len() > usize::from(MAX_LINK_FILL)
                || fill != link_fill(offset, fill.len())
            {
                self.fault = Some(format!(
                    "fill message {} (bytes {offset} ..) is not the fill the protocol defines",
                    self.messages + 1
                ));
            }
        }
        self.messages += 1;
        self.next = offset.wrapping_add(fill.len() as u32);
        self.link_bytes += frame_bytes as u64;
        match &mut self.first {
            Some((t, link, fill_bytes)) if *t == at => {
                *link += frame_bytes as u64;
                *fill_bytes += fill.len() as u64;
            }
            Some(_) => {}
            None => self.first = Some((at, frame_bytes as u64, fill.len() as u64)),
        }
        self.last = Some(at);
    }
}

impl Client {
    /// `LinkTest { bytes, chunk }` (PROTOCOL.md §15): `bytes` fill bytes
    /// from the device, `chunk` a message, checked and timed. The wait
    /// ends after the client's timeout of silence, not of the whole test;
    /// replies that answer no link test (a late answer to an earlier
    /// `Hello` on QEMU's pty) are not its reply (`request_raw`).
    pub fn link_test(&mut self, bytes: u32, chunk: u16) -> Result<LinkTestReport, LinkError> {
        let frame = self
            .encode(&HostMessage::LinkTest { bytes, chunk })?
            .to_vec();
        self.link_fills = Some(Tally::default());
        let reply = self.request_raw(&frame, MessageKind::LinkTest);
        let tally = self.link_fills.take().unwrap_or_default();
        let done = match reply? {
            Reply::Ack(Ack::LinkTestDone { bytes, messages }) => (bytes, messages),
            other => return Err(unexpected("LinkTest", &other)),
        };
        let broken = |what: String| LinkError::Usage(format!("link test: {what}"));
        if let Some(fault) = tally.fault {
            return Err(broken(fault));
        }
        if done != (bytes, tally.messages) || tally.next != bytes {
            return Err(broken(format!(
                "the device sent {} bytes in {} messages, {} bytes in {} messages arrived",
                done.0, done.1, tally.next, tally.messages
            )));
        }
        let (first, first_link, first_fill) = tally.first.unwrap_or((Instant::now(), 0, 0));
        let span = tally
            .last
            .map_or(Duration::ZERO, |t| t.duration_since(first));
        let rate =
            |after_first: u64| (span >= MIN_SPAN).then(|| after_first as f64 / span.as_secs_f64());
        Ok(LinkTestReport {
            bytes,
            chunk,
            messages: tally.messages,
            link_bytes: tally.link_bytes,
            span,
            link_bytes_per_s: rate(tally.link_bytes - first_link),
            fill_bytes_per_s: rate(u64::from(bytes) - first_fill),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tally_names_the_first_message_out_of_place() {
        let at = Instant::now();
        let mut t = Tally::default();
        t.arrived(0, link_fill(0, 10), 20, at);
        t.arrived(10, link_fill(10, 10), 20, at + Duration::from_millis(1));
        assert!(t.fault.is_none());
        assert_eq!((t.messages, t.next, t.link_bytes), (2, 20, 40));
        assert_eq!(t.first, Some((at, 20, 10)));
        // A message lost: the next one begins later than expected.
        t.arrived(30, link_fill(30, 10), 20, at);
        assert!(t
            .fault
            .as_deref()
            .unwrap()
            .contains("began at byte 30, not 20"));
        // Bytes changed on the way.
        let mut t = Tally::default();
        let mut wrong = link_fill(0, 10).to_vec();
        wrong[3] ^= 1;
        t.arrived(0, &wrong, 20, at);
        assert!(t.fault.as_deref().unwrap().contains("not the fill"));
    }
}
