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
}

impl BoardRun {
    /// Frames completed per second over its stream.
    pub fn frames_per_second(&self) -> f64 {
        self.report.frames_done as f64 / self.report.elapsed.as_secs_f64().max(1e-9)
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
    Gone(usize, StreamReport, Option<LinkError>),
}

/// Streams `frames` (whole camera frames, numbered from `first_frame`) to
/// the rig's boards, one client each, in parallel; every merged frame goes
/// to `on_frame` in frame order. With `verify`, a whole-camera reference
/// checks every complete frame (a partial one counts as dropped).
pub fn stream(
    rig: &Rig,
    clients: Vec<Client>,
    frames: &[Vec<u16>],
    first_frame: u32,
    verify: bool,
    mut on_frame: impl FnMut(&MergedFrame),
) -> RigRun {
    let started = Instant::now();
    let width = rig.whole.camera.width as usize;
    let maps = rig.boards.iter().map(|b| b.windows.clone()).collect();
    let mut merger = Merger::new(maps, rig.whole.windows.len());
    for k in 0..frames.len() {
        merger.expect(first_frame.wrapping_add(k as u32));
    }
    let mut verifier = verify.then(|| {
        Verifier::new(&rig.whole.view(), 10).expect("a loaded rig's configuration is valid")
    });
    let mut reports: Vec<Option<(StreamReport, Option<LinkError>)>> =
        (0..rig.boards.len()).map(|_| None).collect();
    let (mut complete, mut partial) = (0u64, 0u64);
    let mut deliver = |merged: Vec<MergedFrame>| {
        for m in merged {
            let index = m.frame.wrapping_sub(first_frame) as usize;
            match m.as_outcome() {
                Some(outcome) => {
                    complete += 1;
                    if let Some(v) = verifier.as_mut() {
                        v.check(&frames[index], &outcome);
                    }
                }
                None => {
                    partial += 1;
                    if let Some(v) = verifier.as_mut() {
                        let dropped = FrameOutcome::Incomplete(FrameSlopes {
                            frame: m.frame,
                            ..FrameSlopes::default()
                        });
                        v.check(&frames[index], &dropped);
                    }
                }
            }
            on_frame(&m);
        }
    };
    std::thread::scope(|scope| {
        let (tx, rx) = mpsc::channel();
        for (b, mut client) in clients.into_iter().enumerate() {
            let tx = tx.clone();
            let rectangle = rig.boards[b].rectangle;
            scope.spawn(move || {
                let cropped = frames.iter().map(|f| rectangle.crop(f, width));
                let result = client.stream_frames(first_frame, cropped, |o| {
                    let _ = tx.send(Event::Outcome(b, o));
                });
                let (report, error) = match result {
                    Ok(report) => (report, None),
                    Err(e) => (StreamReport::default(), Some(e)),
                };
                let _ = tx.send(Event::Gone(b, report, error));
            });
        }
        drop(tx);
        for event in rx {
            match event {
                Event::Outcome(b, o) => deliver(merger.add(b, o)),
                Event::Gone(b, report, error) => {
                    reports[b] = Some((report, error));
                    deliver(merger.board_gone(b));
                }
            }
        }
    });
    deliver(merger.finish());
    let boards = reports
        .into_iter()
        .zip(&merger.counts)
        .map(|(r, &counts)| {
            let (report, error) = r.unwrap_or_default();
            BoardRun {
                report,
                error,
                counts,
            }
        })
        .collect();
    RigRun {
        boards,
        frames_complete: complete,
        frames_partial: partial,
        verifier,
        elapsed: started.elapsed(),
    }
}
