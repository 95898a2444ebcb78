//! Pixels into the engine: `PixelRows` messages and the pixel source, frames
//! tracked for gaps, repeats and faults, results queued and flushed.

use brightpix_protocol::wire::{
    tables, DeviceError, DeviceMessage, FrameFault, SlopeEntry, SlopeList, SLOPES_PER_MESSAGE,
};
use embedded_io_async::{Read, Write};

use super::fmt::{log_debug, log_info};
use super::{bump, saturate, Core, FrameProgress, LinkResult, Watchdog, STATUS_LOG_FRAMES};
use crate::engine::{Engine, FrameError, OutputSink, SubapertureResult};

impl<T: Read + Write, W: Watchdog> Core<'_, T, W> {
    /// Pixels as u16 LE bytes (even length), converted a batch at a time.
    pub(super) async fn feed_le(
        &mut self,
        engine: &mut Engine<'_, '_>,
        frame: u32,
        first_pixel: u32,
        bytes: &[u8],
    ) -> LinkResult<(), T::Error> {
        let buffer = core::mem::take(&mut self.pixels);
        let batch = buffer.len().max(1) * 2;
        let mut first = first_pixel;
        let mut result = Ok(());
        for part in bytes.chunks(batch) {
            let n = tables::pixels_from_le(part, buffer);
            result = self.feed(engine, frame, first, &buffer[..n]).await;
            if result.is_err() || n == 0 {
                break;
            }
            first = first.wrapping_add(n as u32);
        }
        self.pixels = buffer;
        result
    }

    /// Pixels `first_pixel ..` of frame `frame`.
    pub(super) async fn feed(
        &mut self,
        engine: &mut Engine<'_, '_>,
        frame: u32,
        first_pixel: u32,
        pixels: &[u16],
    ) -> LinkResult<(), T::Error> {
        if pixels.is_empty() {
            return Ok(());
        }
        let camera = engine.config().camera;
        match self.frame {
            Some(p) if p.frame == frame && p.next == first_pixel => {}
            _ if first_pixel == 0 => {
                if let Some(p) = self.frame {
                    let received = p.next;
                    self.drop_frame(engine, FrameFault::Incomplete { received })
                        .await?;
                }
                self.skipping = None;
                self.frame = Some(FrameProgress {
                    frame,
                    next: 0,
                    sent: 0,
                });
                if let Some(capture) = &mut self.capture {
                    capture.frame_begins();
                }
            }
            _ => {
                if self.skipping == Some(frame) {
                    return Ok(());
                }
                bump(&mut self.counters.overruns, 1);
                let mut expected = 0;
                if let Some(p) = self.frame {
                    if p.frame == frame {
                        expected = p.next;
                        self.abandon(engine).await?;
                    } else {
                        let received = p.next;
                        self.drop_frame(engine, FrameFault::Incomplete { received })
                            .await?;
                    }
                }
                self.skipping = Some(frame);
                log_debug!("device: frame {=u32}: gap", frame);
                return self
                    .send_error(DeviceError::Frame {
                        frame,
                        fault: FrameFault::Gap {
                            expected,
                            found: first_pixel,
                        },
                    })
                    .await;
            }
        }
        let total = camera.pixel_count() as u64;
        if first_pixel as u64 + pixels.len() as u64 > total {
            self.abandon(engine).await?;
            self.skipping = Some(frame);
            return self
                .send_error(DeviceError::Frame {
                    frame,
                    fault: FrameFault::PastEnd {
                        first_pixel,
                        count: saturate(pixels.len()),
                    },
                })
                .await;
        }
        let width = camera.width as usize;
        let mut rest = pixels;
        while !rest.is_empty() {
            let (row, column) = engine.position();
            let take = rest.len().min(width - column as usize);
            if let Some(capture) = &mut self.capture {
                capture.row_pixels(row, camera.height, &rest[..take]);
            }
            let mut sink = QueueSink {
                results: self.results,
                queued: &mut self.queued,
                lost: 0,
                done: false,
            };
            let pushed = engine.push(&rest[..take], &mut sink);
            let (lost, done) = (sink.lost, sink.done);
            bump(&mut self.counters.overruns, lost);
            if let Err(FrameError::PixelOutOfRange { row, column, value }) = pushed {
                // The engine has abandoned the frame (SPEC.md §8); results
                // already finished stand.
                self.flush(frame, true).await?;
                self.frame = None;
                self.skipping = Some(frame);
                bump(&mut self.counters.pixel_errors, 1);
                self.counters.frames_dropped += 1;
                return self
                    .send_error(DeviceError::Frame {
                        frame,
                        fault: FrameFault::PixelOutOfRange { row, column, value },
                    })
                    .await;
            }
            if let Some(p) = &mut self.frame {
                p.next += take as u32;
            }
            rest = &rest[take..];
            let row_done = column as usize + take == width;
            self.flush(frame, row_done).await?;
            if done {
                let sent = self.frame.take().map_or(0, |p| p.sent);
                self.counters.frames_processed += 1;
                self.fold_engine(engine);
                self.log_progress();
                if let Some(edges) = self.capture.as_ref().and_then(|c| c.edge_rows(frame)) {
                    self.send(&edges).await?;
                }
                self.send(&DeviceMessage::FrameDone { frame, count: sent })
                    .await?;
                if let Some(capture) = &mut self.capture {
                    capture.done += 1;
                    if capture.frames != 0 && capture.done >= capture.frames {
                        self.capture_finished = true;
                    }
                }
            }
        }
        Ok(())
    }

    /// Logs the counters after the first frame and every
    /// [`STATUS_LOG_FRAMES`].
    pub(super) fn log_progress(&self) {
        let c = &self.counters;
        if c.frames_processed == 1 || c.frames_processed.is_multiple_of(STATUS_LOG_FRAMES) {
            log_info!(
                "device: {=u64} frames processed, {=u64} dropped; {=u32} CRC errors, {=u32} decode errors, {=u32} overruns, {=u32} pixel errors",
                c.frames_processed,
                c.frames_dropped,
                c.crc_errors,
                c.decode_errors,
                c.overruns,
                c.pixel_errors
            );
        }
    }

    /// Sends the queued results of `frame`: whole messages, or all if `all`.
    pub(super) async fn flush(&mut self, frame: u32, all: bool) -> LinkResult<(), T::Error> {
        let mut start = 0;
        while self.queued - start >= SLOPES_PER_MESSAGE || (all && self.queued > start) {
            let n = (self.queued - start).min(SLOPES_PER_MESSAGE);
            let mut results = SlopeList::new();
            for r in &self.results[start..start + n] {
                let _ = results.push(SlopeEntry {
                    index: r.index,
                    slope_x: r.slope_x,
                    slope_y: r.slope_y,
                    flux: r.flux,
                    valid: r.valid,
                });
            }
            start += n;
            if let Some(p) = &mut self.frame {
                p.sent += n as u32;
            }
            self.send(&DeviceMessage::Slopes { frame, results }).await?;
        }
        self.results.copy_within(start..self.queued, 0);
        self.queued -= start;
        Ok(())
    }

    /// Abandons the frame in progress, if any, without reporting it; its
    /// remaining pixels will be ignored.
    pub(super) async fn abandon(
        &mut self,
        engine: &mut Engine<'_, '_>,
    ) -> LinkResult<(), T::Error> {
        if let Some(p) = self.frame.take() {
            self.flush(p.frame, true).await?;
            engine.abort_frame();
            self.counters.frames_dropped += 1;
            self.skipping = Some(p.frame);
        }
        Ok(())
    }

    /// Abandons the frame in progress, if any, and reports why.
    pub(super) async fn drop_frame(
        &mut self,
        engine: &mut Engine<'_, '_>,
        fault: FrameFault,
    ) -> LinkResult<(), T::Error> {
        if let Some(p) = self.frame {
            self.abandon(engine).await?;
            log_debug!("device: frame {=u32} dropped", p.frame);
            self.send_error(DeviceError::Frame {
                frame: p.frame,
                fault,
            })
            .await?;
        }
        Ok(())
    }
}

/// Collects the engine's results into the queue.
struct QueueSink<'a> {
    results: &'a mut [SubapertureResult],
    queued: &'a mut usize,
    lost: u32,
    done: bool,
}

impl OutputSink for QueueSink<'_> {
    fn subaperture(&mut self, result: SubapertureResult) {
        match self.results.get_mut(*self.queued) {
            Some(slot) => {
                *slot = result;
                *self.queued += 1;
            }
            // Only if a row finishes more windows than vetted; never.
            None => self.lost += 1,
        }
    }

    fn frame_complete(&mut self, _frame: u32) {
        self.done = true;
    }
}
