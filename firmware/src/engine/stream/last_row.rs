//! The frame's last row: what is left after the frame's last pixel is the
//! end of the windows in that row, and that is the latency the camera side
//! exists to cut. For `subtract-next` without a level filter most of a
//! window's end is done as the last row begins, from the candidates so far;
//! after the last pixel only the last row's few candidates are merged in.
//!
//! As the last row begins (or as many rows earlier as a push spans, so that
//! the push holding the frame's last pixel has nothing to prepare: DMA
//! runs of 512 pixels on a 112-pixel camera, six rows), a window whose
//! candidates reach `v(N+1)` (its back tier dropped, admission strict)
//! takes `u = v(N+1)` of its candidates so far (`F`: the front and the
//! hint's ties). The final `v(N+1)` is at least `u`, so from then on the
//! window admits only `p > u` (the set `L`), and of `F` only the pixels
//! above `u` can be kept: their sums
//! (`sum p`, `sum p i`, `sum p j`, `sum i`, `sum j`) and count `C` go near
//! the end of the window's candidate buffer, where `L` cannot reach.
//! At the end, with `l = |L|` pixels all above `u`: `v(N+1) = u` if
//! `C + l <= N` (the usual case: a window's last row is the edge of its
//! spot), else the `(C + l - N)`-th smallest of the pixels above `u`. The
//! moments of `p - v` over the pixels above `v` are the sums' closed form,
//! less `F`'s pixels between `u` and `v`, plus `L`'s above `v`: exact
//! integer identities, so the result is the ordinary end's bit for bit.
//! Any doubt (another path attended to the window in the last row, `v` too
//! deep among the pixels above `u`) falls back to the ordinary end, whose
//! candidates are all still in place.

use super::admission::{admit_at, settle_at_hint};
use super::{Engine, OutputSink};
use crate::engine::centroid::Moments;
use crate::engine::select::{self, Entry, Tiers, WindowRule};
use crate::engine::window::OpenWindow;
use brightpix_protocol::SelectionRule;

/// `OpenWindow::attention` of a window prepared for the last row (never an
/// address the front reaches, so the row kernel never stops there).
/// Whatever else attends to the window in the last row resets it, and the
/// window then takes the ordinary end.
pub(super) const PREPARED: usize = usize::MAX - 1;

/// The end finds `v(N+1)` above `u` as the `(C + l - N)`-th smallest of the
/// pixels above `u`, at most the `l`-th (`C <= N`, `u` being the (N+1)-th
/// largest of `F`): up to this many, in one pass keeping the smallest
/// (`select::extreme`); more, the ordinary end.
const MOST_SMALLEST: usize = 8;

/// Entries of the block near the buffer's end: `u` and the front's length,
/// the count and the coordinate sums, three for the 64-bit sums.
const BLOCK: usize = 5;

/// Below this N the coordinate sums of the pixels above `u` (at most N of
/// them, each coordinate below 64) fit 16 bits each, packed in one word.
const MOST_N: u16 = 1024;

/// Where the block starts, in entries before the buffer's end: one entry
/// is left free after it, since the row kernel's portable twin stores each
/// admitted pixel at both free ends of the buffer (only the front's copy
/// counts), so the entry before `back_start` is scribbled on.
const BLOCK_END: usize = BLOCK + 1;

impl Engine<'_, '_> {
    /// Pushes of `len` pixels from now on: where the windows of the
    /// frame's last row are prepared (`Engine::prepare_row`). A push that
    /// is whole rows spans `len / width` of them; any other, up to two
    /// more.
    #[cold]
    #[inline(never)]
    pub(super) fn set_prepare_row(&mut self, len: usize) {
        self.push_len = len;
        let (width, height) = (
            self.config.camera.width as usize,
            self.config.camera.height as usize,
        );
        let rows = if len.is_multiple_of(width) {
            len / width
        } else {
            len / width + 2
        };
        let prepares = self.config.selection.rule == SelectionRule::SubtractNext
            && self.config.selection.level_filter.is_none()
            && rows.max(1) < height / 2;
        self.prepare_row = if prepares {
            (height - rows.max(1)) as u16
        } else {
            u16::MAX
        };
        self.update_event_row();
    }

    /// `prepare_row` begins: prepares the windows that end in the frame's
    /// last row and began before this one.
    pub(super) fn prepare_last_row(&mut self) {
        let last = self.config.camera.height - 1;
        for k in 0..self.open_len {
            let window = &self.memory.open[k];
            if window.last_row == last && window.y < self.row {
                let rows_left = (last + 1 - self.row) as usize;
                let window = &mut self.memory.open[k];
                prepare(
                    window,
                    &self.config,
                    self.max_raw,
                    self.memory.scratch,
                    rows_left,
                );
            }
        }
    }
}

/// See the module documentation. Leaves the window as it was unless it can
/// be prepared: among other things, its buffer must have room for every
/// pixel of its `rows_left` rows still to come besides the block, so that
/// nothing the window admits from now on can reach the block.
#[inline(never)]
fn prepare(
    window: &mut OpenWindow,
    config: &brightpix_protocol::Config<'_>,
    max_raw: u16,
    scratch: &mut [i32],
    rows_left: usize,
) {
    if window.capacity == 0
        || window.n >= MOST_N
        || window.rescan
        || !window.strict
        || window.back() != 0
        || window.low_ties.count != 0
        || window.attention != usize::MAX
        || window.room_left() < rows_left * window.width as usize + BLOCK_END
    {
        return;
    }
    settle_at_hint(window);
    let front = window.front();
    let capacity = window.capacity as usize;
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    let rule = WindowRule {
        rule: SelectionRule::SubtractNext,
        n: window.n,
        pixels: window.pixels(),
    };
    let mut tiers = Tiers {
        front: &entries[..front],
        front_at_hint: window.at_hint,
        hint: window.hint,
        hint_ties: window.hint_ties.count,
        back: &[],
        low: window.low,
        low_ties: 0,
        complete: false,
        scratch,
    };
    let u = match select::cut(&rule, &mut tiers) {
        Ok(cut) if cut.cutoff >= window.hint && cut.cutoff < i32::MAX => cut.cutoff,
        _ => return,
    };
    let above = Above::sum(&entries[..front], u);
    let block = &mut entries[capacity - BLOCK_END..capacity - 1];
    block[0] = Entry {
        value: u,
        position: front as u32,
    };
    block[1] = Entry {
        value: above.count as i32,
        position: above.sum_ij,
    };
    for (slot, sum) in block[2..5]
        .iter_mut()
        .zip([above.sum_p, above.sum_pi, above.sum_pj])
    {
        *slot = Entry {
            value: sum as i32,
            position: (sum >> 32) as u32,
        };
    }
    window.attention = PREPARED;
    admit_at(window, config, max_raw, u + 1);
}

impl Engine<'_, '_> {
    /// The end of window `k`, prepared for the last row: `false` (nothing
    /// done) if the ordinary end must compute it. Out of line, so that the
    /// ordinary end's code is what it was without preparation (inlined,
    /// this end moved the Cortex-M7's code for every rule: threshold 17.40
    /// -> 17.83 instructions a pixel).
    #[inline(never)]
    pub(super) fn finish_prepared(&mut self, k: usize, sink: &mut impl OutputSink) -> bool {
        let window = &mut self.memory.open[k];
        // SAFETY: the window's buffer (opened with it), no other reference
        // to it alive.
        let entries: &[Entry] = unsafe { window.entries() };
        let Some((v, moments)) = prepared_end(window, entries) else {
            return false;
        };
        self.finished_in_row = true;
        window.finished = true;
        self.stats.windows = self.stats.windows.wrapping_add(1);
        let held = window.front() + window.hint_ties.count as usize;
        self.stats.candidates = self.stats.candidates.wrapping_add(held as u32);
        self.memory.subapertures[window.index as usize]
            .seed
            .observe(v, false);
        sink.subaperture(self.centroider.result(
            window.index,
            moments,
            window.width,
            window.height,
        ));
        true
    }
}

/// A prepared window's `v(N+1)` and moments (see the module
/// documentation), or `None` if the ordinary end must compute them.
fn prepared_end(window: &OpenWindow, entries: &[Entry]) -> Option<(i32, Moments)> {
    let capacity = window.capacity as usize;
    let block = &entries[capacity - BLOCK_END..capacity - 1];
    let (u, prepared_front) = (block[0].value, block[0].position as usize);
    let count = block[1].value as usize;
    let sum_ij = block[1].position;
    let (sum_i, sum_j) = ((sum_ij & 0xffff) as i64, (sum_ij >> 16) as i64);
    let sum = |e: Entry| (e.value as u32 as i64) | ((e.position as i64) << 32);
    let (sum_p, sum_pi, sum_pj) = (sum(block[2]), sum(block[3]), sum(block[4]));
    let before = &entries[..prepared_front];
    let last = &entries[prepared_front..window.front()];
    let n = window.n as usize;
    let above = count + last.len();
    let v = if above <= n {
        u
    } else {
        // The m-th smallest pixel above u (m <= |L|, since C <= N).
        let m = above - n;
        if m > MOST_SMALLEST {
            return None;
        }
        let values = before.iter().map(|e| e.value).filter(|&p| p > u);
        select::extreme::<false>(values.chain(last.iter().map(|e| e.value)), m)
    };
    let v64 = v as i64;
    let mut moments = Moments {
        sum_w: sum_p - v64 * count as i64,
        sum_wi: sum_pi - v64 * sum_i,
        sum_wj: sum_pj - v64 * sum_j,
    };
    if v > u {
        // F's pixels above u and below v were summed with a negative weight.
        for e in before.iter().filter(|e| e.value > u && e.value < v) {
            weigh(&mut moments, e, v64, -1);
        }
    }
    for e in last.iter().filter(|e| e.value > v) {
        weigh(&mut moments, e, v64, 1);
    }
    Some((v, moments))
}

/// Adds (`sign` 1) or takes away (-1) `e`'s weight `p - v` in the moments.
#[inline(always)]
fn weigh(moments: &mut Moments, e: &Entry, v: i64, sign: i64) {
    let w = sign * (e.value as i64 - v);
    moments.sum_w += w;
    moments.sum_wi += w * (e.position & 63) as i64;
    moments.sum_wj += w * ((e.position >> 6) & 63) as i64;
}

/// Sums over the front's pixels above `u`: `p`, `p i`, `p j`, their number,
/// and `i + 2^16 j` (at most N < 2^10 pixels, so neither half carries).
struct Above {
    sum_p: i64,
    sum_pi: i64,
    sum_pj: i64,
    count: u32,
    sum_ij: u32,
}

impl Above {
    /// One pass, its accumulators in registers (inlined into the engine's
    /// row events they were kept on the stack: 26 instructions a pixel).
    #[inline(never)]
    fn sum(front: &[Entry], u: i32) -> Above {
        let mut above = Above {
            sum_p: 0,
            sum_pi: 0,
            sum_pj: 0,
            count: 0,
            sum_ij: 0,
        };
        for e in front {
            if e.value > u {
                let (p, i, j) = (e.value as i64, e.position & 63, (e.position >> 6) & 63);
                above.sum_p += p;
                above.sum_pi += p * i as i64;
                above.sum_pj += p * j as i64;
                above.count += 1;
                above.sum_ij += i | (j << 16);
            }
        }
        above
    }
}
