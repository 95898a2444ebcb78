//! The engine: routes pixels, as they arrive in raster order, to the windows
//! they belong to, and emits each sub-aperture's result the moment its last
//! pixel has been seen.
//!
//! Windows are opened at their first row (taking a candidate buffer from the
//! pool) and closed after their last, so only the windows crossing the
//! current row hold state. The open windows are kept in a list sorted by
//! first column, and a cursor skips those the current row has already
//! passed, so a chunk touches only the windows it overlaps, whatever its
//! length.
//!
//! For each window's run of pixels in a row (a *segment*), the pre-filter
//! first asks whether any raw pixel can reach the window's admission
//! threshold; usually none can, and the segment costs a few instructions per
//! pixel pair. Otherwise the pixels that can are calibrated and become
//! candidates (see `select.rs`). Pixels that belong to no window are only
//! checked against the camera's bit depth.

use super::calibrate::{self, raw_floor, Calibrator, Steps, WindowBounds, With};
use super::centroid::{Centroider, Moments, SubapertureResult};
use super::memory::{EngineMemory, MemorySize};
use super::plan::plan;
use super::prefilter;
use super::scan::{admit_words, scan, Segment, Stop, TierEnds, WordRun};
use super::select::{self, pack, preferred_capacity, Buffer, Cut, Entry, Tiers, Ties, WindowRule};
use super::window::{OpenWindow, SegmentPath, SubapertureState};
use brightpix_protocol::{Calibration, Config, ConfigError, MAX_WINDOW_SIDE};

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
}

/// The streaming brightest-pixel engine for one configuration.
pub struct Engine<'c, 'm> {
    config: Config<'c>,
    calibrator: Calibrator<'c>,
    centroider: Centroider<'c>,
    memory: EngineMemory<'m>,
    /// Candidate entries per open window.
    stride: usize,
    /// Rows in the history ring (0: no window selects, none kept).
    history_rows: usize,
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
    /// The active windows do not overlap (each ends at or before the next
    /// one's first column): a whole row can take [`Self::push_whole_row`].
    disjoint: bool,
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
            &mut memory.active[..available.open_windows],
        )?;
        let maps = config.calibration.background.is_some() || config.calibration.gain.is_some();
        for (state, window) in memory.subapertures.iter_mut().zip(config.windows) {
            state.bounds = if maps {
                WindowBounds::of(&config, window)
            } else {
                WindowBounds::NONE
            };
        }
        let mut engine = Engine {
            config,
            calibrator: Calibrator::new(config.calibration),
            centroider: Centroider::new(config.centroid),
            memory,
            stride: plan.stride,
            history_rows: plan.history_rows,
            max_raw: config.camera.max_raw(),
            row: 0,
            column: 0,
            next_to_open: 0,
            active_len: 0,
            free_len: 0,
            cursor: 0,
            finished_in_row: false,
            disjoint: true,
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
            // theirs at the end of the row before (`end_row`). Opening every
            // row here instead measured 0.8% slower on Cortex-M4.
            if self.row == 0 && self.column == 0 && self.next_to_open == 0 {
                self.open_windows_of_row();
            }
            let take = pixels.len().min((width - self.column) as usize);
            let (part, rest) = pixels.split_at(take);
            if self.history_rows > 0 {
                let at =
                    (self.row as usize % self.history_rows) * width as usize + self.column as usize;
                copy_pixels(part, &mut self.memory.history[at..at + take]);
            }
            let pushed = if take == width as usize && self.disjoint {
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

    /// A whole row when the active windows do not overlap: the common case,
    /// without [`Self::push_row_part`]'s bookkeeping for chunks that start
    /// or end inside a window. Same contract: on a pixel out of range, its
    /// column; the windows ending before it have been emitted, no other
    /// (windows are visited left to right and each gap is checked before
    /// the window after it).
    #[inline(always)]
    fn push_whole_row<S: Steps, const CHECK: bool>(
        &mut self,
        row_pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        let row = self.row;
        let row_offset = row as usize * row_pixels.len();
        let mut checked = 0;
        for k in 0..self.active_len {
            // SAFETY (the three unchecked indexings, the loop's bounds checks
            // being a tenth of its instructions): `active_len` is at most the
            // active list's length and every active entry is a slot of
            // `open` (`open_windows_of_row`); a window lies inside the
            // camera (`Config::validate`) and `row_pixels` is a whole row.
            let slot = unsafe { *self.memory.active.get_unchecked(k) } as usize;
            let window = unsafe { self.memory.open.get_unchecked(slot) };
            let (x, end) = (window.x as usize, window.end_column as usize);
            if CHECK && x > checked {
                check_range(&row_pixels[checked..x], self.max_raw).map_err(|b| checked + b)?;
            }
            let raw = unsafe { row_pixels.get_unchecked(x..end) };
            // Most segments: a selecting window whose pre-filter rejects the
            // whole segment (`floor` is capped so that an out-of-range pixel
            // is never rejected, and 0 for the windows `segment_rest` takes).
            let last = row == window.last_row;
            let (pixel, j) = (row_offset + x, row - window.y);
            match window.path(raw) {
                SegmentPath::Rejected => Ok(()),
                SegmentPath::Candidates => self.hot_segment::<S, CHECK>(slot, raw, pixel, 0, j),
                SegmentPath::General => self.segment_rest::<S, CHECK>(slot, raw, pixel, 0, j),
            }
            .map_err(|b| x + b)?;
            if last {
                self.finish(slot, sink);
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
    #[inline(always)]
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
        while k < self.active_len {
            let slot = self.memory.active[k] as usize;
            let window = &self.memory.open[slot];
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
                    slot,
                    &part[at..(to - start) as usize],
                    row_offset + from as usize,
                    from - x,
                    row - y,
                );
                match checked_segment {
                    Ok(()) => {
                        if to == end_column && row == last_row {
                            self.finish(slot, sink);
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

    /// One window's pixels of the current row: columns `i0 ..` of its row
    /// `j`, `pixel` the row-major index of the first. Returns the offset of
    /// a pixel out of range.
    #[inline(always)]
    fn segment<S: Steps, const CHECK: bool>(
        &mut self,
        slot: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        // The common case first, in as few instructions as it takes: a
        // selecting window whose segment the pre-filter rejects whole.
        match self.memory.open[slot].path(raw) {
            SegmentPath::Rejected => Ok(()),
            SegmentPath::Candidates => self.hot_segment::<S, CHECK>(slot, raw, pixel, i0, j),
            SegmentPath::General => self.segment_rest::<S, CHECK>(slot, raw, pixel, i0, j),
        }
    }

    /// The rest of [`segment`](Self::segment): windows without selection,
    /// windows awaiting a rescan, and segments with candidates.
    #[inline(never)]
    fn segment_rest<S: Steps, const CHECK: bool>(
        &mut self,
        slot: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        let memory = &mut self.memory;
        let window = &mut memory.open[slot];
        if window.capacity == 0 {
            // No selection: every pixel weighs its value.
            if CHECK {
                check_range(raw, self.max_raw)?;
            }
            let calibrated = &mut self.calibrated[..raw.len()];
            self.calibrator.calibrate(raw, pixel, calibrated);
            window.moments.add_row(calibrated, i0, j);
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
        let base = window.base as usize;
        let capacity = window.capacity as usize;
        let entries = &mut memory.entries[base..base + capacity];
        let max_raw = self.max_raw;
        let mut start = 0;
        loop {
            let segment = Segment {
                raw: &raw[start..],
                start,
                background,
                gain,
                fixed,
                base: pack(i0, j),
                max_raw,
            };
            let (k, entry) = match scan::<S, CHECK>(window, entries, &segment) {
                Stop::End => break,
                Stop::OutOfRange(k) => return Err(k),
                Stop::Full { k, entry } => (k, entry),
            };
            // Full: drop the back tier if the front proves it useless, else
            // raise `low` to the cutoff so far; then place the pixel again.
            self.stats.compactions = self.stats.compactions.wrapping_add(1);
            if !make_room(window, entries, &self.config, memory.scratch) {
                window.rescan = true;
                window.floor = 0;
                return if CHECK {
                    check_range(&raw[k + 1..], max_raw).map_err(|b| k + 1 + b)
                } else {
                    Ok(())
                };
            }
            update_admission(window, &self.config.calibration, max_raw);
            place(window, entries, entry);
            start = k + 1;
        }
        raise_to_hint(window, entries, &self.config, max_raw);
        Ok(())
    }

    /// A selecting window's segment that the pre-filter did not reject
    /// whole: the usual case (room for every pixel, whole words, the seed
    /// in force) in as few instructions as it takes, the others in
    /// [`segment_rest`](Self::segment_rest).
    #[inline(always)]
    fn hot_segment<S: Steps, const CHECK: bool>(
        &mut self,
        slot: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        // SAFETY: callers pass an active window's slot (see push_whole_row).
        let window = unsafe { self.memory.open.get_unchecked(slot) };
        let (front, back, capacity) = (
            window.front as usize,
            window.back as usize,
            window.capacity as usize,
        );
        let whole_words = (raw.as_ptr() as usize & 3) | (raw.len() & 1) == 0;
        // The floor passed the pre-filter (`OpenWindow::path`): a selecting
        // window without a rescan pending.
        if capacity - front - back < raw.len() || !whole_words {
            return self.segment_rest::<S, CHECK>(slot, raw, pixel, i0, j);
        }
        // SAFETY: the segment lies in the camera (a window's row, validated
        // configuration).
        let (background, gain, fixed) =
            unsafe { calibrate::run_maps::<S>(&self.config.calibration, pixel, raw.len()) };
        let memory = &mut self.memory;
        // SAFETY: as above.
        let window = unsafe { memory.open.get_unchecked_mut(slot) };
        let base = window.base as usize;
        // SAFETY: a slot's entries lie in the pool (`plan`: the pool holds
        // `stride` entries for every slot, and capacity <= stride).
        let entries = unsafe { memory.entries.get_unchecked_mut(base..base + capacity) };
        let origin = entries.as_mut_ptr();
        let run = WordRun {
            first: 0,
            background,
            gain,
            fixed,
            lanes: window.lanes,
            admit: window.admit,
            hint: window.hint,
            base: pack(i0, j),
            max_raw: self.max_raw,
        };
        // SAFETY: `raw` is word-aligned and of even length (checked), so it
        // is `raw.len() / 2` words; the maps cover the segment (run_maps);
        // front + back <= capacity, and the room left holds every pixel
        // (checked).
        let bad = unsafe {
            let words = core::slice::from_raw_parts(raw.as_ptr() as *const u32, raw.len() / 2);
            let mut ends = TierEnds {
                front_end: origin.add(front),
                back_start: origin.add(capacity - back),
            };
            let bad = admit_words::<S, CHECK>(words, &run, &mut ends);
            window.front = ends.front_end.offset_from(origin) as u16;
            window.back = (capacity - ends.back_start.offset_from(origin) as usize) as u16;
            bad
        };
        if let Some(k) = bad {
            return Err(k);
        }
        raise_to_hint(window, entries, &self.config, self.max_raw);
        Ok(())
    }

    /// A window's last pixel has arrived: its result, and what it leaves for
    /// the next frame (level filter, seed).
    fn finish(&mut self, slot: usize, sink: &mut impl OutputSink) {
        self.finished_in_row = true;
        let memory = &mut self.memory;
        let window = &mut memory.open[slot];
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
            let base = window.base as usize;
            let capacity = window.capacity as usize;
            let (front, back) = (window.front as usize, window.back as usize);
            let entries = &memory.entries[base..base + capacity];
            settle_at_hint(window, entries);
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
            self.disjoint = self.active_windows_disjoint();
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
        // After a whole frame every window has closed and its slot is free
        // again (in another order, which only moves candidate buffers in
        // the pool); after an aborted one, or before the first, the slots
        // are listed afresh.
        if self.free_len != open {
            for (k, f) in self.memory.free[..open].iter_mut().enumerate() {
                *f = (open - 1 - k) as u16;
            }
            self.free_len = open;
        }
        self.active_len = 0;
        self.cursor = 0;
        self.finished_in_row = false;
        self.row = 0;
        self.column = 0;
        self.next_to_open = 0;
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
            let slot = self.memory.free[self.free_len];
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
            // Field by field, in place, through a pattern that names every
            // field (so a new one fails to compile here until it is set): as
            // one struct literal the compiler built part of it on the stack
            // and copied it with a byte-wise `memcpy` call (~200
            // instructions a window on Cortex-M4).
            let OpenWindow {
                index: window_index,
                x,
                end_column,
                y,
                last_row,
                width,
                height,
                base,
                finished,
                n: window_n,
                capacity: window_capacity,
                front,
                back,
                hint: window_hint,
                hint_ties,
                low: window_low,
                low_ties,
                strict,
                admit,
                lanes,
                at_hint,
                counted,
                floor,
                rescan,
                bounds,
                moments,
            } = &mut self.memory.open[slot as usize];
            *window_index = index as u16;
            *x = w.x;
            *end_column = w.end_column();
            *y = w.y;
            *last_row = w.last_row();
            *width = w.width;
            *height = w.height;
            *base = (slot as usize * self.stride) as u32;
            *finished = false;
            *window_n = n;
            *window_capacity = capacity;
            *front = 0;
            *back = 0;
            *window_hint = hint;
            *hint_ties = Ties::NONE;
            *window_low = low;
            *low_ties = Ties::NONE;
            *strict = false;
            *admit = low;
            *lanes = 0;
            *at_hint = 0;
            *counted = 0;
            *floor = 0;
            *rescan = false;
            *bounds = state.bounds;
            *moments = Moments::ZERO;
            // A window without selection keeps floor 0 (every segment to
            // `segment_rest`).
            if capacity > 0 {
                let window = &mut self.memory.open[slot as usize];
                update_admission(window, &self.config.calibration, self.max_raw);
            }
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
        self.disjoint = self.active_windows_disjoint();
    }

    /// Whether each active window ends at or before the next one starts.
    fn active_windows_disjoint(&self) -> bool {
        let open = &self.memory.open;
        self.memory.active[..self.active_len]
            .windows(2)
            .all(|pair| open[pair[0] as usize].end_column <= open[pair[1] as usize].x)
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
fn settle_at_hint(window: &mut OpenWindow, entries: &[Entry]) {
    let (counted, front) = (window.counted as usize, window.front as usize);
    window.at_hint += count_at_hint(&entries[counted..front], window.hint);
    window.counted = window.front;
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
fn raise_to_hint(window: &mut OpenWindow, entries: &[Entry], config: &Config<'_>, max_raw: u16) {
    if !window.strict
        && window.front + window.hint_ties.count >= window.n
        && covers(window, entries, config)
    {
        window.back = 0;
        window.low = window.hint;
        window.low_ties = Ties::NONE;
        window.strict = Tiers::hint_ties_settled(
            config.selection.rule,
            window.n,
            window.front - window.at_hint,
        );
        update_admission(window, &config.calibration, max_raw);
    }
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
fn covers(window: &mut OpenWindow, entries: &[Entry], config: &Config<'_>) -> bool {
    settle_at_hint(window, entries);
    Tiers::covers_hint(
        config.selection.rule,
        window.n,
        window.front - window.at_hint,
        window.hint_ties.count + window.at_hint,
    )
}

/// A window's candidate buffer is full: drops its back tier if the front
/// proves it useless, else compacts it (`select::Buffer::compact`).
/// `false` if nothing could be dropped.
#[cold]
#[inline(never)]
fn make_room(
    window: &mut OpenWindow,
    entries: &mut [Entry],
    config: &Config<'_>,
    scratch: &mut [i32],
) -> bool {
    settle_at_hint(window, entries);
    let rule = WindowRule {
        rule: config.selection.rule,
        n: window.n,
        pixels: window.pixels(),
    };
    if window.back > 0 && covers(window, entries, config) {
        window.back = 0;
        window.low = window.hint;
        window.low_ties = Ties::NONE;
        return true;
    }
    let mut buffer = Buffer {
        entries,
        front: window.front as usize,
        at_hint: window.at_hint,
        back: window.back as usize,
        hint: window.hint,
        hint_ties: window.hint_ties,
        low: window.low,
        low_ties: window.low_ties,
        strict: window.strict,
    };
    if !buffer.compact(&rule, scratch) {
        return false;
    }
    window.front = buffer.front as u16;
    window.at_hint = buffer.at_hint;
    window.counted = window.front;
    window.back = buffer.back as u16;
    window.hint = buffer.hint;
    window.hint_ties = buffer.hint_ties;
    window.low = buffer.low;
    window.low_ties = buffer.low_ties;
    window.strict = buffer.strict;
    buffer.front + buffer.back < buffer.entries.len()
}

/// Puts an admitted pixel into its tier, after [`make_room`].
#[cold]
fn place(window: &mut OpenWindow, entries: &mut [Entry], entry: Entry) {
    let admit = window.admit;
    let capacity = entries.len();
    let p = entry.value;
    if p < admit {
    } else if p >= window.hint {
        entries[window.front as usize] = entry;
        window.front += 1;
    } else {
        window.back += 1;
        entries[capacity - window.back as usize] = entry;
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
