//! The engine: routes pixels, as they arrive in raster order, through
//! calibration and selection into the windows they belong to, and emits each
//! sub-aperture's result the moment its last pixel has been seen.
//!
//! Windows are opened at their first row (taking a pool slot) and closed after
//! their last, so only the windows crossing the current row hold state. The
//! open windows are kept in a list sorted by first column, and a cursor skips
//! those the current row has already passed, so a chunk touches only the
//! windows it overlaps, whatever its length.

use super::calibrate::Calibrator;
use super::centroid::{Centroider, SubapertureResult};
use super::memory::{EngineMemory, MemorySize};
use super::select::{
    below_capacity, heap_capacity, Rule, RuleKind, SelectionState, Slot, SubtractMeanRule,
    SubtractNextDistinctRule, SubtractNextRule, ThresholdRule,
};
use brightpix_protocol::{
    Config, ConfigError, MemoryKind, SelectionRule, SubapertureWindow, MAX_WINDOW_SIDE,
};

/// Pixels calibrated at once: at least a window's width, so that a block
/// started at a segment holds all of it.
const CALIBRATION_BLOCK: usize = 2 * MAX_WINDOW_SIDE as usize;

/// Where results go.
pub trait OutputSink {
    /// A sub-aperture's last pixel has arrived.
    fn subaperture(&mut self, result: SubapertureResult);
    /// The frame's last pixel has arrived; `frame` counts completed frames
    /// since the engine was configured, from 1.
    fn frame_complete(&mut self, _frame: u32) {}
}

impl<F: FnMut(SubapertureResult)> OutputSink for F {
    fn subaperture(&mut self, result: SubapertureResult) {
        self(result)
    }
}

/// A frame that cannot be processed (SPEC.md §8).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// A raw pixel above `2^bit_depth - 1`. The frame is abandoned.
    PixelOutOfRange { row: u16, column: u16, value: u16 },
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            FrameError::PixelOutOfRange { row, column, value } => write!(
                f,
                "pixel at row {row}, column {column} is {value}, above the camera's bit depth"
            ),
        }
    }
}

/// A window that has started receiving pixels in this frame.
#[derive(Clone, Copy, Debug)]
pub struct OpenWindow {
    index: u16,
    x: u16,
    end_column: u16,
    y: u16,
    last_row: u16,
    width: u16,
    height: u16,
    slot: u16,
    finished: bool,
    selection: SelectionState,
}

impl OpenWindow {
    pub const CLOSED: OpenWindow = OpenWindow {
        index: 0,
        x: 0,
        end_column: 0,
        y: 0,
        last_row: 0,
        width: 0,
        height: 0,
        slot: 0,
        finished: true,
        selection: SelectionState::EMPTY,
    };
}

/// The streaming brightest-pixel engine for one configuration.
pub struct Engine<'c, 'm> {
    config: Config<'c>,
    calibrator: Calibrator<'c>,
    centroider: Centroider<'c>,
    memory: EngineMemory<'m>,
    /// Pool entries per open window.
    stride: usize,
    max_raw: u16,
    row: u16,
    column: u16,
    /// Next window (in `memory.order`) to open.
    next_to_open: usize,
    active_len: usize,
    free_len: usize,
    /// Active windows before this one are done with the current row.
    cursor: usize,
    /// Some window's last pixel arrived in the current row.
    finished_in_row: bool,
    frames: u32,
    needed: MemorySize,
    /// Calibrated values of a block of the current row part.
    calibrated: [i32; CALIBRATION_BLOCK],
}

impl<'c, 'm> Engine<'c, 'm> {
    /// Validates `config` and checks it fits `memory`; resets the level
    /// filters (SPEC.md §4). On error nothing is kept (the caller's previous
    /// engine, if any, is untouched).
    pub fn new(config: Config<'c>, memory: EngineMemory<'m>) -> Result<Self, ConfigError> {
        let mut engine = Self::resume(config, memory)?;
        engine.reset_level_filters();
        Ok(engine)
    }

    /// As [`new`](Self::new), but keeps the level-filter state already in
    /// `memory`: for a caller that re-borrows the memory of an engine it
    /// built earlier with the same configuration.
    pub fn resume(config: Config<'c>, memory: EngineMemory<'m>) -> Result<Self, ConfigError> {
        let available = memory.capacity();
        let plan = plan(
            &config,
            available,
            memory.order,
            &mut memory.active[..available.open_windows],
        )?;
        let mut engine = Engine {
            config,
            calibrator: Calibrator::new(config.calibration),
            centroider: Centroider::new(config.centroid),
            memory,
            stride: plan.stride,
            max_raw: config.camera.max_raw(),
            row: 0,
            column: 0,
            next_to_open: 0,
            active_len: 0,
            free_len: 0,
            cursor: 0,
            finished_in_row: false,
            frames: 0,
            needed: plan.needed,
            calibrated: [0; CALIBRATION_BLOCK],
        };
        engine.start_frame();
        Ok(engine)
    }

    /// What [`new`](Self::new) would answer for `config` and memory of
    /// `capacity`, without touching any engine's memory: `order` and
    /// `scratch` are scratch space of at least `config.windows.len()`
    /// entries each. Lets a caller vet a configuration while another engine
    /// keeps running.
    pub fn check(
        config: &Config<'_>,
        capacity: MemorySize,
        order: &mut [u16],
        scratch: &mut [u16],
    ) -> Result<MemorySize, ConfigError> {
        plan(config, capacity, order, scratch).map(|plan| plan.needed)
    }

    /// The memory this configuration uses (see `memory.rs` for the budget).
    pub fn memory_needed(&self) -> MemorySize {
        self.needed
    }

    pub fn config(&self) -> &Config<'c> {
        &self.config
    }

    /// Frames completed since configuration.
    pub fn frames_completed(&self) -> u32 {
        self.frames
    }

    /// Position of the next expected pixel: (row, column).
    pub fn position(&self) -> (u16, u16) {
        (self.row, self.column)
    }

    /// Whether the engine is between frames (no pixel of a frame seen yet).
    pub fn at_frame_start(&self) -> bool {
        self.row == 0 && self.column == 0
    }

    /// Forgets the temporally filtered levels (SPEC.md §4).
    pub fn reset_level_filters(&mut self) {
        let count = self.config.windows.len();
        for state in &mut self.memory.level_filters[..count] {
            *state = super::level_filter::LevelFilterState::RESET;
        }
    }

    /// Drops a partly received frame; the next pixel starts a new frame.
    pub fn abort_frame(&mut self) {
        self.start_frame();
    }

    /// Feeds the next pixels of the frame, in raster order, in a chunk of any
    /// length (it may end mid-row or run into the next frame).
    pub fn push(&mut self, pixels: &[u16], sink: &mut impl OutputSink) -> Result<(), FrameError> {
        match self.config.selection.rule {
            SelectionRule::Threshold => self.push_with::<ThresholdRule>(pixels, sink),
            SelectionRule::SubtractNext => self.push_with::<SubtractNextRule>(pixels, sink),
            SelectionRule::SubtractNextDistinct => {
                self.push_with::<SubtractNextDistinctRule>(pixels, sink)
            }
            SelectionRule::SubtractMean { .. } => self.push_with::<SubtractMeanRule>(pixels, sink),
        }
    }

    fn push_with<R: Rule>(
        &mut self,
        mut pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), FrameError> {
        let width = self.config.camera.width;
        while !pixels.is_empty() {
            let take = pixels.len().min((width - self.column) as usize);
            let (part, rest) = pixels.split_at(take);
            if self.max_raw != u16::MAX {
                if let Some(bad) = part.iter().position(|&r| r > self.max_raw) {
                    self.push_row_part::<R>(&part[..bad], sink);
                    let error = FrameError::PixelOutOfRange {
                        row: self.row,
                        column: self.column + bad as u16,
                        value: part[bad],
                    };
                    self.start_frame();
                    return Err(error);
                }
            }
            self.push_row_part::<R>(part, sink);
            self.column += take as u16;
            if self.column == width {
                self.end_row(sink);
            }
            pixels = rest;
        }
        Ok(())
    }

    /// Pixels `column .. column + part.len()` of the current row.
    #[inline(always)]
    fn push_row_part<R: Rule>(&mut self, part: &[u16], sink: &mut impl OutputSink) {
        let start = self.column;
        let end = start + part.len() as u16;
        let row = self.row;
        let row_offset = row as usize * self.config.camera.width as usize;
        // subtract-mean's "below" heap, after the heap in a selecting slot.
        let below_len = match self.config.selection.rule {
            SelectionRule::SubtractMean { count } => count as usize,
            _ => 0,
        };
        let memory = &mut self.memory;
        // Columns whose calibrated values are in `self.calibrated`.
        let mut block = (start, start);
        let mut k = self.cursor;
        while k < self.active_len {
            let slot = memory.active[k] as usize;
            let (x, end_column) = (memory.open[slot].x, memory.open[slot].end_column);
            if x >= end {
                break;
            }
            let from = x.max(start);
            let to = end_column.min(end);
            if from < to {
                // Calibrate a block of the row part from this segment on, unless
                // an earlier segment's block covers it already (the active list
                // is sorted by first column, so `from` never decreases). The
                // block goes beyond the segment only if the next window starts
                // within it, so pixels between windows are not calibrated.
                if to > block.1 {
                    let next_x = match memory.active[..self.active_len].get(k + 1) {
                        Some(&next) => memory.open[next as usize].x,
                        None => u16::MAX,
                    };
                    let block_end = if next_x <= to {
                        end.min(from + CALIBRATION_BLOCK as u16)
                    } else {
                        to
                    };
                    self.calibrator.calibrate(
                        &part[(from - start) as usize..(block_end - start) as usize],
                        row_offset + from as usize,
                        &mut self.calibrated,
                    );
                    block = (from, block_end);
                }
                let calibrated =
                    &self.calibrated[(from - block.0) as usize..(to - block.0) as usize];
                let window = &mut memory.open[slot];
                let selection = &mut window.selection;
                let capacity = selection.capacity() as usize;
                let base = window.slot as usize * self.stride;
                // A full heap rejects a whole segment below its minimum at once
                // (the common case); only then is the segment's maximum needed.
                let rejected = if capacity > 0 && selection.is_full() {
                    selection.rejects::<R>(calibrated)
                } else {
                    None
                };
                if let Some(max) = rejected {
                    let below = match R::RULE {
                        RuleKind::SubtractMean => {
                            &mut memory.values[base + capacity..][..below_len]
                        }
                        _ => &mut [],
                    };
                    selection.reject::<R>(below, calibrated, max);
                } else {
                    let mut slot = Slot::at(
                        memory.values,
                        memory.positions,
                        base,
                        capacity,
                        if capacity > 0 { below_len } else { 0 },
                    );
                    selection.push::<R>(&mut slot, calibrated, from - window.x, row - window.y);
                }
                if to == window.end_column && row == window.last_row {
                    let capacity = window.selection.capacity() as usize;
                    let slot = Slot::at(
                        memory.values,
                        memory.positions,
                        base,
                        capacity,
                        if capacity > 0 { below_len } else { 0 },
                    );
                    let filter = self.config.selection.level_filter.map(|f| {
                        (
                            &mut memory.level_filters[window.index as usize],
                            f.gain_shift,
                        )
                    });
                    let moments = window.selection.finish::<R>(&slot, filter);
                    window.finished = true;
                    self.finished_in_row = true;
                    sink.subaperture(self.centroider.result(
                        window.index,
                        moments,
                        window.width,
                        window.height,
                    ));
                }
            }
            if k == self.cursor && end_column <= end {
                self.cursor += 1;
            }
            k += 1;
        }
    }

    fn end_row(&mut self, sink: &mut impl OutputSink) {
        if self.finished_in_row {
            // Close finished windows, keeping the active list in column order.
            let memory = &mut self.memory;
            let mut kept = 0;
            for k in 0..self.active_len {
                let slot = memory.active[k];
                if memory.open[slot as usize].finished {
                    memory.free[self.free_len] = slot;
                    self.free_len += 1;
                } else {
                    memory.active[kept] = slot;
                    kept += 1;
                }
            }
            self.active_len = kept;
            self.finished_in_row = false;
        }
        self.cursor = 0;
        self.column = 0;
        self.row += 1;
        if self.row == self.config.camera.height {
            self.frames = self.frames.wrapping_add(1);
            sink.frame_complete(self.frames);
            self.start_frame();
        } else if self.opens_windows_in_row() {
            self.open_windows_of_row();
        }
    }

    /// Whether some window's first row is the current row (most rows open
    /// none: a cheap test before the loop, whose set-up is not).
    #[inline(always)]
    fn opens_windows_in_row(&self) -> bool {
        let windows = self.config.windows;
        self.memory.order[..windows.len()]
            .get(self.next_to_open)
            .is_some_and(|&index| windows[index as usize].y == self.row)
    }

    fn start_frame(&mut self) {
        let open = self.memory.capacity().open_windows;
        for (k, f) in self.memory.free[..open].iter_mut().enumerate() {
            *f = (open - 1 - k) as u16;
        }
        self.free_len = open;
        self.active_len = 0;
        self.cursor = 0;
        self.finished_in_row = false;
        self.row = 0;
        self.column = 0;
        self.next_to_open = 0;
        self.open_windows_of_row();
    }

    /// Opens the windows whose first row is the current row.
    fn open_windows_of_row(&mut self) {
        let windows = self.config.windows;
        while self.next_to_open < windows.len() {
            let index = self.memory.order[self.next_to_open] as usize;
            let w = windows[index];
            if w.y != self.row {
                break;
            }
            self.next_to_open += 1;
            // Capacity was proved sufficient when the engine was configured.
            self.free_len -= 1;
            let slot = self.memory.free[self.free_len];
            self.memory.open[slot as usize] = OpenWindow {
                index: index as u16,
                x: w.x,
                end_column: w.end_column(),
                y: w.y,
                last_row: w.last_row(),
                width: w.width,
                height: w.height,
                slot,
                finished: false,
                selection: SelectionState::new(capacity_of(&self.config, index)),
            };
            // Insert into the active list, sorted by first column.
            let active = &mut self.memory.active;
            let open = &self.memory.open;
            let mut k = self.active_len;
            while k > 0 && open[active[k - 1] as usize].x > w.x {
                active[k] = active[k - 1];
                k -= 1;
            }
            active[k] = slot;
            self.active_len += 1;
        }
    }
}

/// Sizes of an engine for a configuration.
struct Plan {
    /// Pool entries per open window.
    stride: usize,
    needed: MemorySize,
}

/// Validates `config`, sorts its windows into `order` (by first row, then
/// column) and sizes the engine, using `heap` as scratch for counting open
/// windows; fails if it does not fit `available`.
fn plan(
    config: &Config<'_>,
    available: MemorySize,
    order: &mut [u16],
    heap: &mut [u16],
) -> Result<Plan, ConfigError> {
    config.validate()?;
    let windows = config.windows;
    let count = windows.len();
    let subapertures = available.subapertures.min(order.len());
    if count > subapertures {
        return Err(ConfigError::MemoryBudget {
            needed: count,
            available: subapertures,
            what: MemoryKind::Subapertures,
        });
    }
    let order = &mut order[..count];
    for (k, o) in order.iter_mut().enumerate() {
        *o = k as u16;
    }
    order.sort_unstable_by_key(|&k| (windows[k as usize].y, windows[k as usize].x));
    let stride = (0..count)
        .map(|k| {
            let c = capacity_of(config, k);
            c as usize + below_capacity(config.selection.rule, c) as usize
        })
        .max()
        .unwrap_or(0);
    let open = match count_open_windows(windows, order, heap) {
        Some(open) if open <= available.open_windows => open,
        found => {
            return Err(ConfigError::MemoryBudget {
                needed: found.unwrap_or_else(|| count_open_windows_slowly(windows)),
                available: available.open_windows,
                what: MemoryKind::OpenWindows,
            })
        }
    };
    let needed = MemorySize {
        subapertures: count,
        open_windows: open,
        pool_entries: open * stride,
    };
    if needed.pool_entries > available.pool_entries {
        return Err(ConfigError::MemoryBudget {
            needed: needed.pool_entries,
            available: available.pool_entries,
            what: MemoryKind::SelectionEntries,
        });
    }
    Ok(Plan { stride, needed })
}

fn capacity_of(config: &Config<'_>, index: usize) -> u16 {
    heap_capacity(
        config.selection.rule,
        config.pixel_count(index),
        config.windows[index].pixel_count(),
    )
}

/// The largest number of windows open at once over a frame, using `heap`
/// as a min-heap of last rows; `None` if more than `heap.len()`.
fn count_open_windows(
    windows: &[SubapertureWindow],
    order: &[u16],
    heap: &mut [u16],
) -> Option<usize> {
    let mut len = 0usize;
    let mut most = 0usize;
    for &k in order {
        let w = windows[k as usize];
        // Close the windows that ended before this one's first row.
        while len > 0 && heap[0] < w.y {
            len -= 1;
            heap[0] = heap[len];
            sift_down_rows(&mut heap[..len]);
        }
        if len == heap.len() {
            return None;
        }
        heap[len] = w.last_row();
        len += 1;
        sift_up_rows(&mut heap[..len]);
        most = most.max(len);
    }
    Some(most)
}

/// Exact count for the error message, without memory: O(windows^2).
fn count_open_windows_slowly(windows: &[SubapertureWindow]) -> usize {
    windows
        .iter()
        .map(|a| {
            windows
                .iter()
                .filter(|b| b.y <= a.y && a.y <= b.last_row())
                .count()
        })
        .max()
        .unwrap_or(0)
}

fn sift_up_rows(heap: &mut [u16]) {
    let mut i = heap.len() - 1;
    while i > 0 {
        let parent = (i - 1) / 2;
        if heap[parent] <= heap[i] {
            break;
        }
        heap.swap(i, parent);
        i = parent;
    }
}

fn sift_down_rows(heap: &mut [u16]) {
    let mut i = 0;
    loop {
        let left = 2 * i + 1;
        if left >= heap.len() {
            break;
        }
        let right = left + 1;
        let child = if right < heap.len() && heap[right] < heap[left] {
            right
        } else {
            left
        };
        if heap[child] >= heap[i] {
            break;
        }
        heap.swap(i, child);
        i = child;
    }
}
