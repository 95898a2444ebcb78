//! Where pixels come from besides `PixelRows` messages on the link.

use brightpix_protocol::wire::tables::pixels_from_le;
use brightpix_protocol::wire::{
    decode, CaptureStart, CropFault, FrameReader, HostMessage, PixelSourceKind, Received, SyncFault,
};
use brightpix_protocol::{Camera, Crop};
use embedded_io_async::Read;

/// A run of raw pixels of one frame, in raster order: pixels
/// `first_pixel .. first_pixel + pixels.len()` of frame `frame`.
///
/// A source that lost data (e.g. a DMA overrun) says so by where the next
/// run starts: the device drops the frame and counts an overrun.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRun<'a> {
    pub frame: u32,
    pub first_pixel: u32,
    pub pixels: &'a [u16],
    /// On a capture's first run: how its frame 0 began (the device sends
    /// `CaptureBegan` before anything of it); `None` on every other run.
    pub began: Option<CaptureBegin>,
}

/// A pixel source cannot capture (none, or not this geometry); the host
/// gets `Error(NoCamera)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CameraRefused;

/// How a capture's frame 0 began ([`PixelRun::began`]), for the host's
/// `CaptureBegan`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CaptureBegin {
    /// Frame 0 is the first frame start after a sync edge the source saw.
    pub synced: bool,
    /// The camera's own number of frame 0, if the source knows it.
    pub camera_frame: Option<u32>,
}

/// A source of camera pixels: a camera interface, or a stream the host
/// writes outside the link (e.g. a semihosting file on QEMU).
#[allow(async_fn_in_trait)]
pub trait PixelSource {
    /// Reported to the host in `HelloReply`.
    fn kind(&self) -> PixelSourceKind;

    /// Why the source cannot capture `camera` (a configuration's camera:
    /// the rectangle) at `crop` of a larger sensor; asked at `ConfigBegin`,
    /// before anything is uploaded. By default any rectangle: pixels that
    /// come from the host are cropped by the host.
    fn check_crop(&self, camera: Camera, crop: Crop) -> Result<(), CropFault> {
        let _ = (camera, crop);
        Ok(())
    }

    /// Starts capturing frames of `camera`'s geometry (`Capture`), cut from
    /// a larger sensor at `crop` if there is one. Only a
    /// [`PixelSourceKind::Camera`] source can; the default refuses.
    fn start(&mut self, camera: Camera, crop: Option<Crop>) -> Result<(), CameraRefused> {
        let _ = (camera, crop);
        Err(CameraRefused)
    }

    /// How the next [`start`](Self::start) begins (asked before it):
    /// [`CaptureStart::Immediate`] always can; the sync line's modes only a
    /// source with a sync line (the default refuses them).
    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        match start {
            CaptureStart::Immediate => Ok(()),
            CaptureStart::OnSync | CaptureStart::DriveSync => Err(SyncFault::NoSyncLine),
        }
    }

    /// Whether the capture started last is armed: a rising edge of the
    /// sync line from now on starts it (`OnSync`), or it is about to raise
    /// the line (`DriveSync`). The device acknowledges `Capture` only once
    /// it is, so that a host may then release the leader. By default at
    /// once: a board arms in [`start`](Self::start) itself.
    fn armed(&self) -> bool {
        true
    }

    /// Stops capturing (`StopCapture`, or the requested frames are done).
    fn stop(&mut self) {}

    /// Waits for the next run of pixels.
    ///
    /// Must be cancel-safe: the device races it against the link and drops
    /// the future when a host frame arrives first; no pixels may be lost by
    /// that. A source with nothing to give never resolves.
    async fn next(&mut self) -> PixelRun<'_>;
}

/// No pixel source: pixels come only in `PixelRows` messages (a camera
/// that the host emulates over the link).
#[derive(Clone, Copy, Debug, Default)]
pub struct LinkOnly;

impl PixelSource for LinkOnly {
    fn kind(&self) -> PixelSourceKind {
        PixelSourceKind::Link
    }

    async fn next(&mut self) -> PixelRun<'_> {
        core::future::pending().await
    }
}

/// Pixels from a second byte stream that carries the same frames as the
/// link, holding `PixelRows` messages (other messages and damaged frames
/// are skipped): e.g. a file or FIFO that the host writes and the board
/// reads through semihosting, much faster than an emulated UART.
///
/// Cancel-safe if `R::read` is: all state is kept in the struct.
pub struct PixelRowsStream<'b, R> {
    reader: R,
    frames: FrameReader<&'b mut [u8]>,
    pixels: &'b mut [u16],
    ended: bool,
    /// Frames skipped because they were damaged or not `PixelRows`.
    pub skipped: u32,
}

impl<'b, R: Read> PixelRowsStream<'b, R> {
    /// `frame_buffer`: at least [`MAX_FRAME_LEN`] bytes; `pixels`: at least
    /// `MAX_PIXEL_BYTES / 2` (longer runs are cut, and the device then sees
    /// a gap).
    ///
    /// [`MAX_FRAME_LEN`]: brightpix_protocol::wire::MAX_FRAME_LEN
    pub fn new(reader: R, frame_buffer: &'b mut [u8], pixels: &'b mut [u16]) -> Self {
        PixelRowsStream {
            reader,
            frames: FrameReader::new(frame_buffer),
            pixels,
            ended: false,
            skipped: 0,
        }
    }
}

impl<R: Read> PixelSource for PixelRowsStream<'_, R> {
    fn kind(&self) -> PixelSourceKind {
        PixelSourceKind::Stream
    }

    async fn next(&mut self) -> PixelRun<'_> {
        loop {
            let mut found = None;
            while let Some(received) = self.frames.next_frame() {
                match received {
                    Received::Frame(bytes) => match decode::<HostMessage>(bytes) {
                        Ok(HostMessage::PixelRows {
                            frame,
                            first_pixel,
                            pixels,
                        }) => {
                            let n = pixels_from_le(pixels, self.pixels);
                            found = Some((frame, first_pixel, n));
                            break;
                        }
                        _ => self.skipped = self.skipped.saturating_add(1),
                    },
                    Received::TooLong => self.skipped = self.skipped.saturating_add(1),
                }
            }
            if let Some((frame, first_pixel, n)) = found {
                return PixelRun {
                    frame,
                    first_pixel,
                    pixels: &self.pixels[..n],
                    began: None,
                };
            }
            if self.ended {
                return core::future::pending().await;
            }
            match self.reader.read(self.frames.space()).await {
                Ok(0) | Err(_) => self.ended = true,
                Ok(n) => self.frames.advance(n),
            }
        }
    }
}
