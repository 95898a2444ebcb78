//! Opening the windows whose first row is the current row: a candidate
//! buffer from the pool, the seed's thresholds, a place in column order;
//! and the open windows' layout flags.

use super::admission::{FreshAdmission, FreshWindow};
use super::Engine;
use crate::engine::centroid::Moments;
use crate::engine::seed::MarginFloor;
use crate::engine::select::{preferred_capacity_of, Entry, Ties};
use crate::engine::window::OpenWindow;

impl Engine<'_, '_> {
    /// Whether some window's first row is the current row (most rows open
    /// none: a cheap test before the loop, whose set-up is not).
    #[inline(always)]
    pub(super) fn opens_windows_in_row(&self) -> bool {
        let windows = self.config.windows;
        self.memory.order[..windows.len()]
            .get(self.next_to_open)
            .is_some_and(|&index| windows[index as usize].y == self.row)
    }
    /// `event_row` after `next_to_open` changed: the next window's first
    /// row, or the frame's end; or `prepare_row`, if it is earlier.
    pub(super) fn update_event_row(&mut self) {
        let windows = self.config.windows;
        let height = self.config.camera.height;
        let next = self.memory.order[..windows.len()]
            .get(self.next_to_open)
            .map_or(height, |&index| windows[index as usize].y);
        self.event_row = if self.row < self.prepare_row {
            next.min(self.prepare_row)
        } else {
            next
        };
    }

    /// Opens the windows whose first row is the current row.
    pub(super) fn open_windows_of_row(&mut self) {
        // An instance each: `subtract-next-distinct`'s raised hints in the
        // other rules' loop cost them register room (Cortex-M7 CANARY
        // +0.03 instructions a pixel, 8x8 windows +0.11).
        // Likewise for a calibration without gain map or fixed threshold,
        // whose raw floors take no test of it (`FreshWindow::admission`).
        // And for the windows that end in the frame's last row (their
        // margin's floor, `Seed::thresholds`, an immediate in each: as a
        // value held through the loop it cost 8x8 windows 0.04
        // instructions a pixel more, tested at each window 0.12).
        let c = &self.config.calibration;
        let plain = c.gain.is_none() && c.threshold.is_none();
        let last = self.opens_into_last_row();
        match (self.hint_above, plain, last) {
            (true, true, true) => self.open_windows::<true, true, true>(),
            (true, false, true) => self.open_windows::<true, false, true>(),
            (false, true, true) => self.open_windows::<false, true, true>(),
            (false, false, true) => self.open_windows::<false, false, true>(),
            (true, true, false) => self.open_windows::<true, true, false>(),
            (true, false, false) => self.open_windows::<true, false, false>(),
            (false, true, false) => self.open_windows::<false, true, false>(),
            (false, false, false) => self.open_windows::<false, false, false>(),
        }
    }

    /// Whether the first window this row opens ends in the frame's last
    /// row. The row's other windows are taken to as well: only speed
    /// depends on it, and a row's windows share their height in all but
    /// unusual layouts.
    fn opens_into_last_row(&self) -> bool {
        let windows = self.config.windows;
        self.memory.order[..windows.len()]
            .get(self.next_to_open)
            .is_some_and(|&first| {
                windows[first as usize].last_row() + 1 == self.config.camera.height
            })
    }

    /// [`open_windows_of_row`](Self::open_windows_of_row), with each
    /// window's hint one above its seed's (`HINT_ABOVE`, see
    /// `Engine::hint_above`) or not; `PLAIN` as in `FreshWindow::admission`;
    /// `LAST_ROW`: the windows end in the frame's last row
    /// ([`MarginFloor`]).
    /// Out of line: inlined into
    /// `Engine::row_events` it cost that ~25 instructions a call, the
    /// frame's end among them (every last row +29).
    #[inline(never)]
    fn open_windows<const HINT_ABOVE: bool, const PLAIN: bool, const LAST_ROW: bool>(&mut self) {
        let windows = self.config.windows;
        let fresh = FreshWindow::of(self.config.selection.rule);
        // Windows of one row mostly share N and size: the capacity of the
        // last one, for the next if they match.
        let (mut last_n, mut last_pixels, mut last_capacity) = (u16::MAX, 0u16, 0u16);
        // The counts in locals, written back once (stored at each window
        // they cost it three instructions).
        let (mut next, mut free_len, mut open_len) =
            (self.next_to_open, self.free_len, self.open_len);
        let floor = MarginFloor::of(LAST_ROW);
        while next < windows.len() {
            // SAFETY: `order` holds a permutation of the windows' indices
            // (`plan`), one a window, and the memory holds a sub-aperture
            // state for each (`MemorySize::subapertures`, checked at
            // configuration): the accesses below by `next` and `index` are
            // in bounds (unchecked, ~8 instructions a window fewer).
            let index = unsafe { *self.memory.order.get_unchecked(next) } as usize;
            debug_assert!(index < windows.len() && index < self.memory.subapertures.len());
            let w = unsafe { *windows.get_unchecked(index) };
            if w.y != self.row {
                break;
            }
            next += 1;
            // Capacity was proved sufficient when the engine was configured.
            free_len -= 1;
            let number = self.memory.free[free_len];
            let n = self.config.pixel_count(index);
            // At most 64 x 64 (`Config::validate`): a u16.
            let pixels = w.width * w.height;
            if n != last_n || pixels != last_pixels {
                // The stride is at least every window's least capacity (plan).
                last_capacity = preferred_capacity_of::<HINT_ABOVE>(
                    self.config.selection.rule,
                    n,
                    pixels as usize,
                )
                .min(self.stride as u16);
                (last_n, last_pixels) = (n, pixels);
            }
            let capacity = last_capacity;
            // SAFETY: see `index`.
            let state = unsafe { self.memory.subapertures.get_unchecked(index) };
            let (hint, low) = if capacity > 0 {
                let (hint, low) = state.seed.thresholds(floor);
                (hint.saturating_add(HINT_ABOVE as i32), low)
            } else {
                (0, 0)
            };
            // Its place in column order.
            let open = &mut self.memory.open;
            let mut k = open_len;
            while k > 0 && open[k - 1].x > w.x {
                k -= 1;
            }
            if k < open_len {
                open.copy_within(k..open_len, k + 1);
            }
            open_len += 1;
            let buffer = self.pool + number as usize * self.stride * core::mem::size_of::<Entry>();
            // Field by field, in place, through a pattern that names every
            // field (so a new one fails to compile here until it is set): as
            // one struct literal the compiler built part of it on the stack
            // and copied it with a byte-wise `memcpy` call (~200
            // instructions a window on Cortex-M4). The segment's two fields
            // are `update_kernel_segment`'s, below.
            let OpenWindow {
                segment_start: _,
                segment_end: _,
                lanes,
                admit,
                position_base,
                hint: window_hint,
                front_end,
                back_start,
                attention: window_attention,
                raise_lane,
                short_of_room,
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
                raise,
                rescan,
                bounds,
                moments,
            } = &mut open[k];
            *position_base = 0u32
                .wrapping_sub((w.y as u32) << 6)
                .wrapping_sub(w.x as u32);
            *window_hint = hint;
            *front_end = buffer;
            *back_start = buffer + capacity as usize * core::mem::size_of::<Entry>();
            // `width >= 1` (`Config::validate`).
            *short_of_room = 8 * (w.width - 1);
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
            *finished = false;
            *strict = false;
            *rescan = false;
            *bounds = state.bounds;
            *moments = Moments::ZERO;
            // A window without selection keeps floor 0 (every segment to
            // `segment_rest`).
            let admission = if capacity > 0 {
                fresh.admission::<PLAIN>(
                    (low, hint),
                    state.bounds,
                    n,
                    buffer,
                    &self.config,
                    self.max_raw,
                )
            } else {
                FreshAdmission::NONE
            };
            *lanes = admission.lanes;
            *admit = admission.admit;
            *window_attention = admission.attention;
            *raise_lane = admission.raise_lane;
            *floor = admission.floor;
            *raise = admission.raise;
            let window = &mut open[k];
            #[cfg(debug_assertions)]
            if capacity > 0 {
                FreshWindow::check(window, &self.config, self.max_raw);
            }
            if !window.update_kernel_segment() {
                self.not_ready += 1;
            }
        }
        (self.next_to_open, self.free_len, self.open_len) = (next, free_len, open_len);
        self.update_event_row();
        self.update_layout();
    }

    /// The open windows' layout flags: `disjoint`, `gapless` and
    /// `next_last_row`.
    pub(super) fn update_layout(&mut self) {
        // One pass: `end` is where the previous window ends (0 before the
        // first), so the first window's start and the gaps read alike.
        let (mut disjoint, mut gapless) = (true, true);
        let (mut end, mut next_last_row) = (0, u16::MAX);
        for w in &self.memory.open[..self.open_len] {
            disjoint &= end <= w.x;
            gapless &= end == w.x;
            end = w.end_column;
            next_last_row = next_last_row.min(w.last_row);
        }
        self.disjoint = disjoint;
        self.gapless = self.open_len > 0 && gapless && end == self.config.camera.width;
        self.next_last_row = next_last_row;
        if self.complement {
            self.update_complement();
        }
        // The row kernel's range: every open window, up to the end mark
        // after the last (`memory.open` has a slot for it).
        self.memory.open[self.open_len].mark_end();
        let first = self.memory.open.as_mut_ptr() as usize;
        self.scan.first = first;
        self.scan.end = first + self.open_len * core::mem::size_of::<OpenWindow>();
    }
}
