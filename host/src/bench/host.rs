//! The host bench: the engine on all cores and on one, and the peers on one
//! core, on the same frames, in interleaved rounds.
//!
//! Each peer's time is compared with the engine's on the peer's own rule:
//! the sort computes the workload's rule, the float peers
//! subtract-next-distinct (DARC's rule), so the engine is timed on that
//! rule too, on one core, in the same interleaved rounds. (Comparing the
//! float peers with the engine on subtract-next, a cheaper rule for the
//! engine, flattered it.)
//!
//! Before any timing, every peer's results are compared with the engine's on
//! every frame of the workload: the sort in the engine's arithmetic must be
//! identical (same rule, N, level filter); DARC's method and the two
//! quickselects, which compute subtract-next-distinct in `f32`, must be
//! within 2^-16 pixel of the engine run with that rule (and no level
//! filter), with the same validity.

use anyhow::{bail, Result};
use brightpix_protocol::SelectionRule;
use serde::Serialize;

use super::peers::{all_peers, Peer, PeerSlope, SortPeer};
use super::timing::interleaved_medians;
use super::workloads::Workload;
use crate::parallel::{BatchResults, ParallelEngine};

/// How long and on what the host bench runs.
#[derive(Clone, Copy, Debug)]
pub struct HostOptions {
    /// Timed rounds after the warm-up (the median is reported).
    pub rounds: usize,
    /// Threads for "all cores" (`None`: all of them).
    pub threads: Option<usize>,
    /// Each timed run goes over the workload's frames until it has seen at
    /// least this many pixels.
    pub pixels_per_run: usize,
}

impl Default for HostOptions {
    fn default() -> Self {
        HostOptions {
            rounds: 7,
            threads: None,
            pixels_per_run: 4_000_000,
        }
    }
}

/// A peer's figures.
#[derive(Clone, Debug, Serialize)]
pub struct PeerFigure {
    pub name: String,
    /// The rule it computes.
    pub rule: String,
    /// One core.
    pub mpx_per_s: f64,
    /// The peer's time over the engine's on the peer's own rule, both on
    /// one core.
    pub x_engine: f64,
    /// The peer's time over the engine's on the workload's rule (for the
    /// float peers a different rule: not a like-for-like figure).
    pub x_engine_workload_rule: f64,
    /// Largest difference of a slope from the engine's, pixels.
    pub max_slope_difference_px: f64,
    /// Identical to the engine (exact peers) or within 2^-16 pixel with the
    /// same validity (float peers), on every sub-aperture of every frame.
    pub agrees: bool,
}

/// One workload's host figures.
#[derive(Clone, Debug, Serialize)]
pub struct HostRow {
    pub workload: String,
    pub description: String,
    pub frames: usize,
    pub pixels_per_frame: usize,
    /// Threads of the all-cores figure, and how the engine split the work.
    pub threads: usize,
    pub split: String,
    /// The engine on all cores, Mpx/s.
    pub mpx_per_s: f64,
    /// The engine on one core, Mpx/s.
    pub mpx_per_s_one_core: f64,
    /// The engine on one core on the float peers' rule
    /// (subtract-next-distinct, no level filter), Mpx/s.
    pub mpx_per_s_one_core_peer_rule: f64,
    /// The per-window sort's time over the engine's, one core each.
    pub x_sort: f64,
    /// The fastest peer's time over the engine's, one core each.
    pub x_best_peer: f64,
    pub best_peer: String,
    pub peers: Vec<PeerFigure>,
}

/// Runs the engine (all cores, one core) and every peer (one core) on
/// `workload`; fails if a peer disagrees with the engine or the parallel
/// engine with the sequential one.
pub fn run_host(workload: &Workload, options: &HostOptions) -> Result<HostRow> {
    let view = workload.config.view();
    let shape = workload.shape;
    let subapertures = view.windows.len();
    let mut all = ParallelEngine::new(&view, options.threads)?;
    let mut one = ParallelEngine::new(&view, Some(1))?;
    let threads = all.threads();
    let split = if threads == 1 {
        "one thread".to_string()
    } else if view.selection.level_filter.is_some() || shape.frames < threads {
        format!("{} bands of sub-apertures", all.bands())
    } else {
        "frames".to_string()
    };

    // Agreement, on fresh engines.
    let reference = one.process(&workload.pixels, shape)?;
    if all.process(&workload.pixels, shape)? != reference {
        bail!(
            "{}: the engine on {threads} threads differs from the engine on one",
            workload.name
        );
    }
    let mut distinct_config = workload.config.clone();
    distinct_config.rule = SelectionRule::SubtractNextDistinct;
    distinct_config.level_filter = None;
    let mut one_distinct = ParallelEngine::new(&distinct_config.view(), Some(1))?;
    let distinct = one_distinct.process(&workload.pixels, shape)?;
    let mut peers = all_peers(&view);
    let mut agreement = Vec::new();
    for (k, peer) in peers.iter_mut().enumerate() {
        let exact = k == 0;
        let (expected, rule) = if exact {
            (&reference, rule_name(view.selection.rule))
        } else {
            (&distinct, rule_name(SelectionRule::SubtractNextDistinct))
        };
        let (max_difference, agrees) = compare(peer.as_mut(), workload, expected, exact);
        agreement.push((rule, max_difference, agrees));
    }
    if let Some((k, _)) = agreement.iter().enumerate().find(|(_, a)| !a.2) {
        bail!(
            "{}: the peer \"{}\" does not agree with the engine (largest slope difference {:.3e} px)",
            workload.name,
            peers[k].name(),
            agreement[k].1
        );
    }

    // Timing: every run goes over the frames `repeat` times.
    let repeat = options
        .pixels_per_run
        .div_ceil(workload.pixel_count().max(1))
        .max(1);
    let mut out_all = BatchResults::zeroed(shape.frames, subapertures);
    let mut out_one = BatchResults::zeroed(shape.frames, subapertures);
    let mut out_distinct = BatchResults::zeroed(shape.frames, subapertures);
    let mut engine_all = || {
        for _ in 0..repeat {
            all.process_into(&workload.pixels, shape, out_all.as_mut())
                .expect("checked above");
        }
    };
    let mut engine_one = || {
        for _ in 0..repeat {
            one.process_into(&workload.pixels, shape, out_one.as_mut())
                .expect("checked above");
        }
    };
    let mut engine_one_distinct = || {
        for _ in 0..repeat {
            one_distinct
                .process_into(&workload.pixels, shape, out_distinct.as_mut())
                .expect("checked above");
        }
    };
    let names: Vec<String> = peers.iter().map(|p| p.name().to_string()).collect();
    let mut peer_tasks: Vec<Box<dyn FnMut() + '_>> = peers
        .iter_mut()
        .map(|peer| {
            let mut slopes = vec![PeerSlope::default(); subapertures];
            let task = move || {
                for _ in 0..repeat {
                    for frame in workload.frames() {
                        peer.process(std::hint::black_box(frame), &mut slopes);
                    }
                }
                std::hint::black_box(&slopes);
            };
            Box::new(task) as Box<dyn FnMut()>
        })
        .collect();
    let mut tasks: Vec<&mut dyn FnMut()> =
        vec![&mut engine_all, &mut engine_one, &mut engine_one_distinct];
    for task in &mut peer_tasks {
        tasks.push(task.as_mut());
    }
    let medians = interleaved_medians(options.rounds, &mut tasks);
    drop(tasks);
    drop(peer_tasks);

    let pixels = (workload.pixel_count() * repeat) as f64;
    let rate = |seconds: f64| pixels / seconds.max(1e-12) * 1e-6;
    let engine_one_core = medians[1];
    let engine_one_core_peer_rule = medians[2];
    let peers: Vec<PeerFigure> = names
        .into_iter()
        .zip(&medians[3..])
        .zip(agreement)
        .enumerate()
        .map(
            |(k, ((name, &seconds), (rule, max_difference, agrees)))| PeerFigure {
                name,
                rule,
                mpx_per_s: rate(seconds),
                // Peer 0, the sort, computes the workload's own rule.
                x_engine: seconds
                    / if k == 0 {
                        engine_one_core
                    } else {
                        engine_one_core_peer_rule
                    },
                x_engine_workload_rule: seconds / engine_one_core,
                max_slope_difference_px: max_difference,
                agrees,
            },
        )
        .collect();
    let best = peers
        .iter()
        .min_by(|a, b| a.x_engine.total_cmp(&b.x_engine))
        .expect("there are peers");
    Ok(HostRow {
        workload: workload.name.clone(),
        description: workload.description.clone(),
        frames: shape.frames,
        pixels_per_frame: shape.pixels_per_frame(),
        threads,
        split,
        mpx_per_s: rate(medians[0]),
        mpx_per_s_one_core: rate(engine_one_core),
        mpx_per_s_one_core_peer_rule: rate(engine_one_core_peer_rule),
        x_sort: peers[0].x_engine,
        x_best_peer: best.x_engine,
        best_peer: best.name.clone(),
        peers,
    })
}

/// The peer's slopes against `expected` on every frame: the largest slope
/// difference (pixels) and whether they agree.
fn compare(
    peer: &mut dyn Peer,
    workload: &Workload,
    expected: &BatchResults,
    exact: bool,
) -> (f64, bool) {
    let subapertures = expected.subapertures;
    let mut slopes = vec![PeerSlope::default(); subapertures];
    let mut largest = 0f64;
    let mut agrees = true;
    for (f, frame) in workload.frames().enumerate() {
        peer.process(frame, &mut slopes);
        for (s, got) in slopes.iter().enumerate() {
            let want = expected.get(f, s);
            let dx = (got.x - want.slope_x as f64 / 65536.0).abs();
            let dy = (got.y - want.slope_y as f64 / 65536.0).abs();
            let difference = dx.max(dy);
            largest = largest.max(difference);
            let close = if exact {
                difference == 0.0
            } else {
                difference <= 1.0 / 65536.0
            };
            agrees &= close && got.valid == want.valid;
        }
    }
    (largest, agrees)
}

/// The configuration file's name of a rule.
pub fn rule_name(rule: SelectionRule) -> String {
    match rule {
        SelectionRule::Threshold => "threshold".into(),
        SelectionRule::SubtractNext => "subtract-next".into(),
        SelectionRule::SubtractNextDistinct => "subtract-next-distinct".into(),
        SelectionRule::SubtractMean { count } => format!("subtract-mean M={count}"),
    }
}

/// The sort peer's exact results on one frame (for tests).
pub fn sort_peer_frame(
    config: &brightpix_protocol::Config<'_>,
    frame: &[u16],
) -> Vec<brightpix_firmware::engine::SubapertureResult> {
    let mut peer = SortPeer::new(config);
    let mut slopes = vec![PeerSlope::default(); config.windows.len()];
    peer.process(frame, &mut slopes);
    peer.results
}

/// The host table: a row per workload.
pub fn host_table(rows: &[HostRow]) -> String {
    let mut out = String::new();
    out.push_str(&format!(
        "{:<28} {:>9} {:>9} {:>8} {:>8}  {}\n",
        "workload",
        "Mpx/s all",
        "Mpx/s 1",
        "x sort",
        "x peer",
        "best peer (its Mpx/s on one core; x peer: on its own rule)"
    ));
    for row in rows {
        let best = row
            .peers
            .iter()
            .find(|p| p.name == row.best_peer)
            .map_or(0.0, |p| p.mpx_per_s);
        out.push_str(&format!(
            "{:<28} {:>9.1} {:>9.1} {:>8.2} {:>8.2}  {} ({:.1})\n",
            row.workload,
            row.mpx_per_s,
            row.mpx_per_s_one_core,
            row.x_sort,
            row.x_best_peer,
            row.best_peer,
            best
        ));
    }
    out
}

/// Every peer of every row: Mpx/s on one core, ratio, agreement.
pub fn peer_table(rows: &[HostRow]) -> String {
    let mut out = String::new();
    for row in rows {
        out.push_str(&format!(
            "{}: {} frames of {} px; engine {:.1} Mpx/s on one core ({:.1} on subtract-next-distinct), {:.1} on {} threads (split by {})\n",
            row.workload,
            row.frames,
            row.pixels_per_frame,
            row.mpx_per_s_one_core,
            row.mpx_per_s_one_core_peer_rule,
            row.mpx_per_s,
            row.threads,
            row.split
        ));
        for peer in &row.peers {
            out.push_str(&format!(
                "  {:<58} {:>7.1} Mpx/s  {:>5.2}x the engine's time on its rule ({:.2}x on the workload's)  {} (max |slope diff| {:.1e} px, {})\n",
                peer.name,
                peer.mpx_per_s,
                peer.x_engine,
                peer.x_engine_workload_rule,
                if peer.agrees { "agrees" } else { "DISAGREES" },
                peer.max_slope_difference_px,
                peer.rule
            ));
        }
    }
    out
}
