//! The engine's memory: caller-provided, fixed-size, no heap.
//!
//! Budget (SPEC.md does not depend on it; validation does):
//! - per configured sub-aperture: 2 bytes (raster order) + 16 bytes (level
//!   filter state);
//! - per simultaneously open window (a window is open from its first row to
//!   its last, so a regular grid has one grid row of windows open):
//!   `size_of::<OpenWindow>()` + 4 bytes (active list, free list);
//! - per open window, a pool slot of `stride` entries of 6 bytes (value +
//!   position), `stride = max(C + M)` over windows, where `C = N` (`N + 1`
//!   for subtract-next; 0 without selection) and `M` is subtract-mean's count.
//!
//! E.g. an 80x80 grid of 16x16 windows (6400 sub-apertures, ELT class),
//! subtract-next N = 20: 115 KiB for the sub-apertures, 80 open windows,
//! 80 x 21 pool entries (10 KiB).

use super::level_filter::LevelFilterState;
use super::stream::OpenWindow;

/// Borrowed storage for an [`Engine`](super::Engine).
pub struct EngineMemory<'m> {
    /// One per sub-aperture: windows sorted by first row, then column.
    pub order: &'m mut [u16],
    /// One per sub-aperture.
    pub level_filters: &'m mut [LevelFilterState],
    /// One per simultaneously open window.
    pub open: &'m mut [OpenWindow],
    /// Same length as `open`.
    pub active: &'m mut [u16],
    /// Same length as `open`.
    pub free: &'m mut [u16],
    /// Selection pool: heap values and subtract-mean's values.
    pub values: &'m mut [i32],
    /// Same length as `values`.
    pub positions: &'m mut [u16],
}

impl EngineMemory<'_> {
    /// How many sub-apertures, open windows and pool entries this memory holds.
    pub fn capacity(&self) -> MemorySize {
        MemorySize {
            subapertures: self.order.len().min(self.level_filters.len()),
            open_windows: self.open.len().min(self.active.len()).min(self.free.len()),
            pool_entries: self.values.len().min(self.positions.len()),
        }
    }
}

/// Sizes of the three kinds of engine memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemorySize {
    pub subapertures: usize,
    pub open_windows: usize,
    pub pool_entries: usize,
}

impl MemorySize {
    /// Bytes these sizes take.
    pub const fn bytes(&self) -> usize {
        self.subapertures * (2 + core::mem::size_of::<LevelFilterState>())
            + self.open_windows * (core::mem::size_of::<OpenWindow>() + 4)
            + self.pool_entries * 6
    }
}

/// Memory for a board, sized at compile time, placeable in a `static`.
pub struct StaticEngineMemory<const SUBAPERTURES: usize, const OPEN: usize, const ENTRIES: usize> {
    order: [u16; SUBAPERTURES],
    level_filters: [LevelFilterState; SUBAPERTURES],
    open: [OpenWindow; OPEN],
    active: [u16; OPEN],
    free: [u16; OPEN],
    values: [i32; ENTRIES],
    positions: [u16; ENTRIES],
}

impl<const SUBAPERTURES: usize, const OPEN: usize, const ENTRIES: usize> Default
    for StaticEngineMemory<SUBAPERTURES, OPEN, ENTRIES>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const SUBAPERTURES: usize, const OPEN: usize, const ENTRIES: usize>
    StaticEngineMemory<SUBAPERTURES, OPEN, ENTRIES>
{
    pub const fn new() -> Self {
        StaticEngineMemory {
            order: [0; SUBAPERTURES],
            level_filters: [LevelFilterState::RESET; SUBAPERTURES],
            open: [OpenWindow::CLOSED; OPEN],
            active: [0; OPEN],
            free: [0; OPEN],
            values: [0; ENTRIES],
            positions: [0; ENTRIES],
        }
    }

    pub fn borrow(&mut self) -> EngineMemory<'_> {
        EngineMemory {
            order: &mut self.order,
            level_filters: &mut self.level_filters,
            open: &mut self.open,
            active: &mut self.active,
            free: &mut self.free,
            values: &mut self.values,
            positions: &mut self.positions,
        }
    }
}
