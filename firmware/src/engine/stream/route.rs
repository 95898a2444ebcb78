//! A camera row's pixels routed to the open windows: runs of kernel-ready
//! windows to the row kernel (`scan::row`), the others a window at a time on
//! the general path (`scan::scan`), with the gaps between windows checked
//! against the bit depth in raster order.

use super::admission::{attention, make_room, place, raise_to_hint, update_admission};
use super::{check_range, complement, Engine, OutputSink};
use crate::engine::calibrate::{self, Steps};
use crate::engine::scan::{self, scan, RowStop, Segment, Stop};
use crate::engine::select::pack;
use crate::engine::window::{OpenWindow, SegmentPath};

impl Engine<'_, '_> {
    /// A whole camera row. On a pixel out of range, returns its column; the
    /// windows whose last pixel came before it have been emitted, no other.
    ///
    /// Windows are visited in column order: each run of `kernel_ready` ones
    /// by the row kernel, the others on the general path. That needs a
    /// word-aligned row, and below 16 bits (where the first pixel out of
    /// range must be found in raster order) every pixel of the row in a
    /// window, since only windows' pixels are checked.
    #[inline(always)]
    pub(super) fn push_whole_row<S: Steps, const CHECK: bool, const COMPLEMENT: bool>(
        &mut self,
        row_pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        let row_address = row_pixels.as_ptr() as usize;
        if row_address & 3 != 0 || (CHECK && !self.gapless) {
            return self.push_whole_row_general::<S, CHECK>(row_pixels, sink);
        }
        let row = self.row;
        if self.not_ready == 0 {
            // Every open window is kernel-ready: one kernel pass.
            if let Some((window, pixel)) = self.kernel_run_all::<S, CHECK>(row_address) {
                self.finish_before(window, sink);
                return Err((pixel - row_address) / 2);
            }
            if row == self.next_last_row {
                self.finish_last_row(sink);
            }
            return Ok(());
        }
        if COMPLEMENT && self.all_complement {
            return self.complement_row::<S, CHECK>(row_address, sink);
        }
        self.push_mixed_row::<S, CHECK>(row_pixels, sink)
    }

    /// [`push_whole_row`](Self::push_whole_row) when some open window is
    /// not kernel-ready: runs of ready windows to the kernel, the others
    /// one by one. Out of line: its loop's registers (every window of a
    /// row without selection takes it) then do not depend on the code
    /// around it (once cost no selection +0.25 instructions a pixel).
    #[inline(never)]
    fn push_mixed_row<S: Steps, const CHECK: bool>(
        &mut self,
        row_pixels: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        let row_address = row_pixels.as_ptr() as usize;
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
            self.finish_last_row(sink);
        }
        Ok(())
    }

    /// The windows whose last row is the current row, finished.
    #[inline(always)]
    pub(super) fn finish_last_row(&mut self, sink: &mut impl OutputSink) {
        for k in 0..self.open_len {
            if self.memory.open[k].last_row == self.row {
                self.finish(k, sink);
            }
        }
    }

    /// [`kernel_run`](Self::kernel_run) over every open window: the
    /// kernel's window range is already theirs (`update_layout`).
    #[inline(always)]
    fn kernel_run_all<S: Steps, const CHECK: bool>(
        &mut self,
        row_address: usize,
    ) -> Option<(usize, usize)> {
        let first = self.scan.first;
        let stopped = self.kernel_pass::<S, CHECK>(row_address, first);
        self.scan.first = first;
        stopped
    }

    /// The row kernel over the open windows `k .. end` (all
    /// `kernel_ready`), of the current row at `row_address` (word-aligned).
    /// On a pixel out of range (`CHECK`), the index of its window and its
    /// address.
    pub(super) fn kernel_run<S: Steps, const CHECK: bool>(
        &mut self,
        row_address: usize,
        k: usize,
        end: usize,
    ) -> Option<(usize, usize)> {
        const SIZE: usize = core::mem::size_of::<OpenWindow>();
        let first = self.scan.first;
        self.scan.first = first + k * SIZE;
        let stopped = if end < self.open_len {
            self.kernel_pass_to::<S, CHECK>(row_address, first, end)
        } else {
            self.kernel_pass::<S, CHECK>(row_address, first)
        };
        self.scan.first = first;
        stopped
    }

    /// [`kernel_pass`](Self::kernel_pass) over the windows up to `end`,
    /// short of the last open one: the range's end mark on window `end`
    /// for the pass (after the last open window there is always one).
    #[inline(never)]
    fn kernel_pass_to<S: Steps, const CHECK: bool>(
        &mut self,
        row_address: usize,
        first: usize,
        end: usize,
    ) -> Option<(usize, usize)> {
        let all = self.scan.end;
        self.scan.end = first + end * core::mem::size_of::<OpenWindow>();
        let was = self.memory.open[end].mark_end();
        let stopped = self.kernel_pass::<S, CHECK>(row_address, first);
        self.memory.open[end].unmark_end(was);
        self.scan.end = all;
        stopped
    }

    /// The kernel's calls over its window range for the row at
    /// `row_address`, attending to the windows it stops at; window indices
    /// are counted from `first`, the open windows' first. Leaves
    /// `scan.first` past the last window attended.
    #[inline(always)]
    fn kernel_pass<S: Steps, const CHECK: bool>(
        &mut self,
        row_address: usize,
        first: usize,
    ) -> Option<(usize, usize)> {
        const SIZE: usize = core::mem::size_of::<OpenWindow>();
        self.scan_row(row_address);
        loop {
            // SAFETY: the windows of the kernel's range are kernel-ready
            // and their segments lie in the row the caller holds.
            match unsafe { scan::row::<S, CHECK>(&mut self.scan) } {
                RowStop::Done => return None,
                RowStop::Attention(address) => {
                    self.attend((address - first) / SIZE);
                    self.scan.first = address + SIZE;
                }
                RowStop::OutOfRange { window, pixel } => {
                    return Some(((window - first) / SIZE, pixel))
                }
            }
        }
    }

    /// The row kernels' arguments for the row at `row_address`.
    #[inline(always)]
    pub(super) fn scan_row(&mut self, row_address: usize) {
        self.scan.row = row_address;
        self.scan.bg_delta = self.bg_row.wrapping_sub(2 * row_address).wrapping_sub(16);
        self.scan.position_delta = self
            .position_row
            .wrapping_sub(4)
            .wrapping_sub((row_address >> 1) as u32);
    }

    /// A pixel out of range in window `k`'s segment of a gapless row: the
    /// windows before it that end in this row are complete.
    #[cold]
    pub(super) fn finish_before(&mut self, k: usize, sink: &mut impl OutputSink) {
        for j in 0..k {
            if self.memory.open[j].last_row == self.row {
                self.finish(j, sink);
            }
        }
    }

    /// [`push_whole_row`](Self::push_whole_row) a window at a time, on the
    /// general path: for rows the kernel cannot take. Windows are visited
    /// left to right and each gap is checked before the window after it.
    pub(super) fn push_whole_row_general<S: Steps, const CHECK: bool>(
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
    pub(super) fn push_row_part<S: Steps, const CHECK: bool>(
        &mut self,
        part: &[u16],
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        if let Some(outcome) = self.kernel_part::<S, CHECK>(part, sink) {
            return outcome;
        }
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

    /// [`push_row_part`](Self::push_row_part) in one row-kernel pass, for a
    /// part that starts and ends at even columns of a word-aligned row
    /// whose open windows are disjoint and all kernel-ready (below 16 bits,
    /// also gapless, so that the kernel checks every pixel of the part in
    /// raster order): as a camera's DMA runs deliver rows, in pieces that
    /// need not follow windows. The windows the part's ends cut are
    /// scanned over their columns in the part (their kernel segments
    /// narrowed for the pass, then restored): a window's row in two pieces
    /// admits what it admits whole, as on the general path. `None`: the
    /// part is not such a part (nothing done).
    #[inline(never)]
    fn kernel_part<S: Steps, const CHECK: bool>(
        &mut self,
        part: &[u16],
        sink: &mut impl OutputSink,
    ) -> Option<Result<(), usize>> {
        let start = self.column;
        let end = start + part.len() as u16;
        let row_address = (part.as_ptr() as usize).wrapping_sub(2 * start as usize);
        if row_address & 3 != 0
            || (start | end) & 1 != 0
            || self.not_ready != 0
            || !self.disjoint
            || (CHECK && !self.gapless)
        {
            return None;
        }
        // The windows the part overlaps: from the cursor (the first not
        // done with the row, which ends after `start`) to the first that
        // starts at or after `end`.
        let first = self.cursor;
        let mut stop = first;
        while stop < self.open_len && self.memory.open[stop].x < end {
            stop += 1;
        }
        if first == stop {
            return Some(Ok(()));
        }
        let last = stop - 1;
        {
            let open = &mut self.memory.open;
            if open[first].x < start {
                open[first].segment_start = 2 * start as u32;
            }
            if open[last].end_column > end {
                open[last].segment_end = 2 * end as u32;
            }
        }
        let stopped = self.kernel_run::<S, CHECK>(row_address, first, stop);
        for k in [first, last] {
            let window = &mut self.memory.open[k];
            // Still kernel-ready (an attention stop may have made it not):
            // its whole segment again.
            if window.segment_start != window.segment_end {
                window.segment_start = 2 * window.x as u32;
                window.segment_end = 2 * window.end_column as u32;
            }
        }
        let (done, outcome) = match stopped {
            None => (stop, Ok(())),
            Some((k, pixel)) => (k, Err((pixel - part.as_ptr() as usize) / 2)),
        };
        let row = self.row;
        for k in first..done {
            let window = &self.memory.open[k];
            if window.last_row == row && window.end_column <= end {
                self.finish(k, sink);
            }
        }
        if outcome.is_ok() {
            self.cursor = if self.memory.open[last].end_column <= end {
                stop
            } else {
                last
            };
        }
        Some(outcome)
    }

    /// One window's pixels of the current row on the general path: columns
    /// `i0 ..` of its row `j`, `pixel` the row-major index of the first.
    /// Returns the offset of a pixel out of range.
    #[inline(always)]
    pub(super) fn segment<S: Steps, const CHECK: bool>(
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
    pub(super) fn segment_rest<S: Steps, const CHECK: bool>(
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
            if window.attention == complement::COMPLEMENT {
                return self.complement_segment::<S, CHECK>(k, raw, pixel, i0, j);
            }
            return if CHECK {
                check_range(raw, self.max_raw)
            } else {
                Ok(())
            };
        }
        self.segment_candidates::<S, CHECK>(k, raw, pixel, i0, j)
    }

    /// [`segment_rest`](Self::segment_rest) for a window that selects: its
    /// pixels admitted on the general path. Out of line, so that a window
    /// without selection does not pay for its registers: in one body with
    /// it, Cortex-M7's no-selection row cost 0.3-0.4 instructions a pixel
    /// more (16.92-17.05 against 16.6).
    #[inline(never)]
    fn segment_candidates<S: Steps, const CHECK: bool>(
        &mut self,
        k: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
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
            update_admission(window, &self.config, max_raw);
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
}
