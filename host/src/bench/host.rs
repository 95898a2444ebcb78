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
//!
//! The no-selection baseline ([`super::baseline`]: calibrate and centre of
//! gravity of every pixel, what a user who does not select runs) must equal
//! the engine configured with no selection (N at least every window's pixel
//! count) bit for bit on every frame; both are timed, and the row gives the
//! selecting engine's time over the baseline's: the price of selecting.
//!
//! Every task is timed in runs of at least [`HostOptions::min_run_seconds`]
//! over interleaved rounds ([`super::timing`]); the figures are the
//! minimum, median and maximum over the rounds, ratios taken round by
//! round.

use anyhow::{bail, Result};
use brightpix_protocol::SelectionRule;
use serde::Serialize;

use super::baseline::NoSelectionPeer;
use super::peers::{all_peers, Peer, PeerSlope, SortPeer};
use super::timing::{interleaved, Stats, Timings};
use super::workloads::Workload;
use crate::config_file::PixelCounts;
use crate::parallel::{BatchResults, ParallelEngine};

/// How long and on what the host bench runs.
#[derive(Clone, Copy, Debug)]
pub struct HostOptions {
    /// Timed rounds after the warm-up (min, median and max are reported).
    pub rounds: usize,
    /// Threads for "all cores" (`None`: all of them).
    pub threads: Option<usize>,
    /// Each task repeats its work until one timed run lasts at least this
    /// long (seconds).
    pub min_run_seconds: f64,
}

impl Default for HostOptions {
    fn default() -> Self {
        HostOptions {
            rounds: 20,
            threads: None,
            min_run_seconds: 0.1,
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
    pub mpx_per_s: Stats,
    /// The peer's time over the engine's on the peer's own rule, both on
    /// one core, round by round.
    pub x_engine: Stats,
    /// The peer's time over the engine's on the workload's rule (for the
    /// float peers a different rule: not a like-for-like figure).
    pub x_engine_workload_rule: Stats,
    /// Largest difference of a slope from the engine's, pixels.
    pub max_slope_difference_px: f64,
    /// Identical to the engine (exact peers) or within 2^-16 pixel with the
    /// same validity (float peers), on every sub-aperture of every frame.
    pub agrees: bool,
}

/// The no-selection baseline's figures.
#[derive(Clone, Debug, Serialize)]
pub struct BaselineFigure {
    pub name: String,
    /// One core.
    pub mpx_per_s: Stats,
    /// The engine with no selection (N >= every window's pixel count), one
    /// core: what the baseline must equal bit for bit.
    pub engine_no_selection_mpx_per_s: Stats,
    /// The engine's time with no selection over the baseline's.
    pub engine_no_selection_over_baseline: Stats,
    /// The same code built for baseline x86-64 (SSE2), as the engine is
    /// (where the baseline above uses AVX2), one core.
    pub portable_mpx_per_s: Stats,
    /// Equal to the engine with no selection (slopes, flux, validity) on
    /// every sub-aperture of every frame.
    pub agrees: bool,
}

/// One workload's host figures. Every figure is over the timed rounds:
/// rates from each round's time, ratios round by round.
#[derive(Clone, Debug, Serialize)]
pub struct HostRow {
    pub workload: String,
    pub description: String,
    pub frames: usize,
    pub pixels_per_frame: usize,
    /// Threads of the all-cores figure, and how the engine split the work.
    pub threads: usize,
    pub split: String,
    /// Timed rounds, and the shortest timed run of any task (seconds).
    pub rounds: usize,
    pub shortest_run_s: f64,
    /// The engine on all cores, Mpx/s.
    pub mpx_per_s: Stats,
    /// The engine on one core, Mpx/s.
    pub mpx_per_s_one_core: Stats,
    /// The engine on one core on the float peers' rule
    /// (subtract-next-distinct, no level filter), Mpx/s.
    pub mpx_per_s_one_core_peer_rule: Stats,
    /// The per-window sort's time over the engine's, one core each.
    pub x_sort: Stats,
    /// The fastest peer's (by median) time over the engine's on its own
    /// rule, one core each.
    pub x_best_peer: Stats,
    pub best_peer: String,
    /// The engine's time (workload's rule, one core) over the no-selection
    /// baseline's: what selecting costs over not selecting.
    pub engine_over_baseline: Stats,
    /// The same over the baseline built as the engine is (SSE2).
    pub engine_over_portable_baseline: Stats,
    pub baseline: BaselineFigure,
    pub peers: Vec<PeerFigure>,
}

/// The order of the timed tasks; the peers follow.
const ALL_CORES: usize = 0;
const ONE_CORE: usize = 1;
const ONE_CORE_PEER_RULE: usize = 2;
const ONE_CORE_NO_SELECTION: usize = 3;
const BASELINE: usize = 4;
const BASELINE_PORTABLE: usize = 5;
const PEERS: usize = 6;

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

    // The engine with no selection (SPEC.md §3: N at least every window's
    // pixel count; the rule and level filter then play no part) and the
    // baseline, which must equal it exactly.
    let mut no_selection_config = workload.config.clone();
    let largest = view.windows.iter().map(|w| w.pixel_count()).max();
    no_selection_config.pixels = PixelCounts::All(largest.unwrap_or(1) as u16);
    let mut one_no_selection = ParallelEngine::new(&no_selection_config.view(), Some(1))?;
    let no_selection = one_no_selection.process(&workload.pixels, shape)?;
    let mut baseline = NoSelectionPeer::new(&view);
    let mut portable = NoSelectionPeer::portable(&view);
    for peer in [&mut baseline, &mut portable] {
        if let Some(frame) = baseline_disagrees(peer, workload, &no_selection) {
            bail!(
                "{}: the baseline \"{}\" differs from the engine with no selection on frame {frame}",
                workload.name,
                peer.name()
            );
        }
    }

    // Timing: each task's argument is how many times to go over the frames.
    let mut out_all = BatchResults::zeroed(shape.frames, subapertures);
    let mut out_one = BatchResults::zeroed(shape.frames, subapertures);
    let mut out_distinct = BatchResults::zeroed(shape.frames, subapertures);
    let mut out_no_selection = BatchResults::zeroed(shape.frames, subapertures);
    let engine_task = |engine: &mut ParallelEngine, out: &mut BatchResults, repeat: usize| {
        for _ in 0..repeat {
            engine
                .process_into(&workload.pixels, shape, out.as_mut())
                .expect("checked above");
        }
    };
    let mut engine_all = |r| engine_task(&mut all, &mut out_all, r);
    let mut engine_one = |r| engine_task(&mut one, &mut out_one, r);
    let mut engine_one_distinct = |r| engine_task(&mut one_distinct, &mut out_distinct, r);
    let mut engine_one_no_selection =
        |r| engine_task(&mut one_no_selection, &mut out_no_selection, r);
    let names: Vec<String> = peers.iter().map(|p| p.name().to_string()).collect();
    let baseline_name = baseline.name().to_string();
    let mut portable_task = peer_runs(&mut portable, workload);
    let mut baseline_task = peer_runs(&mut baseline, workload);
    let mut peer_tasks: Vec<Box<dyn FnMut(usize) + '_>> = peers
        .iter_mut()
        .map(|peer| Box::new(peer_runs(peer.as_mut(), workload)) as Box<dyn FnMut(usize)>)
        .collect();
    let mut tasks: Vec<&mut dyn FnMut(usize)> = vec![
        &mut engine_all,
        &mut engine_one,
        &mut engine_one_distinct,
        &mut engine_one_no_selection,
        &mut baseline_task,
        &mut portable_task,
    ];
    for task in &mut peer_tasks {
        tasks.push(task.as_mut());
    }
    let timings = interleaved(options.rounds, options.min_run_seconds, &mut tasks);
    drop(tasks);
    drop(peer_tasks);
    Ok(figures(
        workload,
        options,
        threads,
        split,
        &timings,
        names,
        agreement,
        baseline_name,
    ))
}

/// A timed task: `peer` over the workload's frames, as many times as asked.
fn peer_runs<'a>(peer: &'a mut dyn Peer, workload: &'a Workload) -> impl FnMut(usize) + 'a {
    let mut slopes = vec![PeerSlope::default(); workload.config.windows.len()];
    move |repeat| {
        for _ in 0..repeat {
            for frame in workload.frames() {
                peer.process(std::hint::black_box(frame), &mut slopes);
            }
        }
        std::hint::black_box(&slopes);
    }
}

/// The row from the timings (tasks in the order of the constants above).
#[allow(clippy::too_many_arguments)]
fn figures(
    workload: &Workload,
    options: &HostOptions,
    threads: usize,
    split: String,
    timings: &Timings,
    names: Vec<String>,
    agreement: Vec<(String, f64, bool)>,
    baseline_name: String,
) -> HostRow {
    let pixels = workload.pixel_count() as f64;
    let rate = |k: usize| {
        timings
            .stats(k)
            .map_decreasing(|seconds| pixels / seconds.max(1e-12) * 1e-6)
    };
    let peers: Vec<PeerFigure> = names
        .into_iter()
        .zip(agreement)
        .enumerate()
        .map(|(k, (name, (rule, max_difference, agrees)))| {
            // Peer 0, the sort, computes the workload's own rule.
            let own_rule = if k == 0 { ONE_CORE } else { ONE_CORE_PEER_RULE };
            PeerFigure {
                name,
                rule,
                mpx_per_s: rate(PEERS + k),
                x_engine: timings.ratio(PEERS + k, own_rule),
                x_engine_workload_rule: timings.ratio(PEERS + k, ONE_CORE),
                max_slope_difference_px: max_difference,
                agrees,
            }
        })
        .collect();
    let best = peers
        .iter()
        .min_by(|a, b| a.x_engine.median.total_cmp(&b.x_engine.median))
        .expect("there are peers");
    HostRow {
        workload: workload.name.clone(),
        description: workload.description.clone(),
        frames: workload.shape.frames,
        pixels_per_frame: workload.shape.pixels_per_frame(),
        threads,
        split,
        rounds: options.rounds.max(1),
        shortest_run_s: timings.shortest_run,
        mpx_per_s: rate(ALL_CORES),
        mpx_per_s_one_core: rate(ONE_CORE),
        mpx_per_s_one_core_peer_rule: rate(ONE_CORE_PEER_RULE),
        x_sort: peers[0].x_engine,
        x_best_peer: best.x_engine,
        best_peer: best.name.clone(),
        engine_over_baseline: timings.ratio(ONE_CORE, BASELINE),
        engine_over_portable_baseline: timings.ratio(ONE_CORE, BASELINE_PORTABLE),
        baseline: BaselineFigure {
            name: baseline_name,
            mpx_per_s: rate(BASELINE),
            engine_no_selection_mpx_per_s: rate(ONE_CORE_NO_SELECTION),
            engine_no_selection_over_baseline: timings.ratio(ONE_CORE_NO_SELECTION, BASELINE),
            portable_mpx_per_s: rate(BASELINE_PORTABLE),
            agrees: true,
        },
        peers,
    }
}

/// The first frame on which the baseline's results (slopes, flux,
/// validity) differ from `expected`, if any.
fn baseline_disagrees(
    baseline: &mut NoSelectionPeer,
    workload: &Workload,
    expected: &BatchResults,
) -> Option<usize> {
    let mut slopes = vec![PeerSlope::default(); expected.subapertures];
    workload.frames().enumerate().find_map(|(f, frame)| {
        baseline.process(frame, &mut slopes);
        let same = (0..expected.subapertures).all(|s| baseline.results[s] == expected.get(f, s));
        (!same).then_some(f)
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

/// `median [min-max]` with `decimals` decimals.
pub fn range(stats: &Stats, decimals: usize) -> String {
    format!(
        "{:.d$} [{:.d$}-{:.d$}]",
        stats.median,
        stats.min,
        stats.max,
        d = decimals
    )
}

/// The host tables: a row per workload, the engine against the sort and the
/// best peer (each on the peer's own rule), then against the no-selection
/// baseline; every figure `median [min-max]` over the rounds.
pub fn host_table(rows: &[HostRow]) -> String {
    let mut out = format!(
        "{:<28} {:>22} {:>22} {:>18} {:>18}\n",
        "workload", "Mpx/s all cores", "Mpx/s one core", "x sort", "x peer"
    );
    for row in rows {
        out.push_str(&format!(
            "{:<28} {:>22} {:>22} {:>18} {:>18}\n",
            row.workload,
            range(&row.mpx_per_s, 1),
            range(&row.mpx_per_s_one_core, 1),
            range(&row.x_sort, 2),
            range(&row.x_best_peer, 2),
        ));
    }
    out.push_str(&format!(
        "\n{:<28} {:>22} {:>22} {:>18} {:>18} {:>18}\n",
        "workload",
        "baseline Mpx/s",
        "engine no-sel Mpx/s",
        "no-sel/baseline",
        "engine/baseline",
        "engine/portable"
    ));
    for row in rows {
        out.push_str(&format!(
            "{:<28} {:>22} {:>22} {:>18} {:>18} {:>18}\n",
            row.workload,
            range(&row.baseline.mpx_per_s, 1),
            range(&row.baseline.engine_no_selection_mpx_per_s, 1),
            range(&row.baseline.engine_no_selection_over_baseline, 2),
            range(&row.engine_over_baseline, 2),
            range(&row.engine_over_portable_baseline, 2),
        ));
    }
    for row in rows {
        let best = row
            .peers
            .iter()
            .find(|p| p.name == row.best_peer)
            .map_or(Stats::default(), |p| p.mpx_per_s);
        out.push_str(&format!(
            "{}: best peer {} ({} Mpx/s; the engine on its rule {} Mpx/s); {} rounds, shortest run {:.0} ms\n",
            row.workload,
            row.best_peer,
            range(&best, 1),
            range(&row.mpx_per_s_one_core_peer_rule, 1),
            row.rounds,
            row.shortest_run_s * 1e3
        ));
    }
    out
}

/// Every peer of every row: Mpx/s on one core, ratios, agreement.
pub fn peer_table(rows: &[HostRow]) -> String {
    let mut out = String::new();
    for row in rows {
        out.push_str(&format!(
            "{}: {} frames of {} px; {} rounds, shortest run {:.0} ms; median [min-max]\n",
            row.workload,
            row.frames,
            row.pixels_per_frame,
            row.rounds,
            row.shortest_run_s * 1e3
        ));
        out.push_str(&format!(
            "  engine, one core                 {} Mpx/s\n  engine, one core, next-distinct  {} Mpx/s\n  engine, {} threads (by {}) {} Mpx/s\n",
            range(&row.mpx_per_s_one_core, 1),
            range(&row.mpx_per_s_one_core_peer_rule, 1),
            row.threads,
            row.split,
            range(&row.mpx_per_s, 1),
        ));
        let b = &row.baseline;
        out.push_str(&format!(
            "  {}: {} Mpx/s; the engine with no selection {} Mpx/s, {}x the baseline's time ({}); the engine selecting {}x\n  the same baseline built as the engine is (SSE2): {} Mpx/s; the engine selecting {}x its time\n",
            b.name,
            range(&b.mpx_per_s, 1),
            range(&b.engine_no_selection_mpx_per_s, 1),
            range(&b.engine_no_selection_over_baseline, 2),
            if b.agrees { "equal bit for bit" } else { "DIFFERS" },
            range(&row.engine_over_baseline, 2),
            range(&b.portable_mpx_per_s, 1),
            range(&row.engine_over_portable_baseline, 2),
        ));
        for peer in &row.peers {
            out.push_str(&format!(
                "  {}: {} Mpx/s, {}x the engine's time on its rule, {}x on the workload's; {} (max |slope diff| {:.1e} px, {})\n",
                peer.name,
                range(&peer.mpx_per_s, 1),
                range(&peer.x_engine, 2),
                range(&peer.x_engine_workload_rule, 2),
                if peer.agrees { "agrees" } else { "DISAGREES" },
                peer.max_slope_difference_px,
                peer.rule
            ));
        }
    }
    out
}
