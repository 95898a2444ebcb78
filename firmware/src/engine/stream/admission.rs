//! What an open window admits as it fills: the admission threshold and its
//! raw pre-filter floor, when the row kernel must stop at the window
//! (`attention`), raising admission to the hint once the front proves the
//! cutoff at or above it, and making room in a full candidate buffer.

use super::Engine;
use crate::engine::calibrate::{raw_floor, raw_floor_plain, WindowBounds};
use crate::engine::select::{Buffer, Entry, Tiers, Ties, WindowRule};
use crate::engine::window::{OpenWindow, Raise};
use brightpix_protocol::{Config, SelectionRule};

impl Engine<'_, '_> {
    /// The row kernel stopped at window `k`: its candidates may now prove
    /// the cutoff is at or above the hint (the back tier then goes, and
    /// admission rises), or it is short of room for the next segment (it
    /// then takes the general path, which compacts it when full).
    #[inline(never)]
    pub(super) fn attend(&mut self, k: usize) {
        self.stats.attentions = self.stats.attentions.wrapping_add(1);
        let window = &mut self.memory.open[k];
        raise_to_hint(window, &self.config, self.max_raw);
        window.attention = attention(window, self.config.selection.rule);
        self.refresh_ready(k);
    }

    /// Whether window `k` is `kernel_ready` may have changed: its kernel
    /// segment and the count of windows the kernel skips, updated.
    #[inline(always)]
    pub(super) fn refresh_ready(&mut self, k: usize) {
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
}

/// Counts the front entries equal to the hint that arrived since the last
/// count: `at_hint` is kept lazily, since only the tests of whether the front
/// covers the hint, compaction and the window's end need it.
#[inline(always)]
pub(super) fn settle_at_hint(window: &mut OpenWindow) {
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
/// rest of the window is filtered harder. `subtract-next-distinct` first
/// lowers its hint when that proves it sooner ([`raise_below_front`]).
#[inline(always)]
pub(super) fn raise_to_hint(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16) {
    if config.selection.rule == SelectionRule::SubtractNextDistinct
        && raise_below_front(window, config, max_raw)
    {
        return;
    }
    if !window.strict
        && window.front() + window.hint_ties.count as usize >= window.n as usize
        && covers(window, config)
    {
        let strict = Tiers::hint_ties_settled(
            config.selection.rule,
            window.n,
            window.front() as u16 - window.at_hint,
        );
        raise(window, config, max_raw, strict);
    }
}

/// The back tier dropped, `low` raised to the hint, and admission
/// `p > hint` if `strict`, else `p >= hint`.
#[inline(always)]
fn raise(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16, strict: bool) {
    window.set_back(0);
    window.low = window.hint;
    window.low_ties = Ties::NONE;
    window.strict = strict;
    update_admission(window, config, max_raw);
}

/// `subtract-next-distinct` keeps `p >= v(N)` and subtracts the level, the
/// largest value below `v(N)`. Its windows open with the hint one above
/// the previous level (`Engine::hint_above`), so that the front holds the
/// values above that level and not its copies (about 16 in a faint spot's
/// window), which the row kernel would otherwise count at its stops and
/// the window's end pass over. Once the front holds N pixels, `v(N)` is at
/// or above the hint, so the level is at least the largest value held
/// below the hint, `b`: the hint is lowered to `b`, where the front and a
/// copy of `b` prove the cutoff at or above it (`Tiers::covers_hint`: N
/// front values above it, one copy of it), so the back tier goes and
/// admission becomes `p > b` at once: the raise the previous level's hint
/// would have made once N values were above it, without counting its
/// copies. `false` (nothing changed) if the window is raised already, has
/// hint ties, a front short of N or an empty back tier.
///
/// The back tier goes at once, so `b` need not be its largest, only a value
/// it holds, and one copy of it will do (later copies of a raised window's
/// hint are not counted either, `Tiers::hint_ties_settled`): the previous
/// level, `hint - 1`, found at the first of its copies (a faint spot's
/// window holds ~16 of them among ~60 back entries), else the back's
/// largest. The row kernel does the first itself (`Raise::LOWER`, see
/// [`prepare_raise`]); the engine, after a stop, either.
#[inline(always)]
fn raise_below_front(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16) -> bool {
    if window.strict || window.hint_ties.count != 0 || window.front() < window.n as usize {
        return false;
    }
    let capacity = window.capacity as usize;
    // SAFETY: the window's live buffer, no other reference to it.
    let entries = unsafe { window.entries() };
    let back = &entries[capacity - window.back()..capacity];
    // `hint - 1` does not overflow: the hint is above the back's values.
    let level = window.hint.wrapping_sub(1);
    let Some(copy) = back
        .iter()
        .find(|e| e.value == level)
        .or_else(|| back.iter().max_by_key(|e| e.value))
    else {
        return false;
    };
    let (b, mut ties) = (copy.value, Ties::NONE);
    ties.add(copy.position as u16);
    window.hint = b;
    window.hint_ties = ties;
    // Every front entry is above `b`.
    window.at_hint = 0;
    window.counted = window.front() as u16;
    raise(window, config, max_raw, true);
    true
}

/// Where the row kernel next stops at a window for [`raise_to_hint`]: the
/// front's end at the fewest candidates with which the front and hint ties
/// could prove the cutoff at or above the hint (or, once they have, make
/// admission strict), and at least one more than it holds; never once
/// admission is strict.
#[inline(always)]
pub(super) fn attention(window: &OpenWindow, rule: SelectionRule) -> usize {
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
        // `subtract-next-distinct` without hint ties: N, where its hint is
        // lowered (`raise_below_front`; with nothing held below the
        // hint yet, each admission after, until something is).
        // Else, and for `subtract-mean`: n above the hint besides the
        // front's copies of it counted so far (`at_hint`, which only
        // grows), and copies of the hint: M for `subtract-mean`, one for
        // `subtract-next-distinct`. A bound: the copies that arrived since
        // the last count are counted when it is reached.
        SelectionRule::SubtractNextDistinct => {
            if ties == 0 {
                n
            } else {
                n + window.at_hint as usize + 1usize.saturating_sub(ties + window.at_hint as usize)
            }
        }
        SelectionRule::SubtractMean { count } => {
            n + window.at_hint as usize
                + (count as usize).saturating_sub(ties + window.at_hint as usize)
        }
    };
    window.buffer + fewest.max(front + 1) * core::mem::size_of::<Entry>()
}

/// [`update_admission`] and [`attention`] for a window just opened (not
/// strict, no ties, no back tier), with what depends on the rule alone
/// worked out once for all the windows one row opens: each opening costs
/// the two raw floors and a few stores, not the rules' matches.
#[derive(Clone, Copy)]
pub(super) struct FreshWindow {
    /// [`attention`] at `N` plus this many entries.
    beyond_n: usize,
    /// [`prepare_raise`]'s raise (`threshold`'s: when `low` is below the
    /// hint).
    raise: Raise,
}

impl FreshWindow {
    #[inline(always)]
    pub(super) fn of(rule: SelectionRule) -> FreshWindow {
        let (beyond_n, raise) = match rule {
            SelectionRule::SubtractNext => (1, Raise::ABOVE_HINT),
            SelectionRule::Threshold => (0, Raise::AT_HINT),
            // No hint ties yet: lowered to the previous level first.
            SelectionRule::SubtractNextDistinct => (0, Raise::LOWER),
            SelectionRule::SubtractMean { count } => {
                // M is 1..=16 (`Config::validate`).
                (count as usize, Raise::counting(count as u8))
            }
        };
        FreshWindow { beyond_n, raise }
    }

    /// Admission, the kernel's raise and attention for a window opened
    /// with a candidate buffer at `buffer` and the thresholds `low` and
    /// `hint`, as values, so that the opening writes each field once.
    /// `PLAIN`: the calibration has no gain map and no fixed threshold
    /// (`calibrate::raw_floor_plain`).
    #[inline(always)]
    pub(super) fn admission<const PLAIN: bool>(
        self,
        (low, hint): (i32, i32),
        bounds: WindowBounds,
        n: u16,
        buffer: usize,
        config: &Config<'_>,
        max_raw: u16,
    ) -> FreshAdmission {
        let floor = capped_floor::<PLAIN>(bounds, config, max_raw, low);
        let raise = if self.raise == Raise::AT_HINT && low == hint {
            Raise::NONE
        } else {
            self.raise
        };
        let (raise, raise_lane) =
            raise_and_lane::<PLAIN>(raise, true, hint, bounds, config, max_raw);
        FreshAdmission {
            admit: low,
            floor,
            lanes: lanes_of(floor),
            raise,
            raise_lane,
            attention: buffer + (n as usize + self.beyond_n).max(1) * size_of::<Entry>(),
        }
    }

    /// Debug builds: a window just opened with [`admission`](Self::admission)'s
    /// fields holds what the general functions give it.
    #[cfg(debug_assertions)]
    pub(super) fn check(window: &OpenWindow, config: &Config<'_>, max_raw: u16) {
        let mut general = *window;
        update_admission(&mut general, config, max_raw);
        general.attention = attention(&general, config.selection.rule);
        debug_assert!(
            (general.admit, general.floor, general.lanes, general.raise)
                == (window.admit, window.floor, window.lanes, window.raise)
                && (general.raise_lane, general.attention) == (window.raise_lane, window.attention)
        );
    }
}

/// What [`FreshWindow::admission`] gives a window's fields.
pub(super) struct FreshAdmission {
    pub(super) admit: i32,
    pub(super) floor: u32,
    pub(super) lanes: u32,
    pub(super) raise: Raise,
    pub(super) raise_lane: u16,
    pub(super) attention: usize,
}

impl FreshAdmission {
    /// A window without selection: every pixel to the general path (floor
    /// 0), no raise, no attention.
    pub(super) const NONE: FreshAdmission = FreshAdmission {
        admit: 0,
        floor: 0,
        lanes: 0,
        raise: Raise::NONE,
        raise_lane: 0,
        attention: usize::MAX,
    };
}

/// After `low`, `hint` or `strict` changed: the window's admission
/// threshold, and the pre-filter's raw floor for it, lowered so that a pixel
/// above `max_raw` always passes (see `OpenWindow::floor`), in both forms;
/// and what the row kernel needs to raise admission itself
/// ([`prepare_raise`]).
#[inline(always)]
pub(super) fn update_admission(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16) {
    admit_at(window, config, max_raw, window.admission());
    prepare_raise(window, config, max_raw);
}

/// The window admits `p >= admit` from now on: `admit` and the pre-filter's
/// raw floor for it, in both forms (see [`update_admission`]).
#[inline(always)]
pub(super) fn admit_at(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16, admit: i32) {
    window.admit = admit;
    let floor = capped_floor::<false>(window.bounds, config, max_raw, admit);
    window.floor = floor;
    window.lanes = lanes_of(floor);
}

/// The kernel's form of a raw floor: `floor - 1` in both 16-bit lanes.
#[inline(always)]
fn lanes_of(floor: u32) -> u32 {
    floor.wrapping_sub(1).wrapping_mul(0x0001_0001)
}

/// The raw floor of `threshold` in a window with `bounds`, capped so that a
/// pixel above `max_raw` always passes (see `OpenWindow::floor`); `PLAIN` as
/// in [`FreshWindow::admission`].
#[inline(always)]
fn capped_floor<const PLAIN: bool>(
    bounds: WindowBounds,
    config: &Config<'_>,
    max_raw: u16,
    threshold: i32,
) -> u32 {
    let most = max_raw as u32 + 1;
    if PLAIN {
        raw_floor_plain(bounds, threshold, most)
    } else {
        raw_floor(&config.calibration, bounds, threshold).min(most)
    }
}

/// When the front reaches `attention`, the row kernel raises admission to
/// the hint itself, without stopping, where the proof of the cutoff at or
/// above the hint ([`Tiers::covers_hint`]) is one it can make:
/// - `subtract-next` and `threshold`: reaching [`attention`] is the proof
///   (`front + hint ties > N`, `>= N`, whatever the front's copies of the
///   hint), so [`raise_to_hint`] would drop the back tier (so only while
///   there are no low ties, which a compaction may have made), set `low`
///   to the hint and admit `p > hint` (`subtract-next`: strict at once,
///   `Tiers::hint_ties_settled`) or `p >= hint` (`threshold`). The copies
///   of the hint in the front are then counted later, when something needs
///   them (`settle_at_hint`). A raised `threshold` window then stays
///   non-strict (the kernel sets no further attention): its later copies
///   of the hint are admitted, where the engine's stop once `N` front
///   values were above the hint made admission strict, which cost a stop
///   in every window to save a few admissions in some; so not for a window
///   already raised.
/// - `subtract-next-distinct` and `subtract-mean`: the proof needs N front
///   values above the hint and one copy of it (M for the mean), so the
///   kernel counts the front's copies that arrived since the last count
///   (`settle_at_hint`'s count) and raises to `p > hint` if they prove
///   it, else sets the next attention as [`attention`] would: what
///   `Engine::attend` did, without leaving the kernel.
/// - `subtract-next-distinct` without hint ties (its hint one above the
///   previous level): the kernel lowers the hint to `hint - 1` where the
///   back tier holds a copy of it and raises above it (`Raise::LOWER`:
///   [`raise_below_front`]'s usual case); else it stops, and
///   `Engine::attend` lowers the hint to the back's largest value.
///
/// Not for a raised floor of 0 (every pixel passes: the general path's).
#[inline(always)]
fn prepare_raise(window: &mut OpenWindow, config: &Config<'_>, max_raw: u16) {
    let raise = match config.selection.rule {
        SelectionRule::SubtractNext => Raise::ABOVE_HINT,
        SelectionRule::Threshold if window.low != window.hint || window.back() != 0 => {
            Raise::AT_HINT
        }
        SelectionRule::Threshold => Raise::NONE,
        SelectionRule::SubtractNextDistinct if window.hint_ties.count == 0 => Raise::LOWER,
        SelectionRule::SubtractNextDistinct => Raise::counting(1),
        // M is 1..=16 (`Config::validate`).
        SelectionRule::SubtractMean { count } => Raise::counting(count as u8),
    };
    // Only a window that is not strict, has no low ties and selects takes
    // a raise (a window just opened always does: `FreshWindow::admission`).
    let allowed = !window.strict && window.low_ties.count == 0 && window.capacity > 0;
    (window.raise, window.raise_lane) =
        raise_and_lane::<false>(raise, allowed, window.hint, window.bounds, config, max_raw);
}

/// [`prepare_raise`] once the raise is chosen: the raise and its lane, the
/// lane of its raw floor (see [`Raise::admits_hint`]), if the window can
/// take it (`allowed`), else no raise. A window just opened
/// ([`FreshWindow`]) can: not strict, no low ties, a candidate buffer (the
/// tests cost every opening ~17 instructions on Cortex-M4).
#[inline(always)]
fn raise_and_lane<const PLAIN: bool>(
    raise: Raise,
    allowed: bool,
    hint: i32,
    bounds: WindowBounds,
    config: &Config<'_>,
    max_raw: u16,
) -> (Raise, u16) {
    let strict = !raise.admits_hint();
    let mut floor = 0;
    // `hint + 1` must not overflow: the kernel adds without saturating.
    if raise != Raise::NONE && allowed && (!strict || hint < i32::MAX) {
        floor = capped_floor::<PLAIN>(bounds, config, max_raw, hint + strict as i32);
    }
    // A raised floor is at most 2^16 (the camera's largest raw value + 1),
    // so its lane `floor - 1` is a u16.
    let raise = if floor != 0 { raise } else { Raise::NONE };
    (raise, floor.wrapping_sub(1) as u16)
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
pub(super) fn make_room(window: &mut OpenWindow, config: &Config<'_>, scratch: &mut [i32]) -> bool {
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
pub(super) fn place(window: &mut OpenWindow, entry: Entry) {
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
