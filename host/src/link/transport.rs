//! Bytes on the link: messages encoded into frames, written in pieces with
//! a stall timeout (reading meanwhile, so neither side blocks the other),
//! and what arrives read, decoded and sorted into replies, frame results
//! and frame outcomes.

use std::io::{self, ErrorKind};
use std::time::{Duration, Instant};

use brightpix_protocol::wire::{
    decode, encode, hello_prefix, DeviceError, DeviceMessage, FrameFault, Hello, HostMessage,
    Received, SlopeEntry,
};

use super::{Client, DeviceInfo, FrameOutcome, FrameSlopes, LinkError, Reply};

/// A frame from the device, decoded and owned.
enum Incoming {
    Reply(Reply),
    /// A `HelloReply` of another protocol version (only its prefix decoded).
    ForeignHello(Hello),
    Slopes {
        frame: u32,
        results: Vec<SlopeEntry>,
    },
    FrameDone {
        frame: u32,
        count: u32,
    },
    FrameError {
        frame: u32,
        fault: FrameFault,
    },
    Began(super::frames::CaptureBegan),
    EdgeRows {
        frame: u32,
        first: u32,
        last: u32,
    },
    /// A link test's fill; `frame_bytes` on the link, delimiter included.
    LinkFill {
        offset: u32,
        fill: Vec<u8>,
        frame_bytes: usize,
    },
    Damaged,
}

impl Client {
    /// Encodes `message` as one frame (into the client's buffer).
    pub fn encode(&mut self, message: &HostMessage<'_>) -> Result<&[u8], LinkError> {
        match encode(message, &mut self.tx) {
            Ok(frame) => Ok(frame),
            Err(e) => Err(LinkError::Usage(format!(
                "cannot encode {:?}: {e}",
                message.kind()
            ))),
        }
    }

    /// Writes bytes to the link as they are, reading from it whenever the
    /// write would wait.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.write_raw(bytes, "raw bytes")
    }

    pub(super) fn write_raw(&mut self, bytes: &[u8], what: &str) -> Result<(), LinkError> {
        const PIECE: usize = 4096;
        for piece in bytes.chunks(PIECE) {
            self.set_timeout(self.options.timeout)?;
            let mut rest = piece;
            while !rest.is_empty() {
                match self.port.write(rest) {
                    Ok(0) => {
                        return Err(LinkError::Disconnected {
                            port: self.name.clone(),
                            source: io::Error::new(ErrorKind::WriteZero, "the port took no bytes"),
                        })
                    }
                    Ok(n) => rest = &rest[n..],
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {
                        return Err(LinkError::WriteStalled {
                            port: self.name.clone(),
                            timeout: self.options.timeout,
                            what: what.to_string(),
                        })
                    }
                    Err(source) => {
                        return Err(LinkError::Disconnected {
                            port: self.name.clone(),
                            source,
                        })
                    }
                }
            }
            if bytes.len() > PIECE {
                self.pump(Duration::ZERO)?;
            }
        }
        let _ = self.port.flush();
        Ok(())
    }

    pub(super) fn set_timeout(&mut self, t: Duration) -> Result<(), LinkError> {
        if self.io_timeout != Some(t) {
            self.port
                .set_io_timeout(t)
                .map_err(|source| LinkError::Disconnected {
                    port: self.name.clone(),
                    source,
                })?;
            self.io_timeout = Some(t);
        }
        Ok(())
    }

    /// Waits until `found` returns something; an error if the device sends
    /// nothing for the timeout.
    pub(super) fn wait<T>(
        &mut self,
        waiting: &str,
        found: impl FnMut(&mut Self) -> Option<T>,
    ) -> Result<T, LinkError> {
        self.wait_within(waiting, self.options.timeout, found)
    }

    /// [`wait`](Self::wait) with its own longest silence.
    pub(super) fn wait_within<T>(
        &mut self,
        waiting: &str,
        timeout: Duration,
        mut found: impl FnMut(&mut Self) -> Option<T>,
    ) -> Result<T, LinkError> {
        let mut last_byte = Instant::now();
        loop {
            if let Some(t) = found(self) {
                return Ok(t);
            }
            self.check_interrupt()?;
            let left = timeout.saturating_sub(last_byte.elapsed());
            if left.is_zero() {
                return Err(LinkError::Timeout {
                    port: self.name.clone(),
                    timeout,
                    waiting: waiting.to_string(),
                });
            }
            if self.pump(left.min(Duration::from_millis(200)))? > 0 {
                last_byte = Instant::now();
            }
        }
    }

    /// Reads what arrives within `wait` (one read) and decodes every whole
    /// frame; returns the bytes read.
    pub(super) fn pump(&mut self, wait: Duration) -> Result<usize, LinkError> {
        self.set_timeout(wait)?;
        let n = match self.port.read(&mut self.read_buf) {
            Ok(0) => {
                return Err(LinkError::Disconnected {
                    port: self.name.clone(),
                    source: io::Error::new(ErrorKind::UnexpectedEof, "end of stream"),
                })
            }
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                ) =>
            {
                return Ok(0)
            }
            Err(source) => {
                return Err(LinkError::Disconnected {
                    port: self.name.clone(),
                    source,
                })
            }
        };
        let mut incoming = Vec::new();
        let mut at = 0;
        while at < n {
            at += self.rx.push(&self.read_buf[at..n]);
            while let Some(received) = self.rx.next_frame() {
                incoming.push(match received {
                    Received::Frame(bytes) => decode_incoming(bytes),
                    Received::TooLong => Incoming::Damaged,
                });
            }
        }
        let now = Instant::now();
        for i in incoming {
            self.absorb(i, now);
        }
        Ok(n)
    }

    /// What arrived, read at `at`.
    fn absorb(&mut self, incoming: Incoming, at: Instant) {
        match incoming {
            Incoming::Reply(r) => self.replies.push_back(r),
            Incoming::ForeignHello(theirs) => {
                // Reported by the handshake as a version mismatch.
                self.replies.push_back(Reply::Hello(DeviceInfo {
                    version: theirs.version,
                    schema: theirs.schema,
                    ..self.info.clone()
                }))
            }
            Incoming::Slopes { frame, results } => {
                self.open_frames.entry(frame).or_default().extend(results)
            }
            Incoming::FrameDone { frame, count } => {
                self.pacing.finished(frame);
                let slopes = self.open_frames.remove(&frame).unwrap_or_default();
                self.finished.push_back(FrameOutcome::Done(FrameSlopes {
                    frame,
                    slopes,
                    done_count: Some(count),
                    edge_rows: self.edge_rows.remove(&frame),
                }));
            }
            Incoming::FrameError { frame, fault } => {
                self.pacing.finished(frame);
                let slopes = self.open_frames.remove(&frame).unwrap_or_default();
                self.finished.push_back(FrameOutcome::Dropped {
                    slopes: FrameSlopes {
                        frame,
                        slopes,
                        done_count: None,
                        edge_rows: self.edge_rows.remove(&frame),
                    },
                    fault,
                });
            }
            Incoming::Began(began) => self.capture_began = Some(began),
            Incoming::EdgeRows { frame, first, last } => {
                self.edge_rows.insert(frame, (first, last));
            }
            Incoming::LinkFill {
                offset,
                fill,
                frame_bytes,
            } => match &mut self.link_fills {
                Some(tally) => tally.arrived(offset, &fill, frame_bytes, at),
                // An earlier test's, abandoned: not a reply to anything.
                None => self.stale_outcomes += 1,
            },
            Incoming::Damaged => self.damaged_frames += 1,
        }
    }
}

fn decode_incoming(bytes: &mut [u8]) -> Incoming {
    let copy = bytes.to_vec();
    let frame_bytes = bytes.len() + 1;
    match decode::<DeviceMessage>(bytes) {
        Ok(DeviceMessage::HelloReply(h)) => Incoming::Reply(Reply::Hello(DeviceInfo::new(
            h.version,
            h.schema,
            h.session,
            &h.capabilities,
        ))),
        Ok(DeviceMessage::Ack(a)) => Incoming::Reply(Reply::Ack(a)),
        Ok(DeviceMessage::Error(DeviceError::Frame { frame, fault })) => {
            Incoming::FrameError { frame, fault }
        }
        Ok(DeviceMessage::Error(e)) => Incoming::Reply(Reply::Error(e)),
        Ok(DeviceMessage::Status(s)) => Incoming::Reply(Reply::Status(s)),
        Ok(DeviceMessage::Slopes { frame, results }) => Incoming::Slopes {
            frame,
            results: results.to_vec(),
        },
        Ok(DeviceMessage::FrameDone { frame, count }) => Incoming::FrameDone { frame, count },
        Ok(DeviceMessage::BenchReport(r)) => {
            Incoming::Reply(Reply::Bench(super::bench::BenchRow::of(&r)))
        }
        Ok(DeviceMessage::CaptureBegan {
            synced,
            camera_frame,
        }) => Incoming::Began(super::frames::CaptureBegan {
            synced,
            camera_frame,
        }),
        Ok(DeviceMessage::EdgeRows { frame, first, last }) => {
            Incoming::EdgeRows { frame, first, last }
        }
        Ok(DeviceMessage::LinkFill { offset, fill }) => Incoming::LinkFill {
            offset,
            fill: fill.to_vec(),
            frame_bytes,
        },
        Err(_) => {
            let mut copy = copy;
            match hello_prefix(&mut copy) {
                Some(h) => Incoming::ForeignHello(h),
                None => Incoming::Damaged,
            }
        }
    }
}
