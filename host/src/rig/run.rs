//! One camera, K devices, one result: each board configured with its part
//! (and its digest checked before any frame), each fed its rectangle of
//! every frame on a thread of its own, their outcomes merged by frame
//! number ([`Merger`]) and, with verification, every merged frame checked
//! bit for bit against the whole-camera reference.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use brightpix_protocol::wire::tables::config_digest;

use brightpix_protocol::wire::CaptureStart;

use super::file::Rig;
use super::merge::{BoardCounts, MergedFrame, Merger};
use crate::link::verify::Verifier;
use crate::link::{CaptureBegan, Client, FrameOutcome, FrameSlopes, LinkError, StreamReport};

/// Why a rig could not start.
#[derive(Debug, thiserror::Error)]
pub enum RigStartError {
    #[error("board {board:?}: {error}")]
    Link { board: String, error: LinkError },
    #[error(
        "board {board:?} runs configuration digest {found}, not its part of the rig ({expected:#010x}): configure it (brightpix rig configure) or check its port"
    )]
    WrongConfiguration {
        board: String,
        found: String,
        expected: u32,
    },
}

/// Uploads each board's part over its client (in board order) and checks
/// that every board then runs it.
pub fn configure(rig: &Rig, clients: &mut [Client]) -> Result<(), RigStartError> {
    for (board, client) in rig.boards.iter().zip(clients.iter_mut()) {
        client
            .configure(&board.config.view())
            .map_err(|error| RigStartError::Link {
                board: board.name.clone(),
                error,
            })?;
    }
    check_configurations(rig, clients)
}

/// Refuses a board whose active configuration is not its part of the rig.
pub fn check_configurations(rig: &Rig, clients: &mut [Client]) -> Result<(), RigStartError> {
    for (board, client) in rig.boards.iter().zip(clients.iter_mut()) {
        let status = client.status().map_err(|error| RigStartError::Link {
            board: board.name.clone(),
            error,
        })?;
        let expected = config_digest(&board.config.view());
        if status.config_digest != Some(expected) {
            return Err(RigStartError::WrongConfiguration {
                board: board.name.clone(),
                found: status
                    .config_digest
                    .map_or("none".into(), |d| format!("{d:#010x}")),
                expected,
            });
        }
    }
    Ok(())
}

/// What a board did in a run.
#[derive(Debug)]
pub struct BoardRun {
    pub report: StreamReport,
    /// Why it stopped early, if it did.
    pub error: Option<LinkError>,
    pub counts: BoardCounts,
    /// The highest frame number it gave an outcome for.
    pub last_frame: Option<u32>,
    /// How its capture began (`rig capture`), if it said.
    pub began: Option<CaptureBegan>,
}

impl BoardRun {
    /// Frames completed per second over its stream: the board's measured
    /// frame rate.
    pub fn frames_per_second(&self) -> f64 {
        self.report.frames_done as f64 / self.report.elapsed.as_secs_f64().max(1e-9)
    }

    /// Whether the board kept up with a camera of `camera_rate` frames per
    /// second (within 5%, the timing of a run's first and last frames);
    /// `None` when it completed no frame.
    pub fn keeps_up_with(&self, camera_rate: f64) -> Option<bool> {
        (self.report.frames_done > 0).then(|| self.frames_per_second() >= 0.95 * camera_rate)
    }
}

/// A rig run's totals.
pub struct RigRun {
    pub boards: Vec<BoardRun>,
    /// Frames merged with every board's results.
    pub frames_complete: u64,
    /// Frames merged with some board's results missing.
    pub frames_partial: u64,
    pub verifier: Option<Verifier>,
    pub elapsed: Duration,
    /// How the capture started the boards (`rig capture`).
    pub start: Option<RigStart>,
    /// The alignment self-check on rows boards share (`rig capture`).
    pub edge_check: EdgeCheck,
}

/// `rig capture`'s alignment self-check without wiring: boards whose
/// rectangles share a camera row ([`Rig::shared_rows`]) send a checksum of
/// it every frame (`EdgeRows`), and every merged frame's neighbours must
/// agree.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct EdgeCheck {
    /// Pairs of boards sharing a row `(above, below)`.
    pub pairs: Vec<(usize, usize)>,
    /// Merged frames in which at least one pair could be compared.
    pub frames_checked: u64,
    /// Merged frames in which a pair disagreed.
    pub frames_disagreeing: u64,
    /// The first few of them.
    pub first_disagreeing: Vec<u32>,
}

impl EdgeCheck {
    /// Compares `m`'s shared rows; marks it if a pair disagrees.
    fn check(&mut self, m: &mut MergedFrame) {
        let mut compared = false;
        for &(above, below) in &self.pairs {
            let pair = (m.edge_rows.get(above), m.edge_rows.get(below));
            if let (Some(Some((_, last))), Some(Some((first, _)))) = pair {
                compared = true;
                m.edges_disagree |= last != first;
            }
        }
        self.frames_checked += u64::from(compared);
        if m.edges_disagree {
            self.frames_disagreeing += 1;
            if self.first_disagreeing.len() < 10 {
                self.first_disagreeing.push(m.frame);
            }
        }
    }
}

/// How `rig capture` starts its boards (PROTOCOL.md §9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RigStart {
    /// Every board at once, each on the first frame start after its own
    /// request: on hardware they may begin on different camera frames.
    Immediate,
    /// On the sync line: every board but `leader` armed (`OnSync`) first;
    /// only when all are is the leader's capture (`DriveSync`) sent; all
    /// begin on the frame after the leader's edge.
    Sync { leader: usize },
}

impl RigStart {
    /// The board whose first camera frame the merge is numbered from.
    pub fn reference_board(self) -> usize {
        match self {
            RigStart::Immediate => 0,
            RigStart::Sync { leader } => leader,
        }
    }
}

enum Event {
    Outcome(usize, FrameOutcome),
    Ended(usize, Result<StreamReport, LinkError>),
    /// A follower is armed on the sync line.
    Armed,
    Began(usize, CaptureBegan),
}

/// A rig run in batches: each [`RigStream::run`] streams some frames (a
/// batch read from a file) to every board still running, merges and
/// verifies them; [`RigStream::finish`] gives the totals. The merge by
/// frame number and the whole-camera reference (its level filters) go on
/// from batch to batch; a board that failed is left out of later batches,
/// its sub-apertures without results there.
pub struct RigStream<'r> {
    rig: &'r Rig,
    merger: Merger,
    verifier: Option<Verifier>,
    reports: Vec<StreamReport>,
    errors: Vec<Option<LinkError>>,
    complete: u64,
    partial: u64,
    started: Instant,
    /// Per board, the highest frame number it gave an outcome for (a
    /// capture's camera frames run to it).
    last_frames: Vec<Option<u32>>,
    /// Per board, how its capture began.
    began: Vec<Option<CaptureBegan>>,
    start: Option<RigStart>,
    /// The camera frame merged frame 0 is, once known (a capture).
    base: Option<u32>,
    edge_check: EdgeCheck,
}

impl<'r> RigStream<'r> {
    /// With `verify`, a whole-camera reference checks every complete frame
    /// (a partial one counts as dropped).
    pub fn new(rig: &'r Rig, verify: bool) -> Self {
        let maps = rig.boards.iter().map(|b| b.windows.clone()).collect();
        RigStream {
            rig,
            merger: Merger::new(maps, rig.whole.windows.len()),
            verifier: verify.then(|| {
                Verifier::new(&rig.whole.view(), 10).expect("a loaded rig's configuration is valid")
            }),
            reports: vec![StreamReport::default(); rig.boards.len()],
            errors: (0..rig.boards.len()).map(|_| None).collect(),
            complete: 0,
            partial: 0,
            started: Instant::now(),
            last_frames: vec![None; rig.boards.len()],
            began: vec![None; rig.boards.len()],
            start: None,
            base: None,
            edge_check: EdgeCheck::default(),
        }
    }

    /// Streams `frames` (whole camera frames, numbered from `first_frame`)
    /// to the boards still running, one client each (in board order), in
    /// parallel; every merged frame goes to `on_frame` in frame order.
    pub fn run(
        &mut self,
        clients: &mut [Client],
        frames: &[Vec<u16>],
        first_frame: u32,
        on_frame: &mut impl FnMut(&MergedFrame),
    ) {
        let width = self.rig.whole.camera.width as usize;
        for k in 0..frames.len() {
            self.merger.expect(first_frame.wrapping_add(k as u32));
        }
        let rig = self.rig;
        let running: Vec<bool> = self.errors.iter().map(Option::is_none).collect();
        std::thread::scope(|scope| {
            let (tx, rx) = mpsc::channel();
            for (b, client) in clients.iter_mut().enumerate() {
                if !running[b] {
                    continue;
                }
                let tx = tx.clone();
                let rectangle = rig.boards[b].rectangle;
                scope.spawn(move || {
                    let cropped = frames.iter().map(|f| rectangle.crop(f, width));
                    let result = client.stream_frames(first_frame, cropped, |o| {
                        let _ = tx.send(Event::Outcome(b, o));
                    });
                    let _ = tx.send(Event::Ended(b, result));
                });
            }
            drop(tx);
            for event in rx {
                let merged = match event {
                    Event::Outcome(b, o) => self.merger.add(b, o),
                    Event::Ended(b, Ok(report)) => {
                        let total = &mut self.reports[b];
                        total.frames_sent += report.frames_sent;
                        total.frames_done += report.frames_done;
                        total.frames_dropped += report.frames_dropped;
                        total.pixel_bytes += report.pixel_bytes;
                        total.elapsed += report.elapsed;
                        Vec::new()
                    }
                    // Frames it never sent wait for it no longer, here or later.
                    Event::Ended(b, Err(e)) => {
                        self.errors[b] = Some(e);
                        self.merger.board_gone(b)
                    }
                    Event::Armed | Event::Began(..) => Vec::new(),
                };
                let mut pixels = |f: u32| frames.get(f.wrapping_sub(first_frame) as usize).cloned();
                self.deliver(merged, &mut pixels, on_frame);
            }
        });
    }

    /// Captures `count` frames with every board's own camera (one client
    /// each, in board order) and merges frame `k` of every board's
    /// capture: one camera frame only if every board began on the same
    /// one. `start` says how they begin: [`RigStart::Sync`] (the rig's
    /// sync line) makes them; [`RigStart::Immediate`] leaves it to the
    /// timing of each board's request (README, "Which frame is which").
    /// `camera_frame(c)` gives the whole camera's frame `c` for
    /// verification: merged frame `k` is checked against camera frame
    /// `base + k`, `base` the camera frame the reference board
    /// ([`RigStart::reference_board`]) reports it began on (0 if it does
    /// not say), so a board that began elsewhere shows as mismatches. A
    /// board that falls behind the camera skips frames: they wait for it
    /// until its capture ends, then count as missing on its sub-apertures.
    pub fn capture(
        &mut self,
        clients: &mut [Client],
        count: u32,
        start: RigStart,
        camera_frame: &mut impl FnMut(u32) -> Option<Vec<u16>>,
        on_frame: &mut impl FnMut(&MergedFrame),
    ) {
        for k in 0..count {
            self.merger.expect(k);
        }
        self.start = Some(start);
        self.edge_check.pairs = self.rig.shared_rows();
        let edge_rows = !self.edge_check.pairs.is_empty();
        let leader = match start {
            RigStart::Immediate => None,
            RigStart::Sync { leader } => Some(leader),
        };
        let followers = clients.len() - usize::from(leader.is_some());
        std::thread::scope(|scope| {
            let (tx, rx) = mpsc::channel();
            // On the sync line every board waits for a go: the followers
            // once armed, the leader before it is even asked; all get it
            // once every follower is armed (or a refusal if one cannot be).
            let mut gos = Vec::new();
            for (b, client) in clients.iter_mut().enumerate() {
                let tx = tx.clone();
                let role = match leader {
                    None => CaptureStart::Immediate,
                    Some(l) if l == b => CaptureStart::DriveSync,
                    Some(_) => CaptureStart::OnSync,
                };
                let (go_tx, go_rx) = mpsc::channel::<bool>();
                if role != CaptureStart::Immediate {
                    gos.push(go_tx);
                }
                scope.spawn(move || {
                    let started = Instant::now();
                    let not_released = || {
                        LinkError::Usage(
                            "not started: another board could not be armed on the sync line".into(),
                        )
                    };
                    if role == CaptureStart::DriveSync && go_rx.recv() != Ok(true) {
                        let _ = tx.send(Event::Ended(b, Err(not_released())));
                        return;
                    }
                    if let Err(e) = client.start_capture_with(count, role, edge_rows) {
                        let _ = tx.send(Event::Ended(b, Err(e)));
                        return;
                    }
                    if role == CaptureStart::OnSync {
                        let _ = tx.send(Event::Armed);
                        if go_rx.recv() != Ok(true) {
                            client.send_stop_capture();
                            let _ = tx.send(Event::Ended(b, Err(not_released())));
                            return;
                        }
                    }
                    // The board's rate counts from its first frame, not
                    // from its wait for the others or the edge.
                    let began_at = std::cell::Cell::new(started);
                    let began_seen = std::cell::Cell::new(false);
                    let result = client.collect_capture(
                        &mut |began| {
                            began_at.set(Instant::now());
                            began_seen.set(true);
                            let _ = tx.send(Event::Began(b, began));
                        },
                        &mut |o| {
                            let _ = tx.send(Event::Outcome(b, o.clone()));
                        },
                    );
                    let result = match result {
                        Ok(outcomes) => {
                            let done = outcomes
                                .iter()
                                .filter(|o| matches!(o, FrameOutcome::Done(_)))
                                .count();
                            Ok(StreamReport {
                                frames_sent: count as usize,
                                frames_done: done,
                                frames_dropped: outcomes.len() - done,
                                pixel_bytes: 0,
                                elapsed: began_at.get().elapsed(),
                            })
                        }
                        // Silence from a board armed on the line that never
                        // began: it missed the edge.
                        Err(interrupted) => Err(match interrupted.error {
                            LinkError::Timeout { port, timeout, .. }
                                if role != CaptureStart::Immediate && !began_seen.get() =>
                            {
                                LinkError::NoSyncEdge { port, timeout }
                            }
                            e => e,
                        }),
                    };
                    let _ = tx.send(Event::Ended(b, result));
                });
            }
            drop(tx);
            let mut armed = 0;
            let release = |go: bool, gos: &mut Vec<mpsc::Sender<bool>>| {
                for g in gos.drain(..) {
                    let _ = g.send(go);
                }
            };
            if followers == 0 {
                release(true, &mut gos);
            }
            for event in rx {
                let merged = match event {
                    Event::Armed => {
                        armed += 1;
                        if armed == followers {
                            release(true, &mut gos);
                        }
                        Vec::new()
                    }
                    Event::Began(b, began) => {
                        self.began[b] = Some(began);
                        Vec::new()
                    }
                    Event::Outcome(b, o) => {
                        if let Some(last) = self.last_frames.get_mut(b) {
                            *last = Some(last.map_or(o.frame(), |l: u32| l.max(o.frame())));
                        }
                        self.merger.add(b, o)
                    }
                    Event::Ended(b, result) => {
                        match result {
                            Ok(report) => self.reports[b] = report,
                            Err(e) => {
                                // Not armed: no board is released.
                                release(false, &mut gos);
                                self.errors[b] = Some(e)
                            }
                        }
                        // Its capture is over: frames it skipped wait no more.
                        self.merger.board_gone(b)
                    }
                };
                let base = self.capture_base(start);
                let mut pixels = |k: u32| camera_frame(base.wrapping_add(k));
                self.deliver(merged, &mut pixels, on_frame);
            }
        });
    }

    /// The camera frame merged frame 0 is: the reference board's, else
    /// the first board's that said, else 0; fixed once a frame is merged.
    fn capture_base(&mut self, start: RigStart) -> u32 {
        if let Some(base) = self.base {
            return base;
        }
        let reference = start.reference_board();
        let known = self.began[reference]
            .and_then(|b| b.camera_frame)
            .or_else(|| self.began.iter().flatten().find_map(|b| b.camera_frame));
        match known {
            Some(base) => {
                self.base = Some(base);
                base
            }
            None => 0,
        }
    }

    fn deliver(
        &mut self,
        merged: Vec<MergedFrame>,
        pixels: &mut dyn FnMut(u32) -> Option<Vec<u16>>,
        on_frame: &mut impl FnMut(&MergedFrame),
    ) {
        for mut m in merged {
            self.edge_check.check(&mut m);
            let frame = pixels(m.frame);
            let outcome = m.as_outcome();
            if outcome.is_some() {
                self.complete += 1;
            } else {
                self.partial += 1;
            }
            if let Some(v) = self.verifier.as_mut() {
                match (frame, outcome) {
                    (Some(pixels), Some(outcome)) => {
                        v.check(&pixels, &outcome);
                    }
                    (Some(pixels), None) => {
                        let dropped = FrameOutcome::Incomplete(FrameSlopes {
                            frame: m.frame,
                            ..FrameSlopes::default()
                        });
                        v.check(&pixels, &dropped);
                    }
                    (None, _) => v.missing(),
                }
            }
            on_frame(&m);
        }
    }

    /// Frames still awaited (none unless a board ended without an outcome
    /// for a frame it was sent) merged with what arrived, and the totals.
    pub fn finish(mut self, on_frame: &mut impl FnMut(&MergedFrame)) -> RigRun {
        let rest = self.merger.finish();
        self.deliver(rest, &mut |_| None, on_frame);
        let boards = self
            .reports
            .into_iter()
            .zip(self.errors)
            .zip(&self.merger.counts)
            .zip(self.last_frames)
            .zip(self.began)
            .map(
                |((((report, error), &counts), last_frame), began)| BoardRun {
                    report,
                    error,
                    counts,
                    last_frame,
                    began,
                },
            )
            .collect();
        RigRun {
            boards,
            frames_complete: self.complete,
            frames_partial: self.partial,
            verifier: self.verifier,
            elapsed: self.started.elapsed(),
            start: self.start,
            edge_check: self.edge_check,
        }
    }
}

/// Streams `frames` (whole camera frames, numbered from `first_frame`) to
/// the rig's boards in one batch ([`RigStream`]).
pub fn stream(
    rig: &Rig,
    mut clients: Vec<Client>,
    frames: &[Vec<u16>],
    first_frame: u32,
    verify: bool,
    mut on_frame: impl FnMut(&MergedFrame),
) -> RigRun {
    let mut run = RigStream::new(rig, verify);
    run.run(&mut clients, frames, first_frame, &mut on_frame);
    run.finish(&mut on_frame)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn board(frames_done: usize, seconds: f64) -> BoardRun {
        BoardRun {
            report: StreamReport {
                frames_done,
                elapsed: Duration::from_secs_f64(seconds),
                ..StreamReport::default()
            },
            error: None,
            counts: BoardCounts::default(),
            last_frame: None,
            began: None,
        }
    }

    /// A board's measured rate against the camera's: within 5% keeps up.
    #[test]
    fn a_board_slower_than_the_camera_is_told_apart() {
        assert_eq!(board(100, 1.0).frames_per_second(), 100.0);
        assert_eq!(board(100, 1.0).keeps_up_with(100.0), Some(true));
        assert_eq!(board(96, 1.0).keeps_up_with(100.0), Some(true));
        assert_eq!(board(80, 1.0).keeps_up_with(100.0), Some(false));
        assert_eq!(board(0, 1.0).keeps_up_with(100.0), None);
    }
}
