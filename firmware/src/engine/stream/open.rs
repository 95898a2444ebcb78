//! Opening the windows whose first row is the current row: a candidate
//! buffer from the pool, the seed's thresholds, a place in column order;
//! and the open windows' layout flags.

use super::admission::FreshWindow;
use super::Engine;
use crate::engine::centroid::Moments;
use crate::engine::select::{preferred_capacity_of, Entry, Ties};
use crate::engine::window::{OpenWindow, Raise};

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
        if self.hint_above {
            self.open_windows::<true>();
        } else {
            self.open_windows::<false>();
        }
    }

    /// [`open_windows_of_row`](Self::open_windows_of_row), with each
    /// window's hint one above its seed's (`HINT_ABOVE`, see
    /// `Engine::hint_above`) or not. Out of line: inlined into
    /// `Engine::row_events` it cost that ~25 instructions a call, the
    /// frame's end among them (every last row +29).
    #[inline(never)]
    fn open_windows<const HINT_ABOVE: bool>(&mut self) {
        let windows = self.config.windows;
        let fresh = FreshWindow::of(self.config.selection.rule);
        // Windows of one row mostly share N and size: the capacity of the
        // last one, for the next if they match.
        let (mut last_n, mut last_pixels, mut last_capacity) = (u16::MAX, 0u16, 0u16);
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
            let state = &self.memory.subapertures[index];
            let (hint, low) = if capacity > 0 {
                let (hint, low) = state.seed.thresholds();
                (hint.saturating_add(HINT_ABOVE as i32), low)
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
            *lanes = 0;
            *admit = low;
            *position_base = 0u32
                .wrapping_sub((w.y as u32) << 6)
                .wrapping_sub(w.x as u32);
            *window_hint = hint;
            *front_end = buffer;
            *back_start = buffer + capacity as usize * core::mem::size_of::<Entry>();
            *window_attention = usize::MAX;
            *raise_lane = 0;
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
            *floor = 0;
            *finished = false;
            *strict = false;
            *raise = Raise::NONE;
            *rescan = false;
            *bounds = state.bounds;
            *moments = Moments::ZERO;
            // A window without selection keeps floor 0 (every segment to
            // `segment_rest`).
            let window = &mut open[k];
            if capacity > 0 {
                fresh.admit(window, &self.config, self.max_raw);
            }
            if !window.update_kernel_segment() {
                self.not_ready += 1;
            }
        }
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
