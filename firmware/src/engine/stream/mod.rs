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
//! is at or above the hint, or it is short of room: `Engine::attend`).
//! What the kernel does not take (a chunk that ends inside a window,
//! windows without selection or awaiting a rescan, odd columns) takes the
//! general path, a window at a time. Pixels that belong to no window are
//! only checked against the camera's bit depth.
//!
//! Here: the engine's state, its construction and the per-chunk and
//! per-row bookkeeping. In order of a window's life:
//! - `open`: windows opened at their first row;
//! - `route`: each row's pixels to the open windows (row kernel or general
//!   path);
//! - `admission`: what a window admits as it fills (thresholds, the
//!   kernel's attention stops, room in a full buffer);
//! - `finish`: a window's end, its cutoff, moments and result;
//!   `closed_form`: the same from sums taken in one pass, when the
//!   candidates reach the cutoff (for `subtract-next` almost always, for
//!   the other rules most often); `last_row`: most of
//!   that done as the frame's last row begins;
//! - `complement`: a `subtract-next` window keeping more than half its
//!   pixels keeps the few below its cutoff instead, beside every pixel's
//!   sums.

use super::calibrate::{Calibrator, Steps, WindowBounds, With};
use super::centroid::{Centroider, SubapertureResult};
use super::memory::{EngineMemory, MemorySize};
use super::plan::plan;
use super::prefilter;
use super::scan::{CheckedKernels, RowScan};
use super::window::SubapertureState;
use brightpix_protocol::{Config, ConfigError};

mod admission;
mod closed_form;
mod complement;
mod finish;
mod last_row;
mod open;
mod route;

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
    /// attention (`Engine::attend`). Not the raises to the hint the kernel
    /// does itself, nor its counts of the hint's copies
    /// (`OpenWindow::raise`).
    pub attentions: u32,
    /// Frames in which the row kernel (`scan::row`, the assembly routine
    /// on Cortex-M) ran at least once, whole or abandoned, the frame in
    /// progress included. 0: every pixel took the general path
    /// (`route.rs`: rows not word-aligned, below 16 bits rows with pixels
    /// outside every window, windows at odd columns or of odd width,
    /// windows without selection). Counted once a frame, when the next one
    /// opens, not in the row loop: a count per kernel call cost 0.03
    /// instructions a pixel at CANARY on Cortex-M4.
    pub kernel_frames: u32,
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
    /// While a frame that arrived whole in one call to [`Engine::push`] is
    /// processed (only then), the address of its first pixel: a rescan
    /// reads its rows there, so none is copied to the history ring.
    whole_frame: usize,
    /// `history_rows * width`: where the history ring ends.
    history_end: usize,
    /// Where the history ring the current frame is copied to ends
    /// (`history_rows * width`), or 0 while `whole_frame` is set (or no
    /// window selects). Derivable from the two, kept so that a row tests
    /// one field (testing both measured 16.22 against 16.18 instructions a
    /// pixel on Cortex-M4) and the ring's index wraps without a multiply
    /// each row.
    ring_end: usize,
    max_raw: u16,
    row: u16,
    column: u16,
    /// Next window (in `memory.order`) to open.
    next_to_open: usize,
    /// The next row at which `end_row` has more to do than advance: the
    /// first row of the next window to open, or the camera's height (the
    /// frame's end). Kept so that a row tests one field.
    event_row: u16,
    /// The windows that end in the frame's last row are prepared at the
    /// start of this row (`last_row`), `event_row` stopping there too:
    /// the last row, or the row in which the push holding the frame's last
    /// pixel starts, so that that push does not prepare them
    /// (`set_prepare_row`); `u16::MAX`: never (pushes of half a frame or
    /// more).
    prepare_row: u16,
    /// Windows may end in closed form (`closed_form`): `subtract-next`
    /// without a level filter, or `threshold` (which subtracts no level,
    /// so never filters one).
    closed_form: bool,
    /// Likewise, for `subtract-next-distinct` or `subtract-mean` without a
    /// level filter.
    level_closed_form: bool,
    /// Likewise, for the subtracting rules with a level filter.
    filtered_closed_form: bool,
    /// The level filter's gain shift (0 without one).
    gain_shift: u8,
    /// A window's hint is one above its seed's as it opens: for
    /// `subtract-next-distinct`, whose front then holds the values above
    /// the previous level, not its copies
    /// (`admission::raise_below_front`).
    hint_above: bool,
    /// Some window selects the complement (`complement`).
    complement: bool,
    /// Every open window selects the complement, with whole words for
    /// segments: a whole row takes `scan::complement::row`.
    all_complement: bool,
    /// The length of the last push, from which `prepare_row` was set.
    push_len: usize,
    /// What `push_len` becomes as a frame ends: the same if it divides the
    /// frame, else 0 (which matches only an empty push, which does
    /// nothing). Pushes of one length that run from frame to frame meet
    /// each frame at another offset unless their length divides it, so
    /// where the push holding the last pixel starts is then worked out
    /// again at the next push (`set_prepare_row`). Set with `push_len`, so
    /// that the frame's end, after its last pixel, only copies it.
    push_len_next_frame: usize,
    /// Which instance of `push_with` a push takes (the calibration steps,
    /// the range check and the complement, bits as in [`variant`]):
    /// decided once per configuration, so that a push is one indexed jump.
    variant: u8,
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
    /// What `bg_row` and `scan.gain_row` advance by each row: a row of the
    /// map in bytes, 0 without one (so that a row adds, with no test).
    bg_stride: usize,
    gain_stride: usize,
    position_row: u32,
    frames: u32,
    needed: MemorySize,
    stats: EngineStats,
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
            history_end: plan.history_rows * config.camera.width as usize,
            whole_frame: 0,
            ring_end: 0,
            max_raw: config.camera.max_raw(),
            row: 0,
            column: 0,
            next_to_open: 0,
            event_row: 0,
            prepare_row: u16::MAX,
            closed_form: match config.selection.rule {
                brightpix_protocol::SelectionRule::SubtractNext => {
                    config.selection.level_filter.is_none()
                }
                brightpix_protocol::SelectionRule::Threshold => true,
                _ => false,
            },
            level_closed_form: matches!(
                config.selection.rule,
                brightpix_protocol::SelectionRule::SubtractNextDistinct
                    | brightpix_protocol::SelectionRule::SubtractMean { .. }
            ) && config.selection.level_filter.is_none(),
            filtered_closed_form: matches!(
                config.selection.rule,
                brightpix_protocol::SelectionRule::SubtractNext
                    | brightpix_protocol::SelectionRule::SubtractNextDistinct
                    | brightpix_protocol::SelectionRule::SubtractMean { .. }
            ) && config.selection.level_filter.is_some(),
            gain_shift: config.selection.level_filter.map_or(0, |f| f.gain_shift),
            hint_above: config.selection.rule
                == brightpix_protocol::SelectionRule::SubtractNextDistinct,
            complement: complement::applies(&config),
            all_complement: false,
            push_len: 0,
            push_len_next_frame: 0,
            variant: variant(&config),
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
                checked: CheckedKernels::for_max_raw(config.camera.max_raw()),
            },
            bg_row: 0,
            bg_stride: config
                .calibration
                .background
                .map_or(0, |_| size_of::<i32>() * config.camera.width as usize),
            gain_stride: config
                .calibration
                .gain
                .map_or(0, |_| size_of::<u16>() * config.camera.width as usize),
            position_row: 0,
            frames: 0,
            needed: plan.needed,
            stats: EngineStats::default(),
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
        let mut stats = self.stats;
        // The frame in progress, or the last one until the next opens.
        stats.kernel_frames = stats
            .kernel_frames
            .wrapping_add(u32::from(self.scan.row != 0));
        stats
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
    /// length (it may end mid-row or run into the next frame). A frame that
    /// is whole in the chunk from its first pixel on is not copied to the
    /// row history: a window rescanned reads its rows in the chunk.
    pub fn push(&mut self, pixels: &[u16], sink: &mut impl OutputSink) -> Result<(), FrameError> {
        if pixels.len() != self.push_len {
            self.set_prepare_row(pixels.len());
        }
        macro_rules! with {
            ($b:literal, $g:literal, $t:literal, $c:literal) => {
                self.push_with::<With<$b, $g, $t>, $c, false>(pixels, sink)
            };
            ($b:literal, $c:literal, complement) => {
                self.push_with::<With<$b, false, false>, $c, true>(pixels, sink)
            };
        }
        match self.variant {
            // `COMPLEMENT_VARIANT` (16) with a background map or none.
            16 => with!(false, false, complement),
            17 => with!(true, false, complement),
            24 => with!(false, true, complement),
            25 => with!(true, true, complement),
            0 => with!(false, false, false, false),
            1 => with!(true, false, false, false),
            2 => with!(false, true, false, false),
            3 => with!(true, true, false, false),
            4 => with!(false, false, true, false),
            5 => with!(true, false, true, false),
            6 => with!(false, true, true, false),
            7 => with!(true, true, true, false),
            8 => with!(false, false, false, true),
            9 => with!(true, false, false, true),
            10 => with!(false, true, false, true),
            11 => with!(true, true, false, true),
            12 => with!(false, false, true, true),
            13 => with!(true, false, true, true),
            14 => with!(false, true, true, true),
            _ => with!(true, true, true, true),
        }
    }

    /// `S`: the calibration steps; `CHECK`: whether raw pixels must be
    /// checked against the bit depth (below 16 bits); `COMPLEMENT`: whether
    /// windows may select the complement, whose whole rows then take
    /// `complement_row` (an instance of its own, so that the others' row
    /// path does not even test for it).
    fn push_with<S: Steps, const CHECK: bool, const COMPLEMENT: bool>(
        &mut self,
        mut pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), FrameError> {
        let width = self.config.camera.width as usize;
        while !pixels.is_empty() {
            if self.column == 0 {
                // A frame's first row opens its windows here, when its
                // first pixel arrives (`start_frame` does not), so that the
                // work after a frame's last pixel is only its results; the
                // other rows open theirs at the end of the row before
                // (`end_row`).
                if self.row == 0 && self.next_to_open == 0 {
                    // The frame before ran the row kernel if it set
                    // `scan.row`.
                    if self.scan.row != 0 {
                        self.count_kernel_frame();
                    }
                    let frame = width * self.config.camera.height as usize;
                    if pixels.len() >= frame {
                        self.whole_frame = pixels.as_ptr() as usize;
                        self.ring_end = 0;
                    }
                    self.open_windows_of_row();
                }
                // A whole row: the usual case, kept short.
                if pixels.len() >= width {
                    let (row, rest) = pixels.split_at(width);
                    self.keep_row(row);
                    if let Err(bad) = self.push_whole_row::<S, CHECK, COMPLEMENT>(row, sink) {
                        return Err(self.out_of_range(row, bad));
                    }
                    self.end_row(sink);
                    pixels = rest;
                    continue;
                }
            }
            let take = pixels.len().min(width - self.column as usize);
            let (part, rest) = pixels.split_at(take);
            if self.ring_end > 0 {
                let at = self.history_row + self.column as usize;
                // SAFETY: the ring holds `history_rows` camera rows (plan),
                // `history_row` is one of them and the part lies in it.
                let to = unsafe { self.memory.history.get_unchecked_mut(at..at + take) };
                copy_pixels(part, to);
            }
            if let Err(bad) = self.push_row_part::<S, CHECK>(part, sink) {
                return Err(self.out_of_range(part, bad));
            }
            self.column += take as u16;
            if self.column as usize == width {
                self.end_row(sink);
            }
            pixels = rest;
        }
        Ok(())
    }

    /// The frame before ran the row kernel: count it (once a frame, out
    /// of line).
    #[inline(never)]
    fn count_kernel_frame(&mut self) {
        self.stats.kernel_frames = self.stats.kernel_frames.wrapping_add(1);
        self.scan.row = 0;
    }

    /// A whole row (from column 0) copied to the row history, if one is
    /// kept for this frame.
    #[inline(always)]
    fn keep_row(&mut self, row: &[u16]) {
        if self.ring_end > 0 {
            let at = self.history_row;
            // SAFETY: the ring holds `history_rows` camera rows (plan) and
            // `history_row` is the first pixel of one of them.
            let to = unsafe { self.memory.history.get_unchecked_mut(at..at + row.len()) };
            copy_row(row, to);
        }
    }

    /// The pixel at offset `bad` of `part` (pixels from the current
    /// column) is above the bit depth: the frame is abandoned.
    #[cold]
    #[inline(never)]
    fn out_of_range(&mut self, part: &[u16], bad: usize) -> FrameError {
        let error = FrameError::PixelOutOfRange {
            row: self.row,
            column: self.column + bad as u16,
            value: part[bad],
        };
        self.start_frame();
        error
    }

    /// The current row is complete: on to the next one. Most rows only
    /// advance; the rows where windows close or open, and the frame's
    /// last, take [`row_events`](Self::row_events).
    #[inline(always)]
    fn end_row(&mut self, sink: &mut impl OutputSink) {
        self.cursor = 0;
        self.column = 0;
        self.row += 1;
        let width = self.config.camera.width as usize;
        self.bg_row += self.bg_stride;
        self.scan.gain_row += self.gain_stride;
        self.position_row += 1 << 6;
        if self.ring_end > 0 {
            self.history_row += width;
            if self.history_row == self.ring_end {
                self.history_row = 0;
            }
        }
        #[cfg(debug_assertions)]
        self.check_open_windows();
        if self.finished_in_row || self.row == self.event_row {
            self.row_events(sink);
        }
    }

    /// Debug builds, at every row's end: each open window's pre-filter
    /// passes every pixel its admission (`admit`) takes, and its tiers are
    /// in order. Its raw floor is at
    /// most `admit`'s (`calibrate::raw_floor`; lower only costs pixels the
    /// exact test then rejects) and `lanes` agrees with it, however the
    /// admission was last set (opening, a raise prepared by the engine and
    /// made by the row kernel, a stop, a compaction, the last row's
    /// preparation). A floor one value too high drops pixels only where
    /// their background is the window's least, which differential tests
    /// meet rarely; this meets it wherever the two floors differ.
    #[cfg(debug_assertions)]
    fn check_open_windows(&self) {
        for w in &self.memory.open[..self.open_len] {
            if w.capacity == 0 || w.rescan || w.finished || w.floor == 0 {
                continue;
            }
            let exact = super::calibrate::raw_floor(&self.config.calibration, w.bounds, w.admit)
                .min(self.max_raw as u32 + 1);
            debug_assert!(
                w.floor <= exact,
                "window {}: raw floor {} above admission {}'s, {exact}",
                w.index,
                w.floor,
                w.admit
            );
            debug_assert_eq!(w.lanes, (w.floor - 1).wrapping_mul(0x0001_0001));
            // The tiers within the buffer and apart; the front's counted
            // copies of the hint within it.
            debug_assert!(
                w.buffer <= w.front_end
                    && w.front_end <= w.back_start
                    && w.back_start
                        <= w.buffer
                            + w.capacity as usize * core::mem::size_of::<super::select::Entry>()
                    && w.at_hint <= w.counted
                    && w.counted as usize <= w.front(),
                "window {}: tiers out of order",
                w.index
            );
        }
    }

    /// What [`end_row`](Self::end_row) leaves to the rows where windows
    /// closed (in the row just ended) or open (in the new current row), and
    /// to a frame's end.
    #[inline(never)]
    fn row_events(&mut self, sink: &mut impl OutputSink) {
        let mut layout_changed = false;
        if self.finished_in_row {
            // Close finished windows, keeping the others in column order.
            let memory = &mut self.memory;
            let mut kept = 0;
            for k in 0..self.open_len {
                let window = &memory.open[k];
                if window.finished {
                    memory.free[self.free_len] = window.buffer_number;
                    self.free_len += 1;
                    if window.segment_start == window.segment_end {
                        self.not_ready -= 1;
                    }
                } else {
                    if kept != k {
                        memory.open[kept] = memory.open[k];
                    }
                    kept += 1;
                }
            }
            self.open_len = kept;
            self.finished_in_row = false;
            layout_changed = true;
        }
        if self.row == self.config.camera.height {
            self.frames = self.frames.wrapping_add(1);
            sink.frame_complete(self.frames);
            self.start_frame();
            return;
        }
        if self.row == self.prepare_row {
            self.prepare_last_row();
            self.update_event_row();
        }
        if self.opens_windows_in_row() {
            self.open_windows_of_row();
        } else if layout_changed {
            self.update_layout();
        }
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
        self.whole_frame = 0;
        self.ring_end = self.history_end;
        let c = &self.config.calibration;
        self.bg_row = c.background.map_or(0, |b| b.as_ptr() as usize);
        self.scan.gain_row = c.gain.map_or(0, |g| g.as_ptr() as usize);
        self.position_row = 0;
        self.next_to_open = 0;
        self.push_len = self.push_len_next_frame;
        self.update_event_row();
        self.update_layout();
        // The first row's windows open in `push_with`.
    }
}

/// [`copy_pixels`] for a whole row: the row and its place in the history are
/// both word-aligned when the camera's width is even and the caller's row
/// is (the usual case), and are then copied as words with no ends to mind.
#[inline(always)]
fn copy_row(from: &[u16], to: &mut [u16]) {
    let n = from.len().min(to.len());
    if (from.as_ptr() as usize | to.as_ptr() as usize) & 3 == 0 && n.is_multiple_of(2) {
        // SAFETY: both aligned to 4 and `n` (even) pixels long; any bits
        // are a u32 and a pair of u16.
        let (fw, tw) = unsafe {
            (
                core::slice::from_raw_parts(from.as_ptr() as *const u32, n / 2),
                core::slice::from_raw_parts_mut(to.as_mut_ptr() as *mut u32, n / 2),
            )
        };
        prefilter::copy_words(fw, tw);
    } else {
        copy_unaligned_row(from, to);
    }
}

/// [`copy_pixels`] out of line, for rows that are not word-aligned: inlined
/// into [`copy_row`], its set-up ran in every push (CANARY on Cortex-M4
/// 15.00 against 14.88 instructions a pixel).
#[inline(never)]
fn copy_unaligned_row(from: &[u16], to: &mut [u16]) {
    copy_pixels(from, to);
}

/// `Engine::variant` for `config`: bit 0 a background map, 1 a gain map, 2
/// a fixed threshold, 3 pixels checked against a bit depth below 16.
fn variant(config: &Config<'_>) -> u8 {
    let c = &config.calibration;
    let steps = c.background.is_some() as u8
        | (c.gain.is_some() as u8) << 1
        | (c.threshold.is_some() as u8) << 2
        | ((config.camera.max_raw() != u16::MAX) as u8) << 3;
    // The complement's row kernel takes a background map or none.
    if complement::applies(config) && c.gain.is_none() && c.threshold.is_none() {
        steps | COMPLEMENT_VARIANT
    } else {
        steps
    }
}

/// The [`variant`] bit of configurations whose windows may select the
/// complement (`complement`), with neither gain map nor fixed threshold.
const COMPLEMENT_VARIANT: u8 = 16;
const _: () = assert!(
    COMPLEMENT_VARIANT == 16,
    "`Engine::push` matches its values"
);

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

/// The offset of the first pixel of `raw` above `max_raw`, if any.
#[inline(always)]
pub(super) fn check_range(raw: &[u16], max_raw: u16) -> Result<(), usize> {
    if prefilter::any_at_least(raw, max_raw + 1) {
        Err(raw.iter().position(|&r| r > max_raw).unwrap_or(0))
    } else {
        Ok(())
    }
}
