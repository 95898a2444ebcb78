//! The board's camera path, for the bench: frames reach the engine through
//! the same [`DcmiSource`] as on the STM32H743 (runs taken out of the DMA
//! ring, cut at row ends, turned into pixels), over a ring in RAM that the
//! bench fills as the DMA would.
//!
//! The ring is the frame buffer itself, seen as the DCMI's words: its
//! 10- to 16-bit pixels are two to a word, first pixel in the low half,
//! which is how `u16` pixels lie in little-endian memory. The frame's words
//! arrive in two steps: all rows but the last (the source takes them in
//! runs while the "DMA" is far ahead), then the last row with the
//! frame-end mark, as the frame-end interrupt records it. What the board
//! does besides and this leaves out: the D-cache invalidation before each
//! copy (one register write per eight words), the DMA and frame-end
//! interrupts, and the device loop around each run.

use core::future::Future;
use core::pin::pin;
use core::task::{Context, Poll, Waker};

use brightpix_firmware::camera::{DataWidth, DcmiSource, DmaProgress, DmaRing, FrameMarks};
use brightpix_firmware::device::PixelSource;
use brightpix_protocol::Camera;

/// A DMA ring in RAM over one frame's words: the DMA has written
/// `written` words since the capture started.
pub struct BenchRing {
    base: *const u32,
    len: usize,
    written: u32,
    marks: FrameMarks,
}

impl DmaRing for BenchRing {
    fn capacity(&self) -> usize {
        self.len
    }

    fn start(&mut self) -> u32 {
        self.written = 0;
        0
    }

    fn stop(&mut self) {}

    fn half_events(&self) -> u32 {
        self.written / (self.len as u32 / 2)
    }

    fn write_index(&self) -> usize {
        self.written as usize % self.len
    }

    fn marks(&self) -> &FrameMarks {
        &self.marks
    }

    fn invalidate_lines(&mut self, _first_line: usize, _count: usize) {}

    fn copy(&mut self, start: usize, out: &mut [u32]) {
        assert!(start + out.len() <= self.len);
        // SAFETY: `base` is the frame buffer of `len` words (set by
        // `CameraFeed::arrive` before any run is taken), `start + out.len()`
        // of them checked above.
        unsafe { brightpix_firmware::camera::copy_from_ring(self.base.add(start), out) }
    }

    fn register_waker(&mut self, _waker: &Waker) {}
}

/// Frames of one camera through a [`DcmiSource`] over a [`BenchRing`].
pub struct CameraFeed<'b> {
    source: DcmiSource<'b, BenchRing>,
    frame_words: u32,
    row_words: u32,
}

impl<'b> CameraFeed<'b> {
    /// A running capture of `camera`'s frames (10 to 16 bits, an even
    /// width, a frame of whole 16-word granules: the ring is one frame),
    /// which will arrive in `frame` (word-aligned, as a DMA buffer is);
    /// `words` and `pixels` are the source's run buffers. `None` for a
    /// camera or frame buffer it cannot carry.
    pub fn new(
        camera: Camera,
        frame: &[u16],
        words: &'b mut [u32],
        pixels: &'b mut [u16],
    ) -> Option<Self> {
        let width = DataWidth::holding(camera.bit_depth);
        let frame_words = camera.pixel_count() / 2;
        if width == DataWidth::Bits8
            || !(frame.as_ptr() as usize).is_multiple_of(4)
            || frame.len() != camera.pixel_count()
            || !camera.width.is_multiple_of(2)
            || frame_words == 0
            || !frame_words.is_multiple_of(brightpix_firmware::camera::RING_GRANULE_WORDS)
        {
            return None;
        }
        let ring = BenchRing {
            base: core::ptr::null(),
            len: frame_words,
            written: 0,
            marks: FrameMarks::new(),
        };
        let mut source = DcmiSource::new(ring, width, words, pixels);
        source.start(camera, None).ok()?;
        Some(CameraFeed {
            source,
            frame_words: frame_words as u32,
            row_words: camera.width as u32 / 2,
        })
    }

    /// The DMA writes the next frame (`frame`, which the ring is from now
    /// on: the buffer given to [`CameraFeed::new`]) up to the start of its
    /// last row.
    pub fn arrive_before_last_row(&mut self, frame: &[u16]) {
        assert!(
            frame.len() == 2 * self.frame_words as usize
                && (frame.as_ptr() as usize).is_multiple_of(4)
        );
        let ring = self.source.ring();
        ring.base = frame.as_ptr() as *const u32;
        ring.written = ring.written.wrapping_add(self.frame_words - self.row_words);
    }

    /// Then its last row, and the frame-end interrupt's mark.
    pub fn arrive_last_row(&mut self) {
        let ring = self.source.ring();
        ring.written = ring.written.wrapping_add(self.row_words);
        let at = DmaProgress {
            half_events: ring.half_events(),
            write_index: ring.write_index() as u32,
        };
        ring.marks.record(at);
    }

    /// Every run the source has, to `push`, as the device loop takes them
    /// (one poll of `next` each); stops at the first error.
    #[inline(always)]
    pub fn drain<E>(&mut self, mut push: impl FnMut(&[u16]) -> Result<(), E>) -> Result<(), E> {
        let mut cx = Context::from_waker(Waker::noop());
        loop {
            let mut next = pin!(self.source.next());
            match next.as_mut().poll(&mut cx) {
                Poll::Ready(run) => push(run.pixels)?,
                Poll::Pending => return Ok(()),
            }
        }
    }
}
