//! The engine: routes pixels, as they arrive in raster order, to the windows
//! they belong to, and emits each sub-aperture's result the moment its last
//! pixel has been seen.
//!
//! Windows are opened at their first row (taking a candidate buffer from the
//! pool) and closed after their last, so only the windows crossing the
//! current row hold state. The open windows are kept in the engine's memory
//! in order of first column, and a cursor skips those the current row has
//! already passed, so a chunk touches only the windows it overlaps,
//! whatever its length.
//!
//! A whole camera row goes to the row kernel (`scan::row`): every open
//! window's run of pixels in the row (its *segment*) in one call, each pair
//! of raw pixels tested against the window's raw floor with one
//! instruction, and the pixels that can reach its admission threshold
//! calibrated and made candidates (see `select.rs`). The kernel stops at a
//! window that needs more than that (its candidates now prove the cutoff
//! is at or above the hint, or it is short of room: [`Engine::attend`]).
//! What the kernel does not take (a chunk that ends inside a window,
//! windows without selection or awaiting a rescan, odd columns) takes the
//! general path, a window at a time. Pixels that belong to no window are
//! only checked against the camera's bit depth.

use super::calibrate::{self, raw_floor, Calibrator, Steps, WindowBounds, With};
use super::centroid::{Centroider, Moments, SubapertureResult};
use super::memory::{EngineMemory, MemorySize};
use super::plan::plan;
use super::prefilter;
use super::scan::{self, scan, RowScan, RowStop, Segment, Stop};
use super::select::{self, pack, preferred_capacity, Buffer, Cut, Entry, Tiers, Ties, WindowRule};
use super::window::{OpenWindow, SegmentPath, SubapertureState};
use brightpix_protocol::{Calibration, Config, ConfigError, SelectionRule, MAX_WINDOW_SIDE};

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
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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

/// How often the engine took its slow paths, since it was built. Speed
/// only: results do not depend on them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EngineStats {
    /// Windows finished with selection.
    pub windows: u32,
    /// Candidates those windows held at their end (buffer and ties).
    pub candidates: u32,
    /// Candidate buffers that filled and were compacted.
    pub compactions: u32,
    /// Windows computed again from the row history.
    pub rescans: u32,
    /// Times the row kernel stopped at a window for the engine's
    /// attention (`Engine::attend`).
    pub attentions: u32,
}

/// The streaming brightest-pixel engine for one configuration.
pub struct Engine<'c, 'm> {
    config: Config<'c>,
    calibrator: Calibrator<'c>,
    centroider: Centroider<'c>,
    memory: EngineMemory<'m>,
    /// The address of the candidate pool's first entry: a window's buffer
    /// is `stride` entries from `pool + number * stride`.
    pool: usize,
    /// Candidate entries per open window.
    stride: usize,
    /// Rows in the history ring (0: no window selects, none kept).
    history_rows: usize,
    /// Where the current row starts in the history ring
    /// (`(row % history_rows) * width`).
    history_row: usize,
    max_raw: u16,
    row: u16,
    column: u16,
    /// Next window (in `memory.order`) to open.
    next_to_open: usize,
    /// Open windows: `memory.open[..open_len]`, by first column.
    open_len: usize,
    free_len: usize,
    /// Open windows before this one are done with the current row.
    cursor: usize,
    /// Some window's last pixel arrived in the current row.
    finished_in_row: bool,
    /// The open windows do not overlap (each ends at or before the next
    /// one's first column): a whole row can take [`Self::push_whole_row`].
    disjoint: bool,
    /// The open windows cover the camera row with no gap: no pixel of a
    /// row lies outside a window (so the row kernel, which checks only the
    /// windows' pixels against the bit depth, checks them all).
    gapless: bool,
    /// Open windows the row kernel skips (not `kernel_ready`).
    not_ready: usize,
    /// The earliest last row of an open window.
    next_last_row: u16,
    /// The row kernel's arguments, kept from row to row: the open windows
    /// (`first .. end`, set with the layout), the maps' addresses for the
    /// current row (advanced by `end_row`).
    scan: RowScan,
    /// The address of the current row's first background value (0 without
    /// a map), and its packed row (`row << 6`).
    bg_row: usize,
    position_row: u32,
    frames: u32,
    needed: MemorySize,
    stats: EngineStats,
    /// Calibrated values of one segment of a window without selection.
    calibrated: [i32; MAX_WINDOW_SIDE as usize],
}

impl<'c, 'm> Engine<'c, 'm> {
    /// Validates `config` and checks it fits `memory`; resets the level
    /// filters (SPEC.md §4) and seeds. On error nothing is kept (the
    /// caller's previous engine, if any, is untouched).
    pub fn new(config: Config<'c>, memory: EngineMemory<'m>) -> Result<Self, ConfigError> {
        let mut engine = Self::resume(config, memory)?;
        engine.reset_level_filters();
        Ok(engine)
    }

    /// As [`new`](Self::new), but keeps the level-filter state and seeds
    /// already in `memory`: for a caller that re-borrows the memory of an
    /// engine it built earlier with the same configuration.
    pub fn resume(config: Config<'c>, memory: EngineMemory<'m>) -> Result<Self, ConfigError> {
        let available = memory.capacity();
        let plan = plan(
            &config,
            available,
            memory.order,
            &mut memory.free[..available.open_windows],
        )?;
        let maps = config.calibration.background.is_some() || config.calibration.gain.is_some();
        for (state, window) in memory.subapertures.iter_mut().zip(config.windows) {
            state.bounds = if maps {
                WindowBounds::of(&config, window)
            } else {
                WindowBounds::NONE
            };
        }
        let pool = memory.entries.as_mut_ptr() as usize;
        let mut engine = Engine {
            config,
            calibrator: Calibrator::new(config.calibration),
            centroider: Centroider::new(config.centroid),
            memory,
            pool,
            stride: plan.stride,
            history_rows: plan.history_rows,
            history_row: 0,
            max_raw: config.camera.max_raw(),
            row: 0,
            column: 0,
            next_to_open: 0,
            open_len: 0,
            // Not the open windows' count: `start_frame` lists the free
            // buffers afresh.
            free_len: usize::MAX,
            cursor: 0,
            finished_in_row: false,
            disjoint: true,
            gapless: false,
            not_ready: 0,
            next_last_row: u16::MAX,
            scan: RowScan {
                row: 0,
                first: 0,
                end: 0,
                bg_delta: 0,
                position_delta: 0,
                max_raw: config.camera.max_raw() as u32,
                bad: 0,
                gain_row: 0,
                threshold: config.calibration.threshold.unwrap_or(i32::MIN),
            },
            bg_row: 0,
            position_row: 0,
            frames: 0,
            needed: plan.needed,
            stats: EngineStats::default(),
            calibrated: [0; MAX_WINDOW_SIDE as usize],
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

    /// How often the slow paths ran since this engine was built.
    pub fn stats(&self) -> EngineStats {
        self.stats
    }

    /// Position of the next expected pixel: (row, column).
    pub fn position(&self) -> (u16, u16) {
        (self.row, self.column)
    }

    /// Whether the engine is between frames (no pixel of a frame seen yet).
    pub fn at_frame_start(&self) -> bool {
        self.row == 0 && self.column == 0
    }

    /// Forgets the temporally filtered levels (SPEC.md §4), and the seeds.
    pub fn reset_level_filters(&mut self) {
        let count = self.config.windows.len();
        for state in &mut self.memory.subapertures[..count] {
            state.level = SubapertureState::RESET.level;
            state.seed = SubapertureState::RESET.seed;
        }
    }

    /// Drops a partly received frame; the next pixel starts a new frame.
    pub fn abort_frame(&mut self) {
        self.start_frame();
    }

    /// Feeds the next pixels of the frame, in raster order, in a chunk of any
    /// length (it may end mid-row or run into the next frame).
    pub fn push(&mut self, pixels: &[u16], sink: &mut impl OutputSink) -> Result<(), FrameError> {
        let c = self.config.calibration;
        let check = self.max_raw != u16::MAX;
        macro_rules! with {
            ($b:literal, $g:literal, $t:literal) => {
                if check {
                    self.push_with::<With<$b, $g, $t>, true>(pixels, sink)
                } else {
                    self.push_with::<With<$b, $g, $t>, false>(pixels, sink)
                }
            };
        }
        match (
            c.background.is_some(),
            c.gain.is_some(),
            c.threshold.is_some(),
        ) {
            (false, false, false) => with!(false, false, false),
            (false, false, true) => with!(false, false, true),
            (true, false, false) => with!(true, false, false),
            (true, false, true) => with!(true, false, true),
            (false, true, false) => with!(false, true, false),
            (false, true, true) => with!(false, true, true),
            (true, true, false) => with!(true, true, false),
            (true, true, true) => with!(true, true, true),
        }
    }

    /// `S`: the calibration steps; `CHECK`: whether raw pixels must be
    /// checked against the bit depth (below 16 bits).
    fn push_with<S: Steps, const CHECK: bool>(
        &mut self,
        mut pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), FrameError> {
        let width = self.config.camera.width;
        while !pixels.is_empty() {
            // A frame's first row opens its windows here, when its first
            // pixel arrives (`start_frame` does not), so that the work after
            // a frame's last pixel is only its results; the other rows open
            // theirs at the end of the row before (`end_row`).
            if self.row == 0 && self.column == 0 && self.next_to_open == 0 {
                self.open_windows_of_row();
            }
            let take = pixels.len().min((width - self.column) as usize);
            let (part, rest) = pixels.split_at(take);
            if self.history_rows > 0 {
                let at = self.history_row + self.column as usize;
                // SAFETY: the ring holds `history_rows` camera rows (plan),
                // `history_row` is one of them and the part lies in it.
                let to = unsafe { self.memory.history.get_unchecked_mut(at..at + take) };
                copy_pixels(part, to);
            }
            let pushed = if take == width as usize {
                self.push_whole_row::<S, CHECK>(part, sink)
            } else {
                self.push_row_part::<S, CHECK>(part, sink)
            };
            if let Err(bad) = pushed {
                let error = FrameError::PixelOutOfRange {
                    row: self.row,
                    column: self.column + bad as u16,
                    value: part[bad],
                };
                self.start_frame();
                return Err(error);
            }
            self.column += take as u16;
            if self.column == width {
                self.end_row(sink);
            }
            pixels = rest;
        }
        Ok(())
    }

    /// A whole camera row. On a pixel out of range, returns its column; the
    /// windows whose last pixel came before it have been emitted, no other.
    ///
    /// Windows are visited in column order: each run of `kernel_ready` ones
    /// by the row kernel, the others on the general path. That needs a
    /// word-aligned row, and below 16 bits (where the first pixel out of
    /// range must be found in raster order) every pixel of the row in a
    /// window, since only windows' pixels are checked.
    #[inline(always)]
    fn push_whole_row<S: Steps, const CHECK: bool>(
        &mut self,
        row_pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        let row_address = row_pixels.as_ptr() as usize;
        if row_address & 3 != 0 || (CHECK && !self.gapless) {
            return self.push_whole_row_general::<S, CHECK>(row_pixels, sink);
        }
        let row = self.row;
        let mut k = 0;
        while k < self.open_len {
            let ready = |w: &OpenWindow| w.segment_start != w.segment_end;
            let end = if self.not_ready == 0 {
                self.open_len
            } else if !ready(&self.memory.open[k]) {
                let w = &self.memory.open[k];
                let (x, end, y) = (w.x as usize, w.end_column as usize, w.y);
                let pixel = row as usize * row_pixels.len() + x;
                if let Err(b) = self.segment::<S, CHECK>(k, &row_pixels[x..end], pixel, 0, row - y)
                {
                    self.finish_before(k, sink);
                    return Err(x + b);
                }
                k += 1;
                continue;
            } else {
                // A run of ready windows (none becomes ready or not before
                // the kernel has passed it).
                let mut end = k + 1;
                while end < self.open_len && ready(&self.memory.open[end]) {
                    end += 1;
                }
                end
            };
            if let Some((window, pixel)) = self.kernel_run::<S, CHECK>(row_address, k, end) {
                self.finish_before(window, sink);
                return Err((pixel - row_address) / 2);
            }
            k = end;
        }
        if row == self.next_last_row {
            for k in 0..self.open_len {
                if self.memory.open[k].last_row == row {
                    self.finish(k, sink);
                }
            }
        }
        Ok(())
    }

    /// The row kernel over the open windows `k .. end` (all
    /// `kernel_ready`), of the current row at `row_address` (word-aligned).
    /// On a pixel out of range (`CHECK`), the index of its window and its
    /// address.
    fn kernel_run<S: Steps, const CHECK: bool>(
        &mut self,
        row_address: usize,
        k: usize,
        end: usize,
    ) -> Option<(usize, usize)> {
        const SIZE: usize = core::mem::size_of::<OpenWindow>();
        let (first, all) = (self.scan.first, self.scan.end);
        self.scan.row = row_address;
        self.scan.bg_delta = self.bg_row.wrapping_sub(2 * row_address).wrapping_sub(16);
        self.scan.position_delta = self
            .position_row
            .wrapping_sub(4)
            .wrapping_sub((row_address >> 1) as u32);
        self.scan.first = first + k * SIZE;
        self.scan.end = first + end * SIZE;
        let stopped = loop {
            // SAFETY: the windows `k .. end` are kernel-ready and their
            // segments lie in the part of the row the caller holds.
            match unsafe { scan::row::<S, CHECK>(&mut self.scan) } {
                RowStop::Done => break None,
                RowStop::Attention(address) => {
                    self.attend((address - first) / SIZE);
                    self.scan.first = address + SIZE;
                }
                RowStop::OutOfRange { window, pixel } => {
                    break Some(((window - first) / SIZE, pixel))
                }
            }
        };
        self.scan.first = first;
        self.scan.end = all;
        stopped
    }

    /// A pixel out of range in window `k`'s segment of a gapless row: the
    /// windows before it that end in this row are complete.
    #[cold]
    fn finish_before(&mut self, k: usize, sink: &mut impl OutputSink) {
        for j in 0..k {
            if self.memory.open[j].last_row == self.row {
                self.finish(j, sink);
            }
        }
    }

    /// [`push_whole_row`](Self::push_whole_row) a window at a time, on the
    /// general path: for rows the kernel cannot take. Windows are visited
    /// left to right and each gap is checked before the window after it.
    fn push_whole_row_general<S: Steps, const CHECK: bool>(
        &mut self,
        row_pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        if !self.disjoint {
            return self.push_row_part::<S, CHECK>(row_pixels, sink);
        }
        let row = self.row;
        let row_offset = row as usize * row_pixels.len();
        let mut checked = 0;
        for k in 0..self.open_len {
            let window = &self.memory.open[k];
            let (x, end) = (window.x as usize, window.end_column as usize);
            let (last, y) = (row == window.last_row, window.y);
            if CHECK && x > checked {
                check_range(&row_pixels[checked..x], self.max_raw).map_err(|b| checked + b)?;
            }
            self.segment::<S, CHECK>(k, &row_pixels[x..end], row_offset + x, 0, row - y)
                .map_err(|b| x + b)?;
            if last {
                self.finish(k, sink);
            }
            checked = end;
        }
        if CHECK && checked < row_pixels.len() {
            check_range(&row_pixels[checked..], self.max_raw).map_err(|b| checked + b)?;
        }
        Ok(())
    }

    /// Pixels `column .. column + part.len()` of the current row. On a pixel
    /// out of range, returns its offset in `part`; every window whose last
    /// pixel came before it has been emitted, no other.
    ///
    /// Why that holds in one pass: windows are visited by first column and
    /// each one's segment is checked pixel by pixel in order (the
    /// pre-filter never skips an out-of-range pixel, see
    /// `OpenWindow::floor`), the gaps between windows when they are passed.
    /// So the first bad pixel found, at column `c`, is the first of the part:
    /// everything before it was covered by an earlier window's segment, a
    /// gap, or the finding window's own segment. The part is then cut at
    /// `c`, and the remaining windows see only their pixels before it: those
    /// that end there are still emitted, as they must be.
    fn push_row_part<S: Steps, const CHECK: bool>(
        &mut self,
        part: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        let start = self.column;
        let mut end = start + part.len() as u16;
        let mut bad = None;
        let row = self.row;
        let row_offset = row as usize * self.config.camera.width as usize;
        // Columns checked against the bit depth so far.
        let mut checked = start;
        let mut k = self.cursor;
        // The row's first pixel's address, if word-aligned: then the windows
        // wholly inside the part take the row kernel, in runs (below 16
        // bits, runs of windows without gaps between them, the gap before
        // a run checked first, so that the first pixel out of range is
        // still found in raster order).
        let row_address = (part.as_ptr() as usize).wrapping_sub(2 * start as usize);
        let kernel = row_address & 3 == 0;
        while k < self.open_len {
            if kernel {
                let inside = |w: &OpenWindow, end: u16| {
                    w.segment_start != w.segment_end && w.x >= start && w.end_column <= end
                };
                let x = self.memory.open[k].x;
                if CHECK && bad.is_none() && x > checked && inside(&self.memory.open[k], end) {
                    let gap = (checked - start) as usize..(x - start) as usize;
                    if let Err(b) = check_range(&part[gap.clone()], self.max_raw) {
                        bad = Some(gap.start + b);
                        end = start + (gap.start + b) as u16;
                    }
                }
                if inside(&self.memory.open[k], end) {
                    let mut run_end = k + 1;
                    while run_end < self.open_len
                        && inside(&self.memory.open[run_end], end)
                        && (!CHECK
                            || self.memory.open[run_end].x
                                == self.memory.open[run_end - 1].end_column)
                    {
                        run_end += 1;
                    }
                    let done = match self.kernel_run::<S, CHECK>(row_address, k, run_end) {
                        None => run_end,
                        Some((w, pixel)) => {
                            let b = (pixel - part.as_ptr() as usize) / 2;
                            bad = Some(b);
                            end = start + b as u16;
                            w
                        }
                    };
                    for j in k..done {
                        if self.memory.open[j].last_row == row {
                            self.finish(j, sink);
                        }
                    }
                    if CHECK && done > k {
                        checked = checked.max(self.memory.open[done - 1].end_column);
                    }
                    if self.cursor == k {
                        self.cursor = done;
                    }
                    // On a pixel out of range, its window is abandoned with
                    // the frame (and every window after it in the run
                    // starts after that pixel).
                    k = if done < run_end { done + 1 } else { done };
                    continue;
                }
            }
            let window = &self.memory.open[k];
            let (x, end_column, y, last_row) =
                (window.x, window.end_column, window.y, window.last_row);
            if x >= end {
                break;
            }
            let from = x.max(start);
            if CHECK && bad.is_none() && from > checked {
                let gap = (checked - start) as usize..(from - start) as usize;
                if let Err(b) = check_range(&part[gap.clone()], self.max_raw) {
                    bad = Some(gap.start + b);
                    end = start + (gap.start + b) as u16;
                    if x >= end {
                        break;
                    }
                }
            }
            let to = end_column.min(end);
            if from < to {
                let at = (from - start) as usize;
                let checked_segment = self.segment::<S, CHECK>(
                    k,
                    &part[at..(to - start) as usize],
                    row_offset + from as usize,
                    from - x,
                    row - y,
                );
                match checked_segment {
                    Ok(()) => {
                        if to == end_column && row == last_row {
                            self.finish(k, sink);
                        }
                    }
                    Err(b) => {
                        bad = Some(at + b);
                        end = from + b as u16;
                    }
                }
                if CHECK {
                    checked = checked.max(to);
                }
            }
            if k == self.cursor && end_column <= end {
                self.cursor += 1;
            }
            k += 1;
        }
        if CHECK && bad.is_none() && checked < end {
            let gap = (checked - start) as usize;
            check_range(&part[gap..], self.max_raw).map_err(|b| gap + b)?;
        }
        bad.map_or(Ok(()), Err)
    }

    /// One window's pixels of the current row on the general path: columns
    /// `i0 ..` of its row `j`, `pixel` the row-major index of the first.
    /// Returns the offset of a pixel out of range.
    #[inline(always)]
    fn segment<S: Steps, const CHECK: bool>(
        &mut self,
        k: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        match self.memory.open[k].path(raw) {
            SegmentPath::Rejected => Ok(()),
            SegmentPath::Candidates | SegmentPath::General => {
                self.segment_rest::<S, CHECK>(k, raw, pixel, i0, j)
            }
        }
    }

    /// The rest of [`segment`](Self::segment): windows without selection,
    /// windows awaiting a rescan, and segments with candidates.
    #[inline(never)]
    fn segment_rest<S: Steps, const CHECK: bool>(
        &mut self,
        k: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
        if window.capacity == 0 {
            // No selection: every pixel weighs its value.
            if CHECK {
                check_range(raw, self.max_raw)?;
            }
            // SAFETY: the segment lies in the camera (a window's row,
            // validated configuration).
            let (background, gain, fixed) =
                unsafe { calibrate::run_maps::<S>(&self.config.calibration, pixel, raw.len()) };
            window
                .moments
                .add_raw_row::<S>(raw, background, gain, fixed, i0, j);
            return Ok(());
        }
        if window.rescan {
            return if CHECK {
                check_range(raw, self.max_raw)
            } else {
                Ok(())
            };
        }
        // SAFETY: the segment lies in the camera (a window's row, validated
        // configuration).
        let (background, gain, fixed) =
            unsafe { calibrate::run_maps::<S>(&self.config.calibration, pixel, raw.len()) };
        let max_raw = self.max_raw;
        let mut start = 0;
        let outcome = loop {
            let segment = Segment {
                raw: &raw[start..],
                start,
                background,
                gain,
                fixed,
                base: pack(i0, j),
                max_raw,
            };
            let (k, entry) = match scan::<S, CHECK>(window, &segment) {
                Stop::End => break Ok(()),
                Stop::OutOfRange(k) => return Err(k),
                Stop::Full { k, entry } => (k, entry),
            };
            // Full: drop the back tier if the front proves it useless, else
            // raise `low` to the cutoff so far; then place the pixel again.
            self.stats.compactions = self.stats.compactions.wrapping_add(1);
            if !make_room(window, &self.config, memory.scratch) {
                window.rescan = true;
                window.floor = 0;
                break if CHECK {
                    check_range(&raw[k + 1..], max_raw).map_err(|b| k + 1 + b)
                } else {
                    Ok(())
                };
            }
            update_admission(window, &self.config.calibration, max_raw);
            place(window, entry);
            start = k + 1;
        };
        if !window.rescan {
            raise_to_hint(window, &self.config, max_raw);
        }
        window.attention = attention(window, self.config.selection.rule);
        self.refresh_ready(k);
        outcome
    }

    /// The row kernel stopped at window `k`: its candidates may now prove
    /// the cutoff is at or above the hint (the back tier then goes, and
    /// admission rises), or it is short of room for the next segment (it
    /// then takes the general path, which compacts it when full).
    #[inline(never)]
    fn attend(&mut self, k: usize) {
        self.stats.attentions = self.stats.attentions.wrapping_add(1);
        let window = &mut self.memory.open[k];
        raise_to_hint(window, &self.config, self.max_raw);
        window.attention = attention(window, self.config.selection.rule);
        self.refresh_ready(k);
    }

    /// Whether window `k` is `kernel_ready` may have changed: its kernel
    /// segment and the count of windows the kernel skips, updated.
    #[inline(always)]
    fn refresh_ready(&mut self, k: usize) {
        let window = &mut self.memory.open[k];
        let was = window.segment_start != window.segment_end;
        let ready = window.update_kernel_segment();
        if was != ready {
            if ready {
                self.not_ready -= 1;
            } else {
                self.not_ready += 1;
            }
        }
    }

    /// A window's last pixel has arrived: its result, and what it leaves for
    /// the next frame (level filter, seed).
    fn finish(&mut self, k: usize, sink: &mut impl OutputSink) {
        self.finished_in_row = true;
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
        window.finished = true;
        let moments = if window.capacity == 0 {
            window.moments
        } else {
            let rule = WindowRule {
                rule: self.config.selection.rule,
                n: window.n,
                pixels: window.pixels(),
            };
            let state = &mut memory.subapertures[window.index as usize];
            let capacity = window.capacity as usize;
            settle_at_hint(window);
            let (front, back) = (window.front(), window.back());
            // SAFETY: the window's buffer (opened with it), no other
            // reference to it alive.
            let entries: &[Entry] = unsafe { window.entries() };
            let filter = self.config.selection.level_filter;
            let level = |cut: &Cut, state: &mut SubapertureState| match filter {
                Some(f) => state.level.update(cut.level, f.gain_shift),
                None => cut.level,
            };
            let held =
                front + back + window.hint_ties.count as usize + window.low_ties.count as usize;
            self.stats.windows = self.stats.windows.wrapping_add(1);
            self.stats.candidates = self.stats.candidates.wrapping_add(held as u32);
            let mut too_high = false;
            let from_buffer = if window.rescan {
                None
            } else {
                let mut tiers = Tiers {
                    front: &entries[..front],
                    front_at_hint: window.at_hint,
                    hint: window.hint,
                    hint_ties: window.hint_ties.count,
                    back: &entries[capacity - back..],
                    low: window.low,
                    low_ties: window.low_ties.count,
                    complete: held == rule.pixels as usize,
                    scratch: memory.scratch,
                };
                let cut = select::cut(&rule, &mut tiers).ok();
                too_high = cut.is_none();
                cut
            };
            match from_buffer {
                Some(cut) => {
                    let level = level(&cut, state);
                    state.seed.observe(cut.cutoff, false);
                    let mut moments = Moments::ZERO;
                    select::add_moments(&mut moments, &cut, level, &entries[..front]);
                    select::add_tie_moments(
                        &mut moments,
                        &cut,
                        level,
                        window.hint,
                        window.hint_ties,
                    );
                    if cut.bound < window.hint {
                        let at = capacity - back;
                        select::add_moments(&mut moments, &cut, level, &entries[at..]);
                        select::add_tie_moments(
                            &mut moments,
                            &cut,
                            level,
                            window.low,
                            window.low_ties,
                        );
                    }
                    moments
                }
                None => {
                    self.stats.rescans = self.stats.rescans.wrapping_add(1);
                    let pixels = rule.pixels as usize;
                    let all = &mut memory.rescan[..pixels];
                    let width = self.config.camera.width as usize;
                    let w = window.width as usize;
                    for j in 0..window.height as usize {
                        let y = window.y as usize + j;
                        let at = (y % self.history_rows) * width + window.x as usize;
                        let row = &mut self.calibrated[..w];
                        self.calibrator.calibrate(
                            &memory.history[at..at + w],
                            y * width + window.x as usize,
                            row,
                        );
                        for (i, (e, &p)) in all[j * w..(j + 1) * w]
                            .iter_mut()
                            .zip(row.iter())
                            .enumerate()
                        {
                            *e = Entry {
                                value: p,
                                position: pack(i as u16, j as u16) as u32,
                            };
                        }
                    }
                    let mut tiers = Tiers {
                        front: all,
                        front_at_hint: 0,
                        hint: i32::MIN,
                        hint_ties: 0,
                        back: &[],
                        low: i32::MIN,
                        low_ties: 0,
                        complete: true,
                        scratch: memory.scratch,
                    };
                    // Complete candidates always cut (N < pixels); the
                    // fallback keeps nothing and is never taken.
                    let cut = select::cut(&rule, &mut tiers).unwrap_or(KEEPS_NOTHING);
                    let level = level(&cut, state);
                    state.seed.observe(cut.cutoff, too_high);
                    let mut moments = Moments::ZERO;
                    select::add_moments(&mut moments, &cut, level, all);
                    moments
                }
            }
        };
        sink.subaperture(self.centroider.result(
            window.index,
            moments,
            window.width,
            window.height,
        ));
    }

    fn end_row(&mut self, sink: &mut impl OutputSink) {
        let mut layout_changed = false;
        if self.finished_in_row {
            // Close finished windows, keeping the others in column order.
            let memory = &mut self.memory;
            let mut kept = 0;
            for k in 0..self.open_len {
                let window = memory.open[k];
                if window.finished {
                    memory.free[self.free_len] = window.buffer_number;
                    self.free_len += 1;
                    if window.segment_start == window.segment_end {
                        self.not_ready -= 1;
                    }
                } else {
                    if kept != k {
                        memory.open[kept] = window;
                    }
                    kept += 1;
                }
            }
            self.open_len = kept;
            self.finished_in_row = false;
            layout_changed = true;
        }
        self.cursor = 0;
        self.column = 0;
        self.row += 1;
        let width = self.config.camera.width as usize;
        if self.bg_row != 0 {
            self.bg_row += 4 * width;
        }
        if self.scan.gain_row != 0 {
            self.scan.gain_row += 2 * width;
        }
        self.position_row += 1 << 6;
        if self.history_rows > 0 {
            self.history_row += width;
            if self.history_row == self.history_rows * width {
                self.history_row = 0;
            }
        }
        if self.row == self.config.camera.height {
            self.frames = self.frames.wrapping_add(1);
            sink.frame_complete(self.frames);
            self.start_frame();
        } else if self.opens_windows_in_row() {
            self.open_windows_of_row();
        } else if layout_changed {
            self.update_layout();
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
        // After a whole frame every window has closed and its buffer is
        // free again (in another order, which only moves candidate buffers
        // in the pool); after an aborted one, or before the first, the
        // buffers are listed afresh.
        if self.free_len != open {
            for (k, f) in self.memory.free[..open].iter_mut().enumerate() {
                *f = (open - 1 - k) as u16;
            }
            self.free_len = open;
        }
        self.open_len = 0;
        self.not_ready = 0;
        self.cursor = 0;
        self.finished_in_row = false;
        self.row = 0;
        self.column = 0;
        self.history_row = 0;
        let c = &self.config.calibration;
        self.bg_row = c.background.map_or(0, |b| b.as_ptr() as usize);
        self.scan.gain_row = c.gain.map_or(0, |g| g.as_ptr() as usize);
        self.position_row = 0;
        self.next_to_open = 0;
        self.update_layout();
        // The first row's windows open in `push_with`.
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
            let number = self.memory.free[self.free_len];
            let n = self.config.pixel_count(index);
            // The stride is at least every window's least capacity (plan).
            let capacity = preferred_capacity(self.config.selection.rule, n, w.pixel_count())
                .min(self.stride as u16);
            let state = &self.memory.subapertures[index];
            let (hint, low) = if capacity > 0 {
                state.seed.thresholds()
            } else {
                (0, 0)
            };
            // Its place in column order.
            let open = &mut self.memory.open;
            let mut k = self.open_len;
            while k > 0 && open[k - 1].x > w.x {
                k -= 1;
            }
            if k < self.open_len {
                open.copy_within(k..self.open_len, k + 1);
            }
            self.open_len += 1;
            let buffer = self.pool + number as usize * self.stride * core::mem::size_of::<Entry>();
            // Field by field, in place, through a pattern that names every
            // field (so a new one fails to compile here until it is set): as
            // one struct literal the compiler built part of it on the stack
            // and copied it with a byte-wise `memcpy` call (~200
            // instructions a window on Cortex-M4).
            let OpenWindow {
                segment_start,
                segment_end,
                lanes,
                admit,
                position_base,
                hint: window_hint,
                front_end,
                back_start,
                attention: window_attention,
                room,
                buffer: window_buffer,
                capacity: window_capacity,
                buffer_number,
                index: window_index,
                x,
                end_column,
                y,
                last_row,
                width,
                height,
                n: window_n,
                at_hint,
                counted,
                hint_ties,
                low: window_low,
                low_ties,
                floor,
                finished,
                strict,
                rescan,
                bounds,
                moments,
            } = &mut open[k];
            *segment_start = 0;
            *segment_end = 0;
            *lanes = 0;
            *admit = low;
            *position_base = 0u32
                .wrapping_sub((w.y as u32) << 6)
                .wrapping_sub(w.x as u32);
            *window_hint = hint;
            *front_end = buffer;
            *back_start = buffer + capacity as usize * core::mem::size_of::<Entry>();
            *window_attention = usize::MAX;
            *room = 8 * w.width as u32;
            *window_buffer = buffer;
            *window_capacity = capacity;
            *buffer_number = number;
            *window_index = index as u16;
            *x = w.x;
            *end_column = w.end_column();
            *y = w.y;
            *last_row = w.last_row();
            *width = w.width;
            *height = w.height;
            *window_n = n;
            *at_hint = 0;
            *counted = 0;
            *hint_ties = Ties::NONE;
            *window_low = low;
            *low_ties = Ties::NONE;
            *floor = 0;
            *finished = false;
            *strict = false;
            *rescan = false;
            *bounds = state.bounds;
            *moments = Moments::ZERO;
            // A window without selection keeps floor 0 (every segment to
            // `segment_rest`).
            let window = &mut open[k];
            if capacity > 0 {
                update_admission(window, &self.config.calibration, self.max_raw);
                window.attention = attention(window, self.config.selection.rule);
            }
            if !window.update_kernel_segment() {
                self.not_ready += 1;
            }
        }
        self.update_layout();
    }

    /// The open windows' layout flags: `disjoint`, `gapless` and
    /// `next_last_row`.
    fn update_layout(&mut self) {
        let open = &self.memory.open[..self.open_len];
        self.disjoint = open.windows(2).all(|pair| pair[0].end_column <= pair[1].x);
        self.gapless = !open.is_empty()
            && open[0].x == 0
            && open[open.len() - 1].end_column == self.config.camera.width
            && open.windows(2).all(|pair| pair[0].end_column == pair[1].x);
        self.next_last_row = open.iter().map(|w| w.last_row).min().unwrap_or(u16::MAX);
        let range = self.memory.open[..self.open_len].as_mut_ptr_range();
        self.scan.first = range.start as usize;
        self.scan.end = range.end as usize;
    }
}

/// `to.copy_from_slice(from)`, eight pixels at a time when both are
/// aligned alike (`prefilter::copy_words`), else a pixel at a time (the
/// library's `memcpy` goes byte by byte on Cortex-M when the two are not
/// aligned alike, and is a call even for the empty ends of a split).
#[inline(always)]
fn copy_pixels(from: &[u16], to: &mut [u16]) {
    let n = from.len().min(to.len());
    let skew = (from.as_ptr() as usize ^ to.as_ptr() as usize) & 3;
    if skew != 0 || n < 8 {
        for (t, f) in to.iter_mut().zip(from) {
            *t = *f;
        }
        return;
    }
    // Aligned alike: one pixel brings both to a word boundary if they are
    // not on one, then whole words and at most one pixel.
    let first = (from.as_ptr() as usize & 2) / 2;
    let words = (n - first) / 2;
    if first == 1 {
        to[0] = from[0];
    }
    // SAFETY: from pixel `first` on both are aligned to 4 and hold at least
    // `2 words` pixels (n >= first + 2 words); any bits are a u32 and a
    // pair of u16.
    let (fw, tw) = unsafe {
        (
            core::slice::from_raw_parts(from.as_ptr().add(first) as *const u32, words),
            core::slice::from_raw_parts_mut(to.as_mut_ptr().add(first) as *mut u32, words),
        )
    };
    prefilter::copy_words(fw, tw);
    let last = first + 2 * words;
    if last < n {
        to[last] = from[last];
    }
}

/// Counts the front entries equal to the hint that arrived since the last
/// count: `at_hint` is kept lazily, since only the tests of whether the front
/// covers the hint, compaction and the window's end need it.
#[inline(always)]
fn settle_at_hint(window: &mut OpenWindow) {
    let (counted, front) = (window.counted as usize, window.front());
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    window.at_hint += count_at_hint(&entries[counted..front], window.hint);
    window.counted = front as u16;
}

/// Front entries equal to the hint.
#[inline(always)]
fn count_at_hint(entries: &[Entry], hint: i32) -> u16 {
    entries.iter().filter(|e| e.value == hint).count() as u16
}

/// Once the front and hint ties prove the cutoff is at or above the hint,
/// nothing below it can matter, and often no more pixels equal to it: the
/// rest of the window is filtered harder.
#[inline(always)]
fn raise_to_hint(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16) {
    if !window.strict
        && window.front() + window.hint_ties.count as usize >= window.n as usize
        && covers(window, config)
    {
        window.set_back(0);
        window.low = window.hint;
        window.low_ties = Ties::NONE;
        window.strict = Tiers::hint_ties_settled(
            config.selection.rule,
            window.n,
            window.front() as u16 - window.at_hint,
        );
        update_admission(window, &config.calibration, max_raw);
    }
}

/// Where the row kernel next stops at a window for [`raise_to_hint`]: the
/// front's end at the fewest candidates with which the front and hint ties
/// could prove the cutoff at or above the hint (or, once they have, make
/// admission strict), and at least one more than it holds; never once
/// admission is strict.
#[inline(always)]
fn attention(window: &OpenWindow, rule: SelectionRule) -> usize {
    if window.capacity == 0 || window.strict {
        return usize::MAX;
    }
    let (n, ties, front) = (
        window.n as usize,
        window.hint_ties.count as usize,
        window.front(),
    );
    let raised = window.low == window.hint && window.back() == 0;
    let fewest = match rule {
        // front + ties > n (Tiers::covers_hint); always strict once raised.
        SelectionRule::SubtractNext => (n + 1).saturating_sub(ties),
        // front + ties >= n, then strict at front - at_hint >= n.
        SelectionRule::Threshold if raised => n + window.at_hint as usize,
        SelectionRule::Threshold => n.saturating_sub(ties),
        // Besides n above the hint, copies of it: the count is a bound, the
        // copies in the front are only counted when it is reached.
        SelectionRule::SubtractNextDistinct => n + (ties == 0) as usize,
        SelectionRule::SubtractMean { count } => n + (count as usize).saturating_sub(ties),
    };
    window.buffer + fewest.max(front + 1) * core::mem::size_of::<Entry>()
}

/// After `low`, `hint` or `strict` changed: the window's admission
/// threshold, and the pre-filter's raw floor for it, lowered so that a pixel
/// above `max_raw` always passes (see `OpenWindow::floor`), in both forms.
#[inline(always)]
fn update_admission(window: &mut OpenWindow, calibration: &Calibration<'_>, max_raw: u16) {
    window.admit = window.admission();
    let floor = raw_floor(calibration, window.bounds, window.admit).min(max_raw as u32 + 1);
    window.floor = floor;
    window.lanes = floor.wrapping_sub(1).wrapping_mul(0x0001_0001);
}

/// [`Tiers::covers_hint`] for an open window: its front holds the pixels
/// above the hint and `at_hint` equal to it, beside its hint ties.
#[inline(always)]
fn covers(window: &mut OpenWindow, config: &Config<'_>) -> bool {
    settle_at_hint(window);
    Tiers::covers_hint(
        config.selection.rule,
        window.n,
        window.front() as u16 - window.at_hint,
        window.hint_ties.count + window.at_hint,
    )
}

/// A window's candidate buffer is full: drops its back tier if the front
/// proves it useless, else compacts it (`select::Buffer::compact`).
/// `false` if nothing could be dropped.
#[cold]
#[inline(never)]
fn make_room(window: &mut OpenWindow, config: &Config<'_>, scratch: &mut [i32]) -> bool {
    settle_at_hint(window);
    let rule = WindowRule {
        rule: config.selection.rule,
        n: window.n,
        pixels: window.pixels(),
    };
    if window.back() > 0 && covers(window, config) {
        window.set_back(0);
        window.low = window.hint;
        window.low_ties = Ties::NONE;
        return true;
    }
    let mut buffer = Buffer {
        // SAFETY: the window's live buffer, no other reference to it.
        entries: unsafe { window.entries() },
        front: window.front(),
        at_hint: window.at_hint,
        back: window.back(),
        hint: window.hint,
        hint_ties: window.hint_ties,
        low: window.low,
        low_ties: window.low_ties,
        strict: window.strict,
    };
    if !buffer.compact(&rule, scratch) {
        return false;
    }
    let room = buffer.front + buffer.back < buffer.entries.len();
    let (front, back) = (buffer.front, buffer.back);
    window.at_hint = buffer.at_hint;
    window.hint = buffer.hint;
    window.hint_ties = buffer.hint_ties;
    window.low = buffer.low;
    window.low_ties = buffer.low_ties;
    window.strict = buffer.strict;
    window.set_front(front);
    window.set_back(back);
    window.counted = front as u16;
    room
}

/// Puts an admitted pixel into its tier, after [`make_room`].
#[cold]
fn place(window: &mut OpenWindow, entry: Entry) {
    let p = entry.value;
    if p < window.admit {
        return;
    }
    // SAFETY: `make_room` left room for one entry between the tiers.
    unsafe {
        if p >= window.hint {
            (window.front_end as *mut Entry).write(entry);
            window.front_end += core::mem::size_of::<Entry>();
        } else {
            window.back_start -= core::mem::size_of::<Entry>();
            (window.back_start as *mut Entry).write(entry);
        }
    }
}

/// Never used: see `Engine::finish`.
const KEEPS_NOTHING: Cut = Cut {
    bound: i32::MAX,
    strict: true,
    level: None,
    cutoff: i32::MIN,
};

/// The offset of the first pixel of `raw` above `max_raw`, if any.
#[inline(always)]
fn check_range(raw: &[u16], max_raw: u16) -> Result<(), usize> {
    if prefilter::any_at_least(raw, max_raw + 1) {
        Err(raw.iter().position(|&r| r > max_raw).unwrap_or(0))
    } else {
        Ok(())
    }
}
