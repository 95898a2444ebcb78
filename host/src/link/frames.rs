//! Pixels out, results back: frames sent through the pixel sink (the link
//! or a FIFO) with a few in flight, each frame's results gathered into a
//! [`FrameOutcome`] (done, dropped, or incomplete when a call fails), and
//! `Capture` on a device with its own camera.

use std::collections::BTreeSet;
use std::io::ErrorKind;
use std::time::{Duration, Instant};

use brightpix_protocol::wire::{
    encode, Ack, CaptureStart, DeviceError, FrameFault, HostMessage, PixelRowsPlan, SlopeEntry,
    MAX_FRAME_LEN, MAX_PIXEL_BYTES,
};

use super::errors::unexpected;
use super::{Client, FifoWriter, Interrupted, LinkError, PixelSink, Reply};

/// The results of one frame, as the device sent them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FrameSlopes {
    pub frame: u32,
    /// In the order received (SPEC.md §6: by index within a camera row is
    /// not guaranteed); see [`FrameSlopes::by_index`].
    pub slopes: Vec<SlopeEntry>,
    /// `FrameDone.count`, if the frame completed.
    pub done_count: Option<u32>,
    /// `EdgeRows` of the frame (first, last row checksums), if the device
    /// sent them (a capture with `edge_rows`).
    pub edge_rows: Option<(u32, u32)>,
}

impl FrameSlopes {
    /// One entry per sub-aperture `0..subapertures`: `None` where the device
    /// sent nothing (or an index twice: the later one wins).
    pub fn by_index(&self, subapertures: usize) -> Vec<Option<SlopeEntry>> {
        let mut out = vec![None; subapertures];
        for s in &self.slopes {
            if let Some(slot) = out.get_mut(s.index as usize) {
                *slot = Some(*s);
            }
        }
        out
    }
}

/// How a frame ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FrameOutcome {
    /// `FrameDone` arrived.
    Done(FrameSlopes),
    /// The device dropped the frame (`Error(Frame{..})`); results sent
    /// before that are kept.
    Dropped {
        slopes: FrameSlopes,
        fault: FrameFault,
    },
    /// The call failed before the frame ended.
    Incomplete(FrameSlopes),
}

impl FrameOutcome {
    pub fn slopes(&self) -> &FrameSlopes {
        match self {
            FrameOutcome::Done(s) | FrameOutcome::Incomplete(s) => s,
            FrameOutcome::Dropped { slopes, .. } => slopes,
        }
    }

    pub fn frame(&self) -> u32 {
        self.slopes().frame
    }
}

/// Totals of a [`Client::stream_frames`] call.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamReport {
    pub frames_sent: usize,
    pub frames_done: usize,
    pub frames_dropped: usize,
    pub pixel_bytes: usize,
    pub elapsed: Duration,
}

impl Client {
    /// Sends frame `frame`'s pixels (raster order) through the pixel sink,
    /// without waiting for results; reads what the device sends meanwhile.
    pub fn send_frame(&mut self, frame: u32, pixels: &[u16]) -> Result<usize, LinkError> {
        if let Some(camera) = self.camera {
            if pixels.len() != camera.pixel_count() {
                return Err(LinkError::Usage(format!(
                    "frame {frame} has {} pixels, the configured camera {}x{} has {}",
                    pixels.len(),
                    camera.width,
                    camera.height,
                    camera.pixel_count()
                )));
            }
        }
        let bytes = encode_pixel_rows(frame, pixels);
        // Counted before the write: a write that stalls part-way still has
        // bytes in flight.
        self.pacing.sent(frame, bytes.len());
        self.send_pixels(&bytes)?;
        Ok(bytes.len())
    }

    /// Writes encoded `PixelRows` frames to the pixel sink, reading from the
    /// link while it writes.
    pub fn send_pixels(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        match &self.sink {
            PixelSink::Link => self.write_raw(bytes, "pixels"),
            PixelSink::Fifo(_) => self.write_fifo(bytes),
        }
    }

    fn write_fifo(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        if self.fifo.is_none() {
            let PixelSink::Fifo(path) = &self.sink else {
                unreachable!()
            };
            let writer =
                FifoWriter::open(path, self.options.timeout).map_err(|source| LinkError::Fifo {
                    path: path.display().to_string(),
                    source,
                })?;
            self.fifo = Some(writer);
        }
        let mut rest = bytes;
        let mut last_progress = Instant::now();
        while !rest.is_empty() {
            let Some(fifo) = self.fifo.as_mut() else {
                unreachable!()
            };
            match fifo.try_write(rest) {
                Ok(n) if n > 0 => {
                    rest = &rest[n..];
                    last_progress = Instant::now();
                    self.pump(Duration::ZERO)?;
                }
                Ok(_) => self.fifo_wait(&mut last_progress)?,
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    self.fifo_wait(&mut last_progress)?
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(LinkError::Fifo {
                        path: fifo.path().display().to_string(),
                        source,
                    })
                }
            }
        }
        Ok(())
    }

    fn fifo_wait(&mut self, last_progress: &mut Instant) -> Result<(), LinkError> {
        if last_progress.elapsed() > self.options.timeout {
            let path = match &self.sink {
                PixelSink::Fifo(p) => p.display().to_string(),
                PixelSink::Link => String::new(),
            };
            return Err(LinkError::WriteStalled {
                port: path,
                timeout: self.options.timeout,
                what: "pixels".into(),
            });
        }
        // The device may be waiting for us to read its results.
        self.pump(Duration::from_millis(2))?;
        Ok(())
    }

    /// Waits for the next frame to end (done or dropped).
    pub fn next_outcome(&mut self) -> Result<FrameOutcome, LinkError> {
        self.check_stream_errors()?;
        let timeout = self.results_timeout();
        self.wait_within("frame results", timeout, |c| c.finished.pop_front())
    }

    /// The longest silence while waiting for results: the timeout, plus
    /// the time the pixel bytes still in flight take at the link's
    /// measured rate (`pacing`): a slow link is not a silent device.
    fn results_timeout(&self) -> Duration {
        self.options.timeout + self.pacing.allowance()
    }

    /// A frame that has ended, if any, without waiting.
    pub fn try_outcome(&mut self) -> Option<FrameOutcome> {
        self.finished.pop_front()
    }

    /// Errors that end a stream: the device refuses pixels altogether.
    fn check_stream_errors(&mut self) -> Result<(), LinkError> {
        let mut fatal = None;
        self.replies.retain(|r| match r {
            Reply::Error(
                e @ (DeviceError::NotConfigured
                | DeviceError::HelloRequired
                | DeviceError::Unexpected { .. }),
            ) => {
                fatal.get_or_insert(*e);
                false
            }
            _ => true,
        });
        self.move_replies_to_notices();
        match fatal {
            Some(error) => Err(LinkError::Device {
                request: "pixels (PixelRows)".into(),
                error,
            }),
            None => Ok(()),
        }
    }

    /// Results received so far of frames that have not ended (taken).
    pub fn take_incomplete(&mut self) -> Vec<FrameSlopes> {
        std::mem::take(&mut self.open_frames)
            .into_iter()
            .map(|(frame, slopes)| FrameSlopes {
                frame,
                slopes,
                done_count: None,
                edge_rows: None,
            })
            .collect()
    }

    /// Sends one frame and waits for its results. A dropped frame is an
    /// error ([`LinkError::FrameDropped`]) with the results sent before.
    pub fn stream_frame(
        &mut self,
        frame: u32,
        pixels: &[u16],
    ) -> Result<FrameSlopes, Interrupted<FrameSlopes>> {
        let mut outcome = None;
        let result = self.stream_frames(frame, [pixels], |o| outcome = Some(o));
        match (result, outcome) {
            (Ok(_), Some(FrameOutcome::Done(s))) => Ok(s),
            (Ok(_), Some(FrameOutcome::Dropped { slopes, fault })) => Err(Interrupted {
                error: LinkError::FrameDropped {
                    frame: slopes.frame,
                    fault,
                },
                received: slopes,
            }),
            (Ok(_), other) => Err(Interrupted {
                error: LinkError::Usage(format!("frame {frame}: no outcome")),
                received: other.map(|o| o.slopes().clone()).unwrap_or_default(),
            }),
            (Err(error), other) => Err(Interrupted {
                error,
                received: other.map(|o| o.slopes().clone()).unwrap_or_default(),
            }),
        }
    }

    /// Streams frames numbered `first_frame, first_frame + 1, ...`, keeping
    /// up to [`ClientOptions::frames_in_flight`] sent ahead of their
    /// results. Every frame's outcome goes to `on_outcome` as it arrives, in
    /// order; on an error, frames in flight go there as
    /// [`FrameOutcome::Incomplete`] with what had arrived, then the error is
    /// returned. Only outcomes of frames this call sent count: results or
    /// drops of any other frame (an earlier stream's, a previous client's)
    /// are discarded and counted in [`Client::stale_outcomes`].
    pub fn stream_frames<F: AsRef<[u16]>>(
        &mut self,
        first_frame: u32,
        frames: impl IntoIterator<Item = F>,
        mut on_outcome: impl FnMut(FrameOutcome),
    ) -> Result<StreamReport, LinkError> {
        let started = Instant::now();
        let mut report = StreamReport::default();
        let window = self.options.frames_in_flight.max(1);
        let mut in_flight: BTreeSet<u32> = BTreeSet::new();
        self.pacing.restart();
        let mut deliver = |o: FrameOutcome, report: &mut StreamReport| {
            match &o {
                FrameOutcome::Done(_) => report.frames_done += 1,
                FrameOutcome::Dropped { .. } => report.frames_dropped += 1,
                FrameOutcome::Incomplete(_) => {}
            }
            on_outcome(o);
        };
        let result = (|| {
            for (k, pixels) in frames.into_iter().enumerate() {
                while in_flight.len() >= window {
                    let o = self.next_outcome_of(&in_flight)?;
                    in_flight.remove(&o.frame());
                    deliver(o, &mut report);
                }
                self.check_interrupt()?;
                let frame = first_frame.wrapping_add(k as u32);
                // Results a previous stream left under this number are stale.
                if self.open_frames.remove(&frame).is_some() {
                    self.stale_outcomes += 1;
                }
                in_flight.insert(frame);
                report.pixel_bytes += self.send_frame(frame, pixels.as_ref())?;
                report.frames_sent += 1;
                while let Some(o) = self.take_outcome_of(&in_flight) {
                    in_flight.remove(&o.frame());
                    deliver(o, &mut report);
                }
                self.check_stream_errors()?;
            }
            while !in_flight.is_empty() {
                let o = self.next_outcome_of(&in_flight)?;
                in_flight.remove(&o.frame());
                deliver(o, &mut report);
            }
            Ok(())
        })();
        report.elapsed = started.elapsed();
        self.close_pixel_fifo();
        match result {
            Ok(()) => Ok(report),
            Err(e) => {
                while let Some(o) = self.take_outcome_of(&in_flight) {
                    in_flight.remove(&o.frame());
                    deliver(o, &mut report);
                }
                for s in self.take_incomplete() {
                    if in_flight.remove(&s.frame) {
                        deliver(FrameOutcome::Incomplete(s), &mut report);
                    }
                }
                for frame in in_flight {
                    deliver(
                        FrameOutcome::Incomplete(FrameSlopes {
                            frame,
                            ..FrameSlopes::default()
                        }),
                        &mut report,
                    );
                }
                Err(e)
            }
        }
    }

    /// The next ended frame among `frames`, without waiting; outcomes of
    /// other frames are discarded (stale).
    fn take_outcome_of(&mut self, frames: &BTreeSet<u32>) -> Option<FrameOutcome> {
        while let Some(o) = self.finished.pop_front() {
            if frames.contains(&o.frame()) {
                return Some(o);
            }
            self.stale_outcomes += 1;
        }
        None
    }

    /// Waits for the next frame among `frames` to end.
    fn next_outcome_of(&mut self, frames: &BTreeSet<u32>) -> Result<FrameOutcome, LinkError> {
        self.check_stream_errors()?;
        let timeout = self.results_timeout();
        self.wait_within("frame results", timeout, |c| c.take_outcome_of(frames))
    }

    /// `Capture { frames }` on a device with its own camera: records
    /// `frames` frames (at least 1) and waits for `Ack(CaptureStopped)`.
    pub fn capture(
        &mut self,
        frames: u32,
    ) -> Result<Vec<FrameOutcome>, Interrupted<Vec<FrameOutcome>>> {
        self.capture_with(frames, &mut |_| {})
    }

    /// [`Client::capture`], calling `on_frame` with each frame as it arrives.
    pub fn capture_with(
        &mut self,
        frames: u32,
        on_frame: &mut dyn FnMut(&FrameOutcome),
    ) -> Result<Vec<FrameOutcome>, Interrupted<Vec<FrameOutcome>>> {
        if let Err(error) = self.start_capture(frames, CaptureStart::Immediate) {
            return Err(Interrupted {
                error,
                received: Vec::new(),
            });
        }
        self.collect_capture(&mut |_| {}, on_frame)
    }

    /// Sends `Capture { frames, start }` (`frames` at least 1) and waits
    /// for its acknowledgement: the capture is armed (on the sync line: it
    /// waits for the edge). Then [`Client::collect_capture`].
    pub fn start_capture(&mut self, frames: u32, start: CaptureStart) -> Result<(), LinkError> {
        self.start_capture_with(frames, start, false)
    }

    /// [`Client::start_capture`], with every frame's `EdgeRows` if
    /// `edge_rows` ([`FrameSlopes::edge_rows`]).
    pub fn start_capture_with(
        &mut self,
        frames: u32,
        start: CaptureStart,
        edge_rows: bool,
    ) -> Result<(), LinkError> {
        if frames == 0 {
            return Err(LinkError::Usage("capture needs at least one frame".into()));
        }
        self.capture_began = None;
        self.edge_rows.clear();
        match self.request(&HostMessage::Capture {
            frames,
            start,
            edge_rows,
        }) {
            Ok(Reply::Ack(Ack::CaptureStarted { .. })) => Ok(()),
            Ok(other) => Err(unexpected("Capture", &other)),
            Err(e @ LinkError::Device { .. }) => Err(e),
            Err(e) => {
                // No acknowledgement in time: a capture armed late must
                // not start later by itself.
                self.send_stop_capture();
                Err(e)
            }
        }
    }

    /// How the capture started last began, once its `CaptureBegan` came.
    pub fn capture_began(&self) -> Option<CaptureBegan> {
        self.capture_began
    }

    /// The frames of the capture [`Client::start_capture`] started, until
    /// its `Ack(CaptureStopped)`: `on_began` once with its `CaptureBegan`,
    /// `on_frame` with each frame as it arrives.
    pub fn collect_capture(
        &mut self,
        on_began: &mut dyn FnMut(CaptureBegan),
        on_frame: &mut dyn FnMut(&FrameOutcome),
    ) -> Result<Vec<FrameOutcome>, Interrupted<Vec<FrameOutcome>>> {
        let mut received = Vec::new();
        let mut began_told = false;
        let result = (|| loop {
            let next = self.wait_within("captured frames", self.options.capture_timeout, |c| {
                if !began_told {
                    if let Some(b) = c.capture_began {
                        return Some(Err(Some(b)));
                    }
                }
                if let Some(o) = c.finished.pop_front() {
                    return Some(Ok(o));
                }
                let at = c
                    .replies
                    .iter()
                    .position(|r| matches!(r, Reply::Ack(Ack::CaptureStopped { .. })))?;
                c.replies.remove(at);
                Some(Err(None))
            })?;
            match next {
                Err(Some(began)) => {
                    began_told = true;
                    on_began(began);
                }
                Ok(o) => {
                    on_frame(&o);
                    received.push(o);
                }
                Err(None) => {
                    // Results of the last frame precede the stop.
                    while let Some(o) = self.finished.pop_front() {
                        on_frame(&o);
                        received.push(o);
                    }
                    return Ok(());
                }
            }
        })();
        match result {
            Ok(()) => Ok(received),
            Err(error) => {
                self.send_stop_capture();
                for s in self.take_incomplete() {
                    received.push(FrameOutcome::Incomplete(s));
                }
                Err(Interrupted { error, received })
            }
        }
    }

    /// `StopCapture` without waiting for its reply (after an error).
    pub fn send_stop_capture(&mut self) {
        let stop = self
            .encode(&HostMessage::StopCapture)
            .map(<[u8]>::to_vec)
            .unwrap_or_default();
        let _ = self.write_raw(&stop, "StopCapture");
    }
}

/// How a capture's frame 0 began (`DeviceMessage::CaptureBegan`,
/// PROTOCOL.md §9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CaptureBegan {
    /// On the first frame start after a sync edge the device saw.
    pub synced: bool,
    /// The camera's number of that frame, if the device knows it.
    pub camera_frame: Option<u32>,
}

/// The `PixelRows` frames of one frame of pixels, concatenated (at most
/// [`MAX_PIXEL_BYTES`] of pixels per message).
pub fn encode_pixel_rows(frame: u32, pixels: &[u16]) -> Vec<u8> {
    let mut plan = PixelRowsPlan::new(frame, pixels, MAX_PIXEL_BYTES / 2);
    let mut scratch = vec![0u8; MAX_PIXEL_BYTES];
    let mut frame_buf = vec![0u8; MAX_FRAME_LEN];
    let mut out = Vec::with_capacity(pixels.len() * 2 + pixels.len() / 400 * 12 + 16);
    while let Some(message) = plan.next(&mut scratch) {
        let encoded = encode(&message, &mut frame_buf).expect("a PixelRows message fits a frame");
        out.extend_from_slice(encoded);
    }
    out
}

/// The frames of [`encode_pixel_rows`], one `Vec` per message (for tests
/// that damage one).
pub fn pixel_rows_frames(frame: u32, pixels: &[u16]) -> Vec<Vec<u8>> {
    let bytes = encode_pixel_rows(frame, pixels);
    bytes
        .split_inclusive(|&b| b == 0)
        .map(<[u8]>::to_vec)
        .collect()
}
