//! The engine's memory: caller-provided, fixed-size, no heap.
//!
//! Budget (SPEC.md does not depend on it; validation does):
//! - per configured sub-aperture: 2 bytes (raster order) +
//!   `size_of::<SubapertureState>()` (level filter, seed, map bounds);
//! - per simultaneously open window (a window is open from its first row to
//!   its last, so a regular grid has one grid row of windows open):
//!   `size_of::<OpenWindow>()` + 2 bytes (free list); and one
//!   `OpenWindow` more, the row kernel's end mark after the last open one;
//! - per open window, a candidate buffer of `stride` entries of 8 bytes
//!   (value + position): the largest `select::preferred_capacity` over the
//!   windows (about `4 (N + 1) + 64`, at most the window's pixels; 0
//!   without selection) when the pool holds that for every open window,
//!   else what it holds, down to the largest `select::least_capacity`
//!   (about `2 (N + 1) + 32`): less room costs speed, never a result;
//! - a row history: the last `H` camera rows, `H` the tallest window that
//!   selects, 2 bytes per pixel, from which a window is rescanned when its
//!   seed left out a pixel it needed;
//! - scratch for the selection and a rescan: 12 bytes per pixel of the
//!   largest window that selects (at least `stride`).
//!
//! E.g. CANARY (112x112, 7x7 windows of 16x16, subtract-next N = 20):
//! 49 sub-apertures, 7 open windows, 7 x 148 candidate entries (7 x 74 at
//! least), 16 x 112 history pixels (3.5 KiB), 256 scratch entries. An 80x80
//! grid of 16x16 windows (6400 sub-apertures, ELT class): 80 open windows,
//! 80 x 148 entries (93 KiB; 46 KiB at least), 16 x 1280 history pixels
//! (40 KiB).

use super::select::Entry;
use super::window::{OpenWindow, SubapertureState};
use core::mem::offset_of;

/// Borrowed storage for an [`Engine`](super::Engine).
pub struct EngineMemory<'m> {
    /// One per sub-aperture: windows sorted by first row, then column.
    pub order: &'m mut [u16],
    /// One per sub-aperture.
    pub subapertures: &'m mut [SubapertureState],
    /// One per simultaneously open window, and one more: the open windows,
    /// by first column, and after the last of them the row kernel's end
    /// mark (`OpenWindow::mark_end`).
    pub open: &'m mut [OpenWindow],
    /// One per simultaneously open window (one less than `open`): the free
    /// candidate buffers.
    pub free: &'m mut [u16],
    /// Candidate buffers.
    pub entries: &'m mut [Entry],
    /// The last camera rows, row-major.
    pub history: &'m mut [u16],
    /// Scratch values for selections.
    pub scratch: &'m mut [i32],
    /// Scratch entries for a rescan, as many as `scratch`.
    pub rescan: &'m mut [Entry],
}

impl EngineMemory<'_> {
    /// How much of each kind this memory holds.
    pub fn capacity(&self) -> MemorySize {
        MemorySize {
            subapertures: self.order.len().min(self.subapertures.len()),
            open_windows: self.open.len().saturating_sub(1).min(self.free.len()),
            pool_entries: self.entries.len(),
            history_pixels: self.history.len(),
            scratch_entries: self.scratch.len().min(self.rescan.len()),
        }
    }
}

/// Sizes of the kinds of engine memory.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MemorySize {
    pub subapertures: usize,
    pub open_windows: usize,
    pub pool_entries: usize,
    pub history_pixels: usize,
    pub scratch_entries: usize,
}

impl MemorySize {
    /// Bytes these sizes take.
    pub const fn bytes(&self) -> usize {
        self.subapertures * (2 + core::mem::size_of::<SubapertureState>())
            + (self.open_windows + 1) * core::mem::size_of::<OpenWindow>()
            + self.open_windows * 2
            + self.pool_entries * 8
            + self.history_pixels * 2
            + self.scratch_entries * 12
    }
}

/// Memory for a board, sized at compile time, placeable in a `static`:
/// `SUBAPERTURES`, `OPEN` windows (and the end mark's slot), `ENTRIES`
/// candidate entries, `HISTORY` row-history pixels and `SCRATCH` scratch
/// entries.
pub struct StaticEngineMemory<
    const SUBAPERTURES: usize,
    const OPEN: usize,
    const ENTRIES: usize,
    const HISTORY: usize,
    const SCRATCH: usize,
> {
    order: [u16; SUBAPERTURES],
    subapertures: [SubapertureState; SUBAPERTURES],
    open: OpenSlots<OPEN>,
    free: [u16; OPEN],
    entries: [Entry; ENTRIES],
    history: [u16; HISTORY],
    scratch: [i32; SCRATCH],
    rescan: [Entry; SCRATCH],
}

impl<
        const SUBAPERTURES: usize,
        const OPEN: usize,
        const ENTRIES: usize,
        const HISTORY: usize,
        const SCRATCH: usize,
    > Default for StaticEngineMemory<SUBAPERTURES, OPEN, ENTRIES, HISTORY, SCRATCH>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<
        const SUBAPERTURES: usize,
        const OPEN: usize,
        const ENTRIES: usize,
        const HISTORY: usize,
        const SCRATCH: usize,
    > StaticEngineMemory<SUBAPERTURES, OPEN, ENTRIES, HISTORY, SCRATCH>
{
    pub const fn new() -> Self {
        StaticEngineMemory {
            order: [0; SUBAPERTURES],
            subapertures: [SubapertureState::RESET; SUBAPERTURES],
            open: OpenSlots {
                windows: [OpenWindow::CLOSED; OPEN],
                end: OpenWindow::CLOSED,
            },
            free: [0; OPEN],
            entries: [Entry::ZERO; ENTRIES],
            history: [0; HISTORY],
            scratch: [0; SCRATCH],
            rescan: [Entry::ZERO; SCRATCH],
        }
    }

    pub fn borrow(&mut self) -> EngineMemory<'_> {
        EngineMemory {
            order: &mut self.order,
            subapertures: &mut self.subapertures,
            open: self.open.as_slice(),
            free: &mut self.free,
            entries: &mut self.entries,
            history: &mut self.history,
            scratch: &mut self.scratch,
            rescan: &mut self.rescan,
        }
    }
}

/// `OPEN` open windows' slots and the end mark's after them, in one
/// slice (the const generics of stable Rust cannot size an array
/// `OPEN + 1`).
#[repr(C)]
struct OpenSlots<const OPEN: usize> {
    windows: [OpenWindow; OPEN],
    end: OpenWindow,
}

impl<const OPEN: usize> OpenSlots<OPEN> {
    fn as_slice(&mut self) -> &mut [OpenWindow] {
        // `end` right after the array, as the slice below needs.
        const { assert!(offset_of!(Self, end) == OPEN * size_of::<OpenWindow>()) };
        // SAFETY: `repr(C)` puts `end` right after the array, with no
        // padding (an `OpenWindow`'s size is a multiple of its alignment),
        // so the struct is `OPEN + 1` consecutive `OpenWindow`s, borrowed
        // mutably as a whole.
        unsafe { core::slice::from_raw_parts_mut(self as *mut Self as *mut OpenWindow, OPEN + 1) }
    }
}
