//! The frame's last row: what is left after the frame's last pixel is the
//! end of the windows in that row, and that is the latency the camera side
//! exists to cut. For every rule most of a window's end is done as the
//! last row begins, from the candidates so far; after the last pixel only
//! the last row's few candidates are merged in, and a level filter's
//! state is updated from the frame's level (`closed_form` gives the
//! moments at the filtered level). `subtract-next` first, then what the
//! other rules do differently.
//!
//! As the last row begins (or, when pushes span several rows, as the row
//! begins in which the push holding the frame's last pixel starts, so
//! that that push has nothing to prepare: `Engine::set_prepare_row`), a
//! window whose candidates reach `v(N+1)` (its back tier dropped,
//! admission strict) takes `u = v(N+1)` of its candidates so far (`F`: the
//! front and the hint's ties). A window whose front still falls short of N + 1 (its
//! spot dimmed or moved since the hint was set: a quarter of the ELT
//! workload's last windows) first lowers its hint to that `u`, which then
//! lies in its back tier, keeping the back's entries at or above it
//! ([`lower_hint_to_cutoff`]), and is prepared the same way. The final
//! `v(N+1)` is at least `u`, so from then on the
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
//! The arithmetic is `closed_form`'s. If anything else attends to the
//! window in the last row (the general path, a kernel stop, a compaction)
//! the window ends the ordinary way, on its candidates, all still in place.
//!
//! `threshold` (DARC's default: `p >= v(N)` kept, weighing `p`) is
//! prepared the same way with `u = v(N)` of the candidates so far, but
//! keeps ties with the cutoff, so from then on the window admits
//! `p >= u`, and the sums are of `F`'s pixels at or above `u`. Fewer than
//! N of `F` are above `u`; at the end `v(N)` is still `u` unless the last
//! row's pixels above `u` make N (counted only when it brought some, the
//! usual case being none), and then every pixel at or above `u` is kept:
//! the sums plus every pixel of `L`, at a level of 0. When they do make
//! N, the window ends the ordinary way (`prepared_threshold_end`). A
//! raised `threshold` window need not be strict (its hint may still be
//! `v(N)`), so it is prepared once its back tier is gone, with no hint
//! ties (copies of the hint outside the buffer, which would weigh).
//!
//! `subtract-next-distinct` (DARC's subtract mode: `p >= v(N)` kept,
//! weighing `p - b`, `b` the largest value below `v(N)`) and
//! `subtract-mean` (weighing `p` less the floored mean of the M largest
//! below `v(N)`) take `u = v(N)`, the level and `w`, the smallest value
//! that sets it (`b`, or the M-th largest below `u`), of their candidates
//! so far when `w` is at or above the hint, so that the back tier can go
//! ([`prepare_level_rule`]), or with the hint first lowered to `w` when
//! the cutoff fell below it ([`lower_hint_to`], as above); the window then
//! admits `p > w` (nothing at or below `w` can change the level). At the
//! end, `v(N)` is still `u` unless the last row's pixels above `u` make N,
//! and the level stays unless the last row brought values between `w` and
//! `u`: for distinct the largest of them is then the level, for mean the
//! window ends the ordinary way, as it does when `v(N)` moved. The sums
//! and the last row's pixels at or above `u` weigh at the level
//! (`prepared_level_end`).

use super::admission::{admit_at, attention, settle_at_hint, update_admission};
use super::closed_form::{cutoff_and_moments, filtered_below, weigh};
use super::finish::{rescan_bound, WindowRows};
use super::{Engine, OutputSink};
use crate::engine::centroid::{self, Moments, SumsAbove};
use crate::engine::select::{self, Cut, Entry, Tiers, TooShallow, WindowRule};
use crate::engine::window::{OpenWindow, Raise};
use brightpix_protocol::SelectionRule;

/// `OpenWindow::attention` of a window prepared for the last row (never an
/// address the front reaches, so the row kernel never stops there).
/// Whatever else attends to the window in the last row resets it, and the
/// window then takes the ordinary end.
pub(super) const PREPARED: usize = usize::MAX - 1;

/// Entries of the block near the buffer's end: `u` and the front's length,
/// the count and the coordinate sums, three for the 64-bit sums.
const BLOCK: usize = 5;

/// Below this N the coordinate sums of the pixels above `u` (at most N of
/// them, each coordinate below 64) fit 16 bits each, packed in one word.
const MOST_N: u16 = 1024;

/// For `subtract-next-distinct` and `subtract-mean`, the entry before the
/// block holds the candidates' level at preparation and the smallest value
/// that set it (`w`).
const LEVEL: usize = 1;

/// Whether a rule's last row is prepared with its level
/// ([`prepare_level_rule`]): `subtract-next-distinct` and `subtract-mean`.
#[inline(always)]
fn level_rule(rule: SelectionRule) -> bool {
    matches!(
        rule,
        SelectionRule::SubtractNextDistinct | SelectionRule::SubtractMean { .. }
    )
}

/// Where the block starts, in entries before the buffer's end: one entry
/// is left free after it, since the row kernel's portable twin stores each
/// admitted pixel at both free ends of the buffer (only the front's copy
/// counts), so the entry before `back_start` is scribbled on.
const BLOCK_END: usize = BLOCK + 1;

/// [`lower_hint_to_cutoff`] only up to this N: with more, the prepared
/// end's selection among the (about N) pixels above `u` costs more than
/// the closed form that ends the window without lowering (Cortex-M4,
/// CANARY N = 200: 39.61 instructions a pixel and a last row of 29,125
/// when lowered, 38.53 and 25,594 when not; N = 20 and the ELT workload
/// are lowered).
const MOST_LOWERED_N: usize = 32;

impl Engine<'_, '_> {
    /// Pushes of `len` pixels from now on: where the windows of the
    /// frame's last row are prepared (`Engine::prepare_row`). If the pushes
    /// from here to the frame's end are all `len` long (a camera's runs
    /// are), the push holding the frame's last pixel starts a whole number
    /// of them from here: they are prepared as the row it starts in begins,
    /// the latest row whose start is in an earlier push. A push of another
    /// length sets it again. Only speed depends on it: prepared earlier, a
    /// window's preparation has seen fewer of its pixels and the prepared
    /// end does more (DMA runs of nine 112-pixel rows prepared nine rows
    /// before the last instead of four: CANARY +0.3 instructions a pixel
    /// on Cortex-M4); later, in the push holding the last pixel, it adds
    /// to the work after that pixel; after a frame that pushes of this
    /// length do not divide, again at the next push
    /// (`Engine::push_len_next_frame`). Not at all with pushes of half a
    /// frame or more.
    #[cold]
    #[inline(never)]
    pub(super) fn set_prepare_row(&mut self, len: usize) {
        self.push_len = len;
        let (width, height) = (
            self.config.camera.width as usize,
            self.config.camera.height as usize,
        );
        self.push_len_next_frame = if (width * height).is_multiple_of(len.max(1)) {
            len
        } else {
            0
        };
        // The rows a push spans: a push that is whole rows `len / width` of
        // them; any other, up to two more.
        let rows = if len.is_multiple_of(width) {
            len / width
        } else {
            len / width + 2
        };
        let rule = self.config.selection.rule;
        let prepared_rule = matches!(rule, SelectionRule::SubtractNext | SelectionRule::Threshold)
            || level_rule(rule);
        let prepares = prepared_rule && rows.max(1) < height / 2;
        self.prepare_row = if prepares {
            // The next pixel is `here` (a row of the frame: `row < height`).
            let here = self.row as usize * width + self.column as usize;
            let last = width * height - 1;
            let len = len.max(1);
            ((here + (last - here) / len * len) / width) as u16
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
                let (config, max_raw) = (&self.config, self.max_raw);
                let window = &mut self.memory.open[k];
                let short = prepare(window, config, max_raw, self.memory.scratch, rows_left);
                if short > 0 && self.take_missed_rows(k, rows_left, short) {
                    let window = &mut self.memory.open[k];
                    prepare(
                        window,
                        &self.config,
                        max_raw,
                        self.memory.scratch,
                        rows_left,
                    );
                }
            }
        }
    }

    /// A window whose candidates so far fall `short` of its cutoff as it
    /// is prepared (by about that many: its seed was too high), and whose
    /// rows still to come are unlikely to make up for it (its last row so
    /// far brought no more candidates than the row before, and the rows
    /// left, at that many each, would not make `short`: a spot's window
    /// ends in background, a ramp's does not), would be rescanned after
    /// the last pixel. It takes the pixels it missed from its rows so far
    /// instead, down to the bound a rescan would start from
    /// ([`rescan_bound`]): those in `[bound, low)` join its back tier, and
    /// `low` becomes the bound. The rescan's reading then comes before the
    /// last row, not after it, and the window can be prepared. `false`,
    /// the window unchanged, if the rows to come may make up for it, or the
    /// pixels would leave fewer entries free than every pixel still to come
    /// and the block. Counted as a rescan.
    #[cold]
    #[inline(never)]
    fn take_missed_rows(&mut self, k: usize, rows_left: usize, short: usize) -> bool {
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
        let rows_so_far = (self.row - window.y) as usize;
        let (front, back, capacity) = (window.front(), window.back(), window.capacity as usize);
        // SAFETY: the window's live buffer, no other reference to it.
        let entries = unsafe { window.entries() };
        // Candidates in the last two rows so far (`recent`, `before`).
        let (mut recent, mut before) = (0, 0);
        for e in entries[..front].iter().chain(&entries[capacity - back..]) {
            let j = select::row(e.position as u16) as usize + 2;
            recent += (j == rows_so_far + 1) as usize;
            before += (j == rows_so_far) as usize;
        }
        if recent > before || recent * rows_left >= short {
            return false;
        }
        let reserve = rows_left * window.width as usize + BLOCK_END + LEVEL;
        let Some(most) = window.room_left().checked_sub(reserve) else {
            return false;
        };
        let rows = WindowRows::new(
            memory.history,
            self.history_rows,
            self.whole_frame,
            &self.config,
        );
        let bound = rescan_bound(window.low, window.hint);
        let range = (bound, window.low);
        let most = most.min(memory.rescan.len());
        let out = &mut memory.rescan[..most];
        let calibrator = &self.calibrator;
        let Some(added) = rows.between(window, calibrator, range, rows_so_far, out) else {
            return false;
        };
        self.stats.rescans = self.stats.rescans.wrapping_add(1);
        let at = capacity - back - added;
        entries[at..capacity - back].copy_from_slice(&out[..added]);
        window.set_back(back + added);
        window.low = bound;
        update_admission(window, &self.config, self.max_raw);
        window.attention = attention(window, self.config.selection.rule);
        self.refresh_ready(k);
        true
    }
}

/// See the module documentation. Leaves the window as it was unless it can
/// be prepared: among other things, its buffer must have room for every
/// pixel of its `rows_left` rows still to come besides the block, so that
/// nothing the window admits from now on can reach the block. Not 0 if it
/// was not because its candidates so far fall short of the rule's cutoff,
/// by about that many (they do not reach it, and it has no ties outside
/// the buffer and is not strict: `Engine::take_missed_rows` can add what
/// it missed).
#[inline(never)]
fn prepare(
    window: &mut OpenWindow,
    config: &brightpix_protocol::Config<'_>,
    max_raw: u16,
    scratch: &mut [i32],
    rows_left: usize,
) -> usize {
    if level_rule(config.selection.rule) {
        return prepare_level_rule(window, config, max_raw, scratch, rows_left);
    }
    let room = rows_left * window.width as usize + BLOCK_END;
    if window.capacity == 0 || window.n >= MOST_N || window.rescan || window.low_ties.count != 0 {
        return 0;
    }
    let threshold = config.selection.rule == SelectionRule::Threshold;
    // Raised: `subtract-next`'s windows are then strict, `threshold`'s
    // have no back tier.
    let raised = window.strict || (threshold && window.back() == 0);
    let lowered = if raised {
        None
    } else {
        match lower_hint_to_cutoff(window, scratch, room, threshold) {
            Some(u) => Some(u),
            None => return falls_short(window, threshold),
        }
    };
    // Raised, `subtract-next`'s windows are also strict (`attention`
    // never); `threshold`'s must have no hint ties (copies of the hint
    // outside the buffer, which weigh when `v(N)` is the hint) and a front
    // short enough for the packed coordinate sums of its pixels at or
    // above `v(N)`, which ties may make more than N.
    if lowered.is_none()
        && (window.back() != 0
            || window.room_left() < room
            || if threshold {
                window.hint_ties.count != 0 || window.front() >= MOST_N as usize
            } else {
                window.attention != usize::MAX
            })
    {
        return 0;
    }
    settle_at_hint(window);
    let front = window.front();
    let capacity = window.capacity as usize;
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    let u = match lowered {
        Some(u) => u,
        None => match cut_so_far(window, config.selection.rule, entries, scratch) {
            Ok(cut) if cut.cutoff >= window.hint => cut.cutoff,
            _ => return 0,
        },
    };
    // The pixels that can still be kept are those above `t`, and the
    // window admits only those from now on: for `subtract-next` those
    // above `u` (the final `v(N+1)` is at least `u`, and ties with it
    // weigh nothing), for `threshold` those at or above `u` (the final
    // `v(N)` is at least `u`, and ties with it are kept).
    let t = if threshold { u.checked_sub(1) } else { Some(u) };
    let Some(t) = t.filter(|&t| t < i32::MAX) else {
        return 0;
    };
    write_block(entries, capacity, t, front);
    window.attention = PREPARED;
    admit_at(window, config, max_raw, t + 1);
    0
}

/// How many fewer candidates than the cutoff's rank a `subtract-next` or
/// `threshold` window that [`lower_hint_to_cutoff`] left alone holds, if
/// it would lower its hint with them (no ties outside the buffer, not
/// strict, N up to [`MOST_LOWERED_N`]); else 0.
fn falls_short(window: &OpenWindow, threshold: bool) -> usize {
    let (n, held) = (window.n as usize, window.front() + window.back());
    let rank = if threshold { n } else { n + 1 };
    if window.hint_ties.count != 0 || window.strict || n > MOST_LOWERED_N {
        return 0;
    }
    rank.saturating_sub(held)
}

/// `rule`'s cut of `window`'s candidates so far (its buffer `entries`,
/// its hint's copies counted), which holds for the whole window only if
/// `Ok`.
#[inline(always)]
fn cut_so_far(
    window: &OpenWindow,
    rule: SelectionRule,
    entries: &[Entry],
    scratch: &mut [i32],
) -> Result<Cut, TooShallow> {
    let (front, back, capacity) = (window.front(), window.back(), window.capacity as usize);
    let rule = WindowRule {
        rule,
        n: window.n,
        pixels: window.pixels(),
    };
    let mut tiers = Tiers {
        front: &entries[..front],
        front_at_hint: window.at_hint,
        hint: window.hint,
        hint_ties: window.hint_ties.count,
        back: &entries[capacity - back..capacity],
        low: window.low,
        low_ties: window.low_ties.count,
        complete: false,
        scratch,
    };
    select::cut(&rule, &mut tiers)
}

/// The block near the end of a window's buffer of `capacity` entries:
/// `t`, the front's length (`front`) and the sums of its pixels above `t`.
#[inline(always)]
fn write_block(entries: &mut [Entry], capacity: usize, t: i32, front: usize) {
    let above = centroid::sums_above(&entries[..front], t);
    let block = &mut entries[capacity - BLOCK_END..capacity - 1];
    block[0] = Entry {
        value: t,
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
}

/// [`prepare`] for `subtract-next-distinct` (DARC's subtract mode: `p >=
/// v(N)` kept, weighing `p - b`, `b` the largest value below `v(N)`) and
/// `subtract-mean` (the floored mean of the M largest below `v(N)`):
/// `u = v(N)`, the level and `w`, the smallest of the values below `u`
/// that set it (`b` itself, or the M-th largest), of the candidates so
/// far, if `w` is at or above the hint (so the back tier, below it, can
/// go, as `raise_to_hint` would drop it), else with the hint lowered to
/// `w` ([`lower_hint_to`]); with no hint or low ties. The final `v(N)` is
/// at least `u`, and values at or below `w` can no longer change the
/// level, so from then on the window admits `p > w`; the block holds the
/// sums of the front's pixels at or above `u`, and the entry before it the
/// level and `w`.
#[inline(always)]
fn prepare_level_rule(
    window: &mut OpenWindow,
    config: &brightpix_protocol::Config<'_>,
    max_raw: u16,
    scratch: &mut [i32],
    rows_left: usize,
) -> usize {
    let room = rows_left * window.width as usize + BLOCK_END + LEVEL;
    if window.capacity == 0
        || window.n >= MOST_N
        || window.rescan
        || window.low_ties.count != 0
        || (window.hint_ties.count != 0
            && config.selection.rule != SelectionRule::SubtractNextDistinct)
        || window.front() >= MOST_N as usize
        || window.room_left() < room
    {
        return 0;
    }
    settle_at_hint(window);
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    // Of these rules, a cut with the candidates incomplete is `Ok` only
    // with all the values that set its level (its `cutoff` the smallest).
    let (u, level, w) = match cut_so_far(window, config.selection.rule, entries, scratch) {
        Ok(Cut {
            bound: u,
            level: Some(level),
            cutoff: w,
            ..
        }) => (u, level, w),
        // Short (by what, the count does not say: the level may need a
        // value below `v(N)` however many are held, so N); the ties
        // outside the buffer keep a lowering out.
        Err(TooShallow) if window.hint_ties.count == 0 && !window.strict => {
            return window.n as usize;
        }
        _ => return 0,
    };
    if w < window.hint {
        // The cutoff fell below the hint (the spot dimmed or moved, a
        // fifth of CANARY's distinct windows): the hint lowered to `w`,
        // the back's entries at or above it moved to the front, the rest
        // dropped (nothing at or below `w` can change the level), and the
        // window is prepared as one whose hint was `w` all along. Not with
        // hint ties (copies of the old hint outside the buffer).
        if window.hint_ties.count != 0
            || window.strict
            || lower_hint_to(window, w, room, MOST_N as usize).is_none()
        {
            return 0;
        }
    } else if window.hint_ties.count != 0 && u <= window.hint {
        // `subtract-next-distinct`'s hint ties (the copy of its lowered
        // hint, `admission::raise_below_front`, or a compaction's cut
        // at the level) lie below `u`, its `v(N)`, which is above the
        // hint then; checked, since the block sums front pixels only and
        // ties at `u` would weigh.
        return 0;
    }
    let front = window.front();
    let capacity = window.capacity as usize;
    // SAFETY: as above; the lowering's borrow ended.
    let entries = unsafe { window.entries() };
    // `u > w`, so `u - 1` does not overflow, nor `w + 1`.
    write_block(entries, capacity, u - 1, front);
    entries[capacity - BLOCK_END - LEVEL] = Entry {
        value: level,
        position: w as u32,
    };
    window.set_back(0);
    window.low = window.hint;
    window.strict = true;
    window.attention = PREPARED;
    admit_at(window, config, max_raw, w + 1);
    0
}

/// A window whose front falls short of N + 1 (the spot dimmed or moved
/// since its hint was set, so `v(N+1)` lies in the back tier): its hint
/// lowered to `u`, the `v(N+1)` of its candidates so far (the
/// `(N + 1 - F)`-th largest of the back), and raised to it as
/// `raise_to_hint` raises a window to its hint. The back's entries at or
/// above `u` move to the front's end; the rest go, since the final
/// `v(N+1)` is at least `u`; admission becomes strict. For `threshold`
/// (`threshold` true) the same with `v(N)` and N, and admission not
/// strict (fewer than N are above `u`, which may stay `v(N)`), and
/// `None` too if the front would be too long for the prepared sums
/// ([`MOST_N`]). The window is then
/// one whose hint was `u` all along (its front every pixel at or above
/// it), which [`prepare`] takes like any other, and which still ends the
/// ordinary way if anything attends to it later. Returns `u`, with the
/// window's admission and attention left for the caller to set; `None`,
/// and the window unchanged, if it has hint ties (they come only with the
/// back emptied) or low ties (pixels equal to `low` outside the buffer,
/// which `u` may equal), if N is above [`MOST_LOWERED_N`], if its front
/// already reaches N + 1 or its back is too short, or if fewer than
/// `room` entries would be left free.
fn lower_hint_to_cutoff(
    window: &mut OpenWindow,
    scratch: &mut [i32],
    room: usize,
    threshold: bool,
) -> Option<i32> {
    let (front, back, n) = (window.front(), window.back(), window.n as usize);
    // The rank of the cutoff: `v(N+1)`, or `threshold`'s `v(N)`.
    let rank = if threshold { n } else { n + 1 };
    if window.hint_ties.count != 0
        || window.low_ties.count != 0
        || n > MOST_LOWERED_N
        || front >= rank
        || rank - front > back
    {
        return None;
    }
    let capacity = window.capacity as usize;
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    let u = select::kth_largest(&entries[capacity - back..], rank - front, scratch);
    let longest = if threshold {
        MOST_N as usize
    } else {
        usize::MAX
    };
    lower_hint_to(window, u, room, longest)?;
    // As after `raise_to_hint`: strict for `subtract-next`; for
    // `threshold` not, since fewer than N are above `u`. Admission and
    // attention are the caller's to set.
    window.strict = !threshold;
    Some(u)
}

/// The hint lowered to `u`, a value at or above `low` that the back tier
/// may hold: the back's entries at or above `u` move to the front's end,
/// the rest go, so that the front holds every pixel at or above `u` and the
/// window is one whose hint was `u` all along. `None`, and the window
/// unchanged, if fewer than `room` entries would be left free or the
/// front would reach `longest` entries. For a window without hint or low
/// ties (copies of the old hint or of `low` outside the buffer); its
/// strictness, admission and attention are the caller's to set.
fn lower_hint_to(window: &mut OpenWindow, u: i32, room: usize, longest: usize) -> Option<()> {
    let (front, back) = (window.front(), window.back());
    let capacity = window.capacity as usize;
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    let back_start = capacity - back;
    // The copies below land in the free space, never on a back entry not
    // yet read: at once if the whole back fits there, else after counting
    // them. Until the front is set they are scratch, so a window left with
    // too little room is left unchanged.
    let free = back_start - front;
    if free < back {
        let moved = entries[back_start..]
            .iter()
            .filter(|e| e.value >= u)
            .count();
        if free < moved {
            return None;
        }
    }
    let (mut to, mut at_u) = (front, 0);
    for from in back_start..capacity {
        let e = entries[from];
        if e.value >= u {
            entries[to] = e;
            to += 1;
            at_u += (e.value == u) as u16;
        }
    }
    if capacity - to < room || to >= longest {
        return None;
    }
    window.set_front(to);
    window.set_back(0);
    window.hint = u;
    window.low = u;
    // The old front's entries are above the old hint, so above `u`.
    window.at_hint = at_u;
    window.counted = to as u16;
    window.raise = Raise::NONE;
    Some(())
}

impl Engine<'_, '_> {
    /// The end of window `k`, prepared for the last row. Out of line, so that the
    /// ordinary end's code is what it was without preparation (inlined,
    /// this end moved the Cortex-M7's code for every rule: threshold 17.40
    /// -> 17.83 instructions a pixel).
    #[inline(never)]
    pub(super) fn finish_prepared(&mut self, k: usize, sink: &mut impl OutputSink) {
        if self.config.selection.rule != SelectionRule::SubtractNext {
            return self.finish_prepared_other(k, sink);
        }
        if self.filtered_closed_form {
            return self.finish_prepared_filtered(k, sink);
        }
        let window = &self.memory.open[k];
        // SAFETY: the window's buffer (opened with it), no other reference
        // to it alive.
        let entries: &[Entry] = unsafe { window.entries() };
        let (v, moments) = prepared_end::<false>(window, entries, self.memory.scratch, |v| v);
        self.emit(k, v, moments, sink);
    }

    /// [`finish_prepared`](Self::finish_prepared) with a level filter
    /// (`subtract-next` and the level rules): the filter's state updated
    /// from this frame's level, the moments at its level; for the level
    /// rules, the ordinary end if that level is not below `v(N)`
    /// ([`filtered_below`]) or the last row moved `v(N)` above `u`. Out of
    /// line, as the next.
    #[inline(never)]
    fn finish_prepared_filtered(&mut self, k: usize, sink: &mut impl OutputSink) {
        let memory = &mut self.memory;
        let window = &memory.open[k];
        // SAFETY: the window's buffer (opened with it), no other reference
        // to it alive.
        let entries: &[Entry] = unsafe { window.entries() };
        let gain_shift = self.gain_shift;
        let state = &mut memory.subapertures[window.index as usize].level;
        let end = match self.config.selection.rule {
            SelectionRule::SubtractNext => {
                Some(prepared_end::<true>(window, entries, memory.scratch, |v| {
                    state.filter(v, gain_shift)
                }))
            }
            rule => prepared_level_end(
                window,
                entries,
                rule == SelectionRule::SubtractNextDistinct,
                |l, cutoff| filtered_below(state, l, gain_shift, cutoff),
            ),
        };
        match end {
            Some((v, moments)) => self.emit(k, v, moments, sink),
            None => self.finish_ordinary(k, sink),
        }
    }

    /// [`finish_prepared`](Self::finish_prepared) for `threshold`,
    /// `subtract-next-distinct` and `subtract-mean` without a level
    /// filter, or the ordinary end
    /// when the last row moved `v(N)` above `u` ([`prepared_threshold_end`],
    /// [`prepared_level_end`]). Out of line, so that `subtract-next`'s
    /// end stays as it was.
    #[inline(never)]
    fn finish_prepared_other(&mut self, k: usize, sink: &mut impl OutputSink) {
        let window = &self.memory.open[k];
        // SAFETY: the window's buffer (opened with it), no other reference
        // to it alive.
        let entries: &[Entry] = unsafe { window.entries() };
        let end = match self.config.selection.rule {
            SelectionRule::Threshold => prepared_threshold_end(window, entries),
            _ if self.filtered_closed_form => return self.finish_prepared_filtered(k, sink),
            rule => prepared_level_end(
                window,
                entries,
                rule == SelectionRule::SubtractNextDistinct,
                |l, _| Some(l),
            ),
        };
        match end {
            Some((v, moments)) => self.emit(k, v, moments, sink),
            None => self.finish_ordinary(k, sink),
        }
    }
}

/// A prepared window's block: `t`, the front's length at preparation and
/// the sums of its pixels above `t`.
#[inline(always)]
fn prepared_block(window: &OpenWindow, entries: &[Entry]) -> (i32, usize, SumsAbove) {
    let capacity = window.capacity as usize;
    let block = &entries[capacity - BLOCK_END..capacity - 1];
    let sum = |e: Entry| (e.value as u32 as i64) | ((e.position as i64) << 32);
    let sums = SumsAbove {
        sum_p: sum(block[2]),
        sum_pi: sum(block[3]),
        sum_pj: sum(block[4]),
        count: block[1].value as u32,
        sum_ij: block[1].position,
    };
    (block[0].value, block[0].position as usize, sums)
}

/// A prepared `subtract-next` window's `v(N+1)` and moments (see the
/// module documentation), at the level `level` gives from `v(N+1)`.
#[inline(always)]
fn prepared_end<const FILTERED: bool>(
    window: &OpenWindow,
    entries: &[Entry],
    scratch: &mut [i32],
    level: impl FnOnce(i32) -> i32,
) -> (i32, Moments) {
    let (u, prepared_front, sums) = prepared_block(window, entries);
    let before = &entries[..prepared_front];
    let last = &entries[prepared_front..window.front()];
    cutoff_and_moments::<FILTERED>(u, &sums, before, last, window.n as usize, scratch, level)
}

/// For a window prepared with `u = v(N)` (`threshold`,
/// `subtract-next-distinct`, `subtract-mean`): `u`, the last row's
/// entries and the block's
/// sums if `v(N)` is still `u`, i.e. the last row's pixels above `u` do
/// not make N (fewer than N were above it at preparation; counted only
/// when the last row brought some). `None` if they do: the window then
/// ends the ordinary way, on its candidates (all still in place).
#[inline(always)]
fn cutoff_stays<'e>(
    window: &OpenWindow,
    entries: &'e [Entry],
) -> Option<(i32, &'e [Entry], SumsAbove)> {
    let (t, prepared_front, sums) = prepared_block(window, entries);
    let last = &entries[prepared_front..window.front()];
    let u = t + 1;
    let above = |entries: &[Entry]| entries.iter().filter(|e| e.value > u).count();
    let last_above = above(last);
    if last_above > 0 && above(&entries[..prepared_front]) + last_above >= window.n as usize {
        return None;
    }
    Some((u, last, sums))
}

/// A prepared `threshold` window's `v(N)` and moments, when `v(N)` is
/// still `u` ([`cutoff_stays`]): every pixel at or above `u` is kept,
/// weighing `p`: the sums, and every pixel of the last row's (all at or
/// above `u`).
#[inline(always)]
fn prepared_threshold_end(window: &OpenWindow, entries: &[Entry]) -> Option<(i32, Moments)> {
    let (u, last, sums) = cutoff_stays(window, entries)?;
    let mut moments = sums.moments(0);
    for e in last {
        weigh(&mut moments, e, 0, 1);
    }
    Some((u, moments))
}

/// A prepared `subtract-next-distinct` or `subtract-mean` window's
/// cutoff for the seed and moments, when `v(N)` is still `u`
/// ([`cutoff_stays`]) and the level is known: the last row's values
/// between `w` and `u` are the only ones that can change it. For
/// distinct the largest of them is the level if above it; for mean any
/// of them sends the window to the ordinary end (`None`). The sums and
/// the last row's pixels at or above `u` weigh at the level to subtract,
/// which `level_to_subtract` gives from that level and `u` (as
/// `closed_form::level_rule_end`'s `level`; `None`: the ordinary end).
#[inline(always)]
fn prepared_level_end(
    window: &OpenWindow,
    entries: &[Entry],
    distinct: bool,
    level_to_subtract: impl FnOnce(i32, i32) -> Option<i32>,
) -> Option<(i32, Moments)> {
    let (u, last, sums) = cutoff_stays(window, entries)?;
    let kept = entries[window.capacity as usize - BLOCK_END - LEVEL];
    let (mut level, w) = (kept.value, kept.position as i32);
    let mut cutoff = w;
    for e in last.iter().filter(|e| e.value > w && e.value < u) {
        if !distinct {
            return None;
        }
        level = level.max(e.value);
        cutoff = level;
    }
    let level = level_to_subtract(level, u)?;
    let mut moments = sums.moments(level);
    for e in last.iter().filter(|e| e.value >= u) {
        weigh(&mut moments, e, level as i64, 1);
    }
    Some((cutoff, moments))
}
