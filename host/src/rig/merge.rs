//! The boards' results, one whole-camera frame at a time.
//!
//! Results are aligned by frame number, never by arrival: a frame is put
//! together from each board's outcome for that number, and only once every
//! board has given one (or has gone). A board that dropped the frame, sent
//! part of it or is gone leaves its sub-apertures without a result for that
//! frame (invalid), counted per board; nothing from two frame numbers is
//! ever put into one frame.

use std::collections::BTreeMap;

use brightpix_protocol::wire::SlopeEntry;

use crate::link::{FrameOutcome, FrameSlopes};

/// One whole-camera frame put together from the boards.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MergedFrame {
    pub frame: u32,
    /// Per whole-camera sub-aperture: its board's result, or `None` where
    /// the board gave none for this frame.
    pub results: Vec<Option<SlopeEntry>>,
    /// Boards that gave no complete result for this frame.
    pub missing_boards: Vec<usize>,
    /// Per board, its `EdgeRows` for this frame (first, last row
    /// checksums), if it sent them.
    pub edge_rows: Vec<Option<(u32, u32)>>,
    /// Two boards that share a camera row sent different checksums of it
    /// for this frame: their parts are of different camera frames
    /// (`RigStream` sets it).
    pub edges_disagree: bool,
}

impl MergedFrame {
    /// As a device's complete frame (whole-camera indices), when every
    /// board delivered; `None` otherwise.
    pub fn as_outcome(&self) -> Option<FrameOutcome> {
        if !self.missing_boards.is_empty() {
            return None;
        }
        let slopes: Vec<SlopeEntry> = self.results.iter().flatten().copied().collect();
        Some(FrameOutcome::Done(FrameSlopes {
            frame: self.frame,
            done_count: Some(slopes.len() as u32),
            slopes,
            edge_rows: None,
        }))
    }
}

/// Per board: what it gave.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BoardCounts {
    pub frames_done: u64,
    /// Frames the board dropped or left incomplete.
    pub frames_dropped: u64,
    /// Frames merged after the board had gone.
    pub frames_missing: u64,
    /// Outcomes for frame numbers not awaited (stale or already merged).
    pub stray_outcomes: u64,
}

/// Puts frames together from `boards` boards' outcomes.
pub struct Merger {
    /// Per board, whole-camera index of each of its sub-apertures.
    local_to_whole: Vec<Vec<usize>>,
    subapertures: usize,
    /// Frames awaited, in number order, with what each board gave.
    pending: BTreeMap<u32, Vec<Option<FrameOutcome>>>,
    gone: Vec<bool>,
    pub counts: Vec<BoardCounts>,
}

impl Merger {
    /// `local_to_whole[b][k]`: the whole-camera index of board `b`'s
    /// sub-aperture `k`.
    pub fn new(local_to_whole: Vec<Vec<usize>>, subapertures: usize) -> Self {
        let boards = local_to_whole.len();
        Merger {
            local_to_whole,
            subapertures,
            pending: BTreeMap::new(),
            gone: vec![false; boards],
            counts: vec![BoardCounts::default(); boards],
        }
    }

    /// Frame `frame` was sent to every board: its outcomes are awaited.
    pub fn expect(&mut self, frame: u32) {
        let boards = self.gone.len();
        self.pending
            .entry(frame)
            .or_insert_with(|| vec![None; boards]);
    }

    /// Board `board`'s outcome; returns the frames now complete, in order.
    pub fn add(&mut self, board: usize, outcome: FrameOutcome) -> Vec<MergedFrame> {
        match self.pending.get_mut(&outcome.frame()) {
            Some(parts) if parts[board].is_none() => parts[board] = Some(outcome),
            _ => self.counts[board].stray_outcomes += 1,
        }
        self.ready()
    }

    /// Board `board` will give nothing more: frames wait for it no longer.
    pub fn board_gone(&mut self, board: usize) -> Vec<MergedFrame> {
        self.gone[board] = true;
        self.ready()
    }

    /// Every frame still awaited, put together with what arrived (the rest
    /// missing): at the end of a run.
    pub fn finish(&mut self) -> Vec<MergedFrame> {
        self.gone.iter_mut().for_each(|g| *g = true);
        self.ready()
    }

    /// The awaited frames, from the lowest number up, for as long as each
    /// has every board's outcome or the board is gone.
    fn ready(&mut self) -> Vec<MergedFrame> {
        let mut out = Vec::new();
        while let Some(entry) = self.pending.first_entry() {
            let complete = entry
                .get()
                .iter()
                .zip(&self.gone)
                .all(|(part, gone)| part.is_some() || *gone);
            if !complete {
                break;
            }
            let (frame, parts) = entry.remove_entry();
            out.push(self.merge(frame, parts));
        }
        out
    }

    fn merge(&mut self, frame: u32, parts: Vec<Option<FrameOutcome>>) -> MergedFrame {
        let mut results = vec![None; self.subapertures];
        let mut missing_boards = Vec::new();
        let edge_rows = parts
            .iter()
            .map(|p| p.as_ref().and_then(|o| o.slopes().edge_rows))
            .collect();
        for (board, part) in parts.into_iter().enumerate() {
            let map = &self.local_to_whole[board];
            match part {
                Some(FrameOutcome::Done(slopes)) if slopes.done_count == Some(map.len() as u32) => {
                    self.counts[board].frames_done += 1;
                    for (local, entry) in slopes.by_index(map.len()).into_iter().enumerate() {
                        results[map[local]] = entry.map(|e| SlopeEntry {
                            index: map[local] as u16,
                            ..e
                        });
                    }
                }
                Some(_) => {
                    self.counts[board].frames_dropped += 1;
                    missing_boards.push(board);
                }
                None => {
                    self.counts[board].frames_missing += 1;
                    missing_boards.push(board);
                }
            }
        }
        MergedFrame {
            frame,
            results,
            missing_boards,
            edge_rows,
            edges_disagree: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(index: u16, value: i32) -> SlopeEntry {
        SlopeEntry {
            index,
            slope_x: value,
            slope_y: -value,
            flux: value as i64,
            valid: true,
        }
    }

    /// Board `board`'s complete outcome for `frame`: slope values
    /// `frame * 100 + whole index`, so a mixed-up frame shows.
    fn done(map: &[usize], frame: u32) -> FrameOutcome {
        FrameOutcome::Done(FrameSlopes {
            frame,
            slopes: map
                .iter()
                .enumerate()
                .map(|(local, &whole)| entry(local as u16, (frame * 100) as i32 + whole as i32))
                .collect(),
            done_count: Some(map.len() as u32),
            edge_rows: None,
        })
    }

    fn maps() -> Vec<Vec<usize>> {
        vec![vec![0, 1, 2], vec![3, 4], vec![5]]
    }

    /// Outcomes arrive out of step across boards (board 0 all frames
    /// ahead, board 2 last and out of order); every merged frame holds one
    /// frame's results.
    #[test]
    fn aligned_by_frame_number_not_arrival() {
        let mut m = Merger::new(maps(), 6);
        (10..14).for_each(|f| m.expect(f));
        let mut merged = Vec::new();
        for f in 10..14 {
            merged.extend(m.add(0, done(&maps()[0], f)));
        }
        assert!(merged.is_empty());
        for f in 10..14 {
            merged.extend(m.add(1, done(&maps()[1], f)));
        }
        // Board 2's outcomes out of order: each still joins its own frame.
        for f in [11, 10, 13, 12] {
            merged.extend(m.add(2, done(&maps()[2], f)));
        }
        assert_eq!(merged.len(), 4);
        for (k, mf) in merged.iter().enumerate() {
            assert_eq!(mf.frame, 10 + k as u32);
            for (whole, r) in mf.results.iter().enumerate() {
                let r = r.unwrap();
                assert_eq!(r.index as usize, whole);
                assert_eq!(r.slope_x, (mf.frame * 100) as i32 + whole as i32);
            }
            assert!(mf.as_outcome().is_some());
        }
    }

    /// A board that dropped a frame, one that skipped it (its next frame's
    /// outcome arrives instead) and one that disappears.
    #[test]
    fn faults_leave_that_boards_subapertures_invalid() {
        let maps = maps();
        let mut m = Merger::new(maps.clone(), 6);
        (0..3).for_each(|f| m.expect(f));
        let mut merged = Vec::new();
        merged.extend(m.add(0, done(&maps[0], 0)));
        merged.extend(m.add(1, done(&maps[1], 0)));
        merged.extend(m.add(
            2,
            FrameOutcome::Incomplete(FrameSlopes {
                frame: 0,
                ..Default::default()
            }),
        ));
        assert_eq!(merged.len(), 1);
        assert_eq!(merged[0].missing_boards, [2]);
        assert!(merged[0].results[5].is_none() && merged[0].results[4].is_some());
        // Frame 1: board 1 gives frame 2's outcome first; frame 1 waits.
        merged.extend(m.add(1, done(&maps[1], 2)));
        merged.extend(m.add(0, done(&maps[0], 1)));
        merged.extend(m.add(2, done(&maps[2], 1)));
        assert_eq!(merged.len(), 1, "frame 1 must wait for board 1's frame 1");
        merged.extend(m.add(1, done(&maps[1], 1)));
        assert_eq!(merged.len(), 2);
        assert_eq!(merged[1].results[3].unwrap().slope_x, 103);
        // Board 2 disappears: frame 2 is merged without it.
        merged.extend(m.add(0, done(&maps[0], 2)));
        assert_eq!(merged.len(), 2);
        merged.extend(m.board_gone(2));
        assert_eq!(merged.len(), 3);
        assert_eq!(merged[2].missing_boards, [2]);
        assert_eq!(merged[2].results[3].unwrap().slope_x, 203);
        assert_eq!(m.counts[2].frames_dropped, 1);
        assert_eq!(m.counts[2].frames_missing, 1);
        assert_eq!(m.counts[0].frames_done, 3);
        // An outcome for a frame no longer awaited is stray, not merged.
        assert!(m.add(0, done(&maps[0], 1)).is_empty());
        assert_eq!(m.counts[0].stray_outcomes, 1);
    }

    /// A capture by a board slower than the camera: it skips the camera's
    /// frame 1 (its outcomes are 0, 2, 3, 4: frame 4 was never awaited) and
    /// its capture ends. Frame 1 waits for it until then, and is merged
    /// with its sub-aperture missing and counted; frame 4 is stray.
    #[test]
    fn frames_a_slow_board_skipped_are_missing_once_its_capture_ends() {
        let maps = maps();
        let mut m = Merger::new(maps.clone(), 6);
        (0..4).for_each(|f| m.expect(f));
        let mut merged = Vec::new();
        for f in 0..4 {
            merged.extend(m.add(0, done(&maps[0], f)));
            merged.extend(m.add(1, done(&maps[1], f)));
        }
        for f in [0, 2, 3, 4] {
            merged.extend(m.add(2, done(&maps[2], f)));
        }
        assert_eq!(merged.len(), 1, "frame 1 waits for the slow board");
        merged.extend(m.board_gone(2));
        assert_eq!(
            merged.iter().map(|f| f.frame).collect::<Vec<_>>(),
            [0, 1, 2, 3]
        );
        assert_eq!(merged[1].missing_boards, [2]);
        assert!(merged[1].results[5].is_none());
        assert_eq!(merged[2].results[5].unwrap().slope_x, 205);
        assert_eq!(m.counts[2].frames_missing, 1);
        assert_eq!(m.counts[2].frames_done, 3);
        assert_eq!(m.counts[2].stray_outcomes, 1);
    }
}
