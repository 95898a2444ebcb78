//! Camera pixels that a parallel camera interface (the STM32 DCMI) writes by
//! circular DMA, turned into pixel runs for the device loop. Board
//! independent, no heap; tested on the host with a simulated DMA writer
//! (`tests/tests/camera_*.rs`).
//!
//! The board owns the hardware and implements [`DmaRing`]: the DMA stream
//! runs circularly over a ring of 32-bit words; its half-transfer and
//! transfer-complete interrupt counts half rings; the camera interface's
//! frame-end interrupt records where each frame ended in [`FrameMarks`].
//! [`DcmiSource`] does the rest: it works out where the DMA is (half events
//! plus the DMA's index), copies the words written since the last run out of
//! the ring, unpacks them ([`packing`]) and hands them to the device loop as
//! [`PixelRun`](crate::device::PixelRun)s, checking frame lengths and
//! detecting overruns.
//!
//! # Positions
//!
//! Every word the DMA writes has a position: words written since the DMA
//! started, modulo 2^32 ([`DmaProgress::position`]). A frame of the
//! configured geometry is `width * height / pixels_per_word` words; the
//! capture starts at a frame start, and each frame ends where the next
//! starts (nothing is captured during vertical blanking). The ring need not
//! hold a whole frame, nor a whole number of rows: frames and rows wrap
//! around it freely.
//!
//! # Overruns
//!
//! The DMA never waits: if the consumer falls more than the ring behind, the
//! words it has not read yet are overwritten. Before copying, the source
//! checks that the DMA is at most a ring ahead of the next word; after
//! copying, it checks again (the DMA kept writing during the copy) and
//! discards the copy if any of its words may have been overwritten. The
//! frame is then dropped, never completed: the source delivers one word of
//! the newest data at its true pixel position, which the device loop sees as
//! a gap (it counts an overrun and drops the frame), and resumes with the
//! next frame. [`CameraStats`] counts overruns, dropped frames and frames of
//! the wrong length.
//!
//! # D-cache maintenance (Cortex-M7)
//!
//! The ring is in cacheable memory (AXI SRAM on the STM32H743), and the DMA
//! writes memory behind the cache's back. The rules, all enforced here or
//! required of the board's [`DmaRing`]:
//!
//! 1. **Invalidate right before reading, exactly the lines read.** Before
//!    each copy the source invalidates the 32-byte lines that hold the words
//!    it is about to copy ([`DmaRing::invalidate_lines`], line `k` = words
//!    `8k .. 8k + 8`), after it has read the DMA position that says those
//!    words are written. Not earlier (not at DMA start, not when a half
//!    event fires): the Cortex-M7 may read cacheable memory speculatively,
//!    so a line invalidated early can be refilled with old data before the
//!    DMA writes it. This is finer than "invalidate the half the DMA just
//!    completed" (rows are delivered as they arrive, not per half ring), and
//!    covers the same ground: a half event is just one more time to look.
//! 2. **Rounding out to whole lines is safe** because the CPU never writes
//!    the ring (no dirty line to lose) and the ring owns its lines: it is
//!    32-byte aligned and its length is a multiple of
//!    [`RING_GRANULE_WORDS`] (16 words: each half of the ring is whole
//!    lines), so no other variable shares a line with it. A line holding
//!    words not yet written is invalidated again before those are read.
//! 3. **Barriers**: the board's `invalidate_lines` issues a DSB before (so
//!    the DMA position read is complete) and DSB + ISB after.
//! 4. **At DMA start** the board invalidates the whole ring
//!    ([`DmaRing::start`]): a dirty line left by start-up code (which zeroes
//!    the ring's memory) could otherwise be evicted over DMA data at any
//!    time.
//!
//! The alternative, an MPU region that makes the ring non-cacheable, needs
//! no maintenance but turns every word read into a separate bus access
//! (slower than line fills by a factor of several), and MPU regions must be
//! power-of-two sized and aligned, which wastes SRAM or constrains the ring.
//! Invalidating by line is cheap (one register write per 8 words) and the
//! rules above are small and tested on the host with a model of a stale
//! cache (`tests/tests/camera_source.rs`).
//!
//! # Frames
//!
//! The frame-end interrupt records each frame's end ([`FrameMarks`], the
//! last [`MARK_SLOTS`] frames). The source holds a frame's last word back
//! until the frame's end is known: if the end is where the geometry puts
//! it, the frame is completed; if not (pixels lost or added on the bus, a
//! camera sending another geometry than configured), the frame is dropped
//! and counted, and the next frame starts at the recorded end (resync).
//! Pixels of such a frame that were already delivered never complete a
//! frame: the device loop reports the frame as incomplete, and results it
//! sent for that frame's earlier rows are not followed by `FrameDone`.

pub mod crop;
pub mod packing;
pub mod ring;
pub mod soft;
mod source;

pub use crop::{dcmi_check, DcmiCropRegisters, SensorCrop};
pub use packing::DataWidth;
pub use ring::{
    copy_from_ring, DmaProgress, DmaRing, FrameMarks, Mark, CACHE_LINE_BYTES, CACHE_LINE_WORDS,
    MARK_SLOTS, MAX_HOLD_BACK_WORDS, RING_GRANULE_WORDS,
};
pub use soft::{SimulatedCamera, SoftCapture, SoftDma, SoftRing};
pub use source::{cut_at_row_end, CameraStats, DcmiSource};
