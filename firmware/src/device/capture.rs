//! The device's own camera: `Capture` (at once or on the rig's sync line),
//! its acknowledgement once armed, `CaptureBegan` before the first results,
//! and `StopCapture` (PROTOCOL.md §9).

use brightpix_protocol::wire::{
    edge_row_checksum, edge_row_update, Ack, CaptureStart, DeviceError, DeviceMessage, FrameFault,
    MessageKind, PixelSourceKind, EDGE_ROW_SEED,
};
use embedded_io_async::{Read, Write};

use super::fmt::log_info;
use super::{CameraRefused, CaptureBegin, Core, LinkResult, PixelSource, Watchdog};
use crate::engine::Engine;

/// A capture in progress.
#[derive(Clone, Copy)]
pub(super) struct Capture {
    /// Frames requested (0: until `StopCapture`).
    pub frames: u32,
    /// Frames completed (dropped ones too).
    pub done: u32,
    /// `Ack(CaptureStarted)` is still due: sent once the source is armed.
    pub unacknowledged: bool,
    /// The frame's first and last rows' checksum states
    /// (`Capture.edge_rows`), or `None` when not asked.
    pub edges: Option<[u64; 2]>,
}

impl Capture {
    /// A new frame begins: its edge rows' checksums start afresh.
    pub fn frame_begins(&mut self) {
        if let Some(edges) = &mut self.edges {
            *edges = [EDGE_ROW_SEED; 2];
        }
    }

    /// `pixels` of camera row `row` of a frame of `height` rows.
    pub fn row_pixels(&mut self, row: u16, height: u16, pixels: &[u16]) {
        if let Some(edges) = &mut self.edges {
            if row == 0 {
                edges[0] = edge_row_update(edges[0], pixels);
            }
            if row + 1 == height {
                edges[1] = edge_row_update(edges[1], pixels);
            }
        }
    }

    /// The frame's `EdgeRows` message, if asked.
    pub fn edge_rows(&self, frame: u32) -> Option<DeviceMessage<'static>> {
        self.edges.map(|[first, last]| DeviceMessage::EdgeRows {
            frame,
            first: edge_row_checksum(first),
            last: edge_row_checksum(last),
        })
    }
}

impl<T: Read + Write, W: Watchdog> Core<'_, T, W> {
    /// `Capture { frames, start }`: the acknowledgement now if the source
    /// is armed at once (`None`: later, from [`Self::acknowledge_capture`]).
    pub(super) fn start_capture<C: PixelSource>(
        &mut self,
        frames: u32,
        start: CaptureStart,
        edge_rows: bool,
        source: &mut C,
        engine: &mut Option<Engine<'_, '_>>,
    ) -> Result<Option<Ack>, DeviceError> {
        if source.kind() != PixelSourceKind::Camera {
            return Err(DeviceError::NoCamera);
        }
        if self.capture.is_some() {
            return Err(DeviceError::Unexpected {
                message: MessageKind::Capture,
            });
        }
        let Some(engine) = engine else {
            return Err(DeviceError::NotConfigured);
        };
        source.set_start(start).map_err(DeviceError::Sync)?;
        let config = engine.config();
        source
            .start(config.camera, config.crop)
            .map_err(|CameraRefused| DeviceError::NoCamera)?;
        let armed = source.armed();
        self.capture = Some(Capture {
            frames,
            done: 0,
            unacknowledged: !armed,
            edges: edge_rows.then_some([EDGE_ROW_SEED; 2]),
        });
        log_info!(
            "device: capture of {=u32} frames started ({})",
            frames,
            match start {
                CaptureStart::Immediate => "at once",
                CaptureStart::OnSync => "on the sync line's edge",
                CaptureStart::DriveSync => "driving the sync line",
            }
        );
        Ok(armed.then_some(Ack::CaptureStarted { frames }))
    }

    /// Sends the capture's acknowledgement if it is still due and `armed`.
    pub(super) async fn acknowledge_capture(&mut self, armed: bool) -> LinkResult<(), T::Error> {
        let Some(capture) = self.capture.as_mut().filter(|c| c.unacknowledged) else {
            return Ok(());
        };
        if !armed {
            return Ok(());
        }
        capture.unacknowledged = false;
        let frames = capture.frames;
        log_info!("device: capture armed");
        self.send(&DeviceMessage::Ack(Ack::CaptureStarted { frames }))
            .await
    }

    /// The capture's first pixels arrived: acknowledged (pixels mean it is
    /// armed), then how it began, before any result of them.
    pub(super) async fn capture_began(&mut self, began: CaptureBegin) -> LinkResult<(), T::Error> {
        if self.capture.is_none() {
            return Ok(());
        }
        self.acknowledge_capture(true).await?;
        self.send(&DeviceMessage::CaptureBegan {
            synced: began.synced,
            camera_frame: began.camera_frame,
        })
        .await
    }

    /// `StopCapture`: the frame in progress is dropped and reported.
    pub(super) async fn stop_capture<C: PixelSource>(
        &mut self,
        source: &mut C,
        engine: &mut Option<Engine<'_, '_>>,
    ) -> LinkResult<Ack, T::Error> {
        let frames = match self.capture.take() {
            Some(capture) => {
                source.stop();
                if let Some(engine) = engine {
                    self.drop_frame(engine, FrameFault::Stopped).await?;
                }
                capture.done
            }
            None => 0,
        };
        Ok(Ack::CaptureStopped { frames })
    }
}
