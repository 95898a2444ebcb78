//! One camera, K devices, one result: each board configured with its part
//! (and its digest checked before any frame), each fed its rectangle of
//! every frame on a thread of its own, their outcomes merged by frame
//! number ([`Merger`]) and, with verification, every merged frame checked
//! bit for bit against the whole-camera reference.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use brightpix_protocol::wire::tables::config_digest;

use super::file::Rig;
use super::merge::{BoardCounts, MergedFrame, Merger};
use crate::link::verify::Verifier;
use crate::link::{Client, FrameOutcome, FrameSlopes, LinkError, StreamReport};

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
}

enum Event {
    Outcome(usize, FrameOutcome),
    Ended(usize, Result<StreamReport, LinkError>),
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
                };
                let mut pixels = |f: u32| frames.get(f.wrapping_sub(first_frame) as usize).cloned();
                self.deliver(merged, &mut pixels, on_frame);
            }
        });
    }

    /// Captures `count` frames with every board's own camera at once (one
    /// client each, in board order) and merges frame `k` of every board's
    /// capture. That is one camera frame only if every board started
    /// counting at the same camera frame: simulated cameras of one seed
    /// begin their sequence at each capture's start, so they do; boards on
    /// real hardware, each numbering frames from the first VSYNC after its
    /// own `Capture`, need a common start or a frame counter the camera
    /// embeds, which nothing provides yet (README, "Which frame is which,
    /// today"). `camera_frame(k)` gives the whole camera's frame `k` for
    /// verification. A board that falls behind the
    /// camera skips frames: they wait for it until its capture ends, then
    /// count as missing on its sub-apertures.
    pub fn capture(
        &mut self,
        clients: &mut [Client],
        count: u32,
        camera_frame: &mut impl FnMut(u32) -> Option<Vec<u16>>,
        on_frame: &mut impl FnMut(&MergedFrame),
    ) {
        for k in 0..count {
            self.merger.expect(k);
        }
        std::thread::scope(|scope| {
            let (tx, rx) = mpsc::channel();
            for (b, client) in clients.iter_mut().enumerate() {
                let tx = tx.clone();
                scope.spawn(move || {
                    let started = Instant::now();
                    let result = client.capture_with(count, &mut |o| {
                        let _ = tx.send(Event::Outcome(b, o.clone()));
                    });
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
                                elapsed: started.elapsed(),
                            })
                        }
                        Err(interrupted) => Err(interrupted.error),
                    };
                    let _ = tx.send(Event::Ended(b, result));
                });
            }
            drop(tx);
            for event in rx {
                let merged = match event {
                    Event::Outcome(b, o) => {
                        if let Some(last) = self.last_frames.get_mut(b) {
                            *last = Some(last.map_or(o.frame(), |l: u32| l.max(o.frame())));
                        }
                        self.merger.add(b, o)
                    }
                    Event::Ended(b, result) => {
                        match result {
                            Ok(report) => self.reports[b] = report,
                            Err(e) => self.errors[b] = Some(e),
                        }
                        // Its capture is over: frames it skipped wait no more.
                        self.merger.board_gone(b)
                    }
                };
                self.deliver(merged, camera_frame, on_frame);
            }
        });
    }

    fn deliver(
        &mut self,
        merged: Vec<MergedFrame>,
        pixels: &mut dyn FnMut(u32) -> Option<Vec<u16>>,
        on_frame: &mut impl FnMut(&MergedFrame),
    ) {
        for m in merged {
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
            .map(|(((report, error), &counts), last_frame)| BoardRun {
                report,
                error,
                counts,
                last_frame,
            })
            .collect();
        RigRun {
            boards,
            frames_complete: self.complete,
            frames_partial: self.partial,
            verifier: self.verifier,
            elapsed: self.started.elapsed(),
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
