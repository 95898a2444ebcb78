//! A window's candidate buffer as the engine keeps it, and its compaction
//! when full.

use super::{cut, Entry, Tiers, Ties, WindowRule};

/// A window's candidate buffer and tie buckets, as the engine keeps them.
pub struct Buffer<'a> {
    /// The whole buffer: front at `[..front]`, back at `[len - back..]`.
    pub entries: &'a mut [Entry],
    pub front: usize,
    /// Front entries equal to the hint.
    pub at_hint: u16,
    pub back: usize,
    pub hint: i32,
    pub hint_ties: Ties,
    pub low: i32,
    pub low_ties: Ties,
    /// Admission is `p > low` (the hint), not `p >= low`: see
    /// [`Tiers::hint_ties_settled`].
    pub strict: bool,
}

impl Buffer<'_> {
    /// Drops the back tier and low ties and raises `low` to the hint, when
    /// [`Tiers::covers_hint`] allows it.
    #[inline(always)]
    pub fn drop_back(&mut self) {
        self.back = 0;
        self.low = self.hint;
        self.low_ties = Ties::NONE;
    }

    /// [`Tiers::covers_hint`]: whether nothing below the hint matters.
    #[inline(always)]
    pub fn covers_hint(&self, rule: &WindowRule) -> bool {
        Tiers::covers_hint(
            rule.rule,
            rule.n,
            self.front as u16 - self.at_hint,
            self.hint_ties.count + self.at_hint,
        )
    }

    /// A full buffer: raises `low` to the cutoff of the candidates so far,
    /// dropping what falls below it. Returns `false` if nothing can be
    /// dropped (the window then needs a rescan). `scratch` holds at least
    /// the buffer's length.
    pub fn compact(&mut self, rule: &WindowRule, scratch: &mut [i32]) -> bool {
        let capacity = self.entries.len();
        let (front, back) = (self.front, self.back);
        let mut tiers = Tiers {
            front: &self.entries[..front],
            front_at_hint: self.at_hint,
            hint: self.hint,
            hint_ties: self.hint_ties.count,
            back: &self.entries[capacity - back..],
            low: self.low,
            low_ties: self.low_ties.count,
            complete: false,
            scratch,
        };
        let cutoff = match cut(rule, &mut tiers) {
            Ok(cut) if cut.cutoff > self.low => cut.cutoff,
            _ => return false,
        };
        if cutoff >= self.hint {
            // Everything at or below the hint but the cutoff's copies goes.
            let mut ties = if cutoff == self.hint {
                self.hint_ties
            } else {
                Ties::NONE
            };
            let mut kept = 0;
            for k in 0..front {
                let e = self.entries[k];
                if e.value > cutoff {
                    self.entries[kept] = e;
                    kept += 1;
                } else if e.value == cutoff {
                    ties.add(e.position as u16);
                }
            }
            self.front = kept;
            self.at_hint = 0;
            self.back = 0;
            self.strict = false;
            self.hint = cutoff;
            self.hint_ties = ties;
            self.low = cutoff;
            self.low_ties = Ties::NONE;
        } else {
            // The cutoff is in the back tier: only the back changes. Read
            // from its top down, so writes never pass the reads.
            let mut ties = Ties::NONE;
            let mut kept = 0;
            for k in (capacity - back..capacity).rev() {
                let e = self.entries[k];
                if e.value > cutoff {
                    self.entries[capacity - 1 - kept] = e;
                    kept += 1;
                } else if e.value == cutoff {
                    ties.add(e.position as u16);
                }
            }
            self.back = kept;
            self.low = cutoff;
            self.low_ties = ties;
        }
        true
    }
}
