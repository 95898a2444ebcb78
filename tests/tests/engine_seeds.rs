//! The engine's speed paths against the reference, on frame sequences made
//! to drive each of them: a window's admission threshold starts from its
//! previous frames' cutoff (its *seed*, `engine/seed.rs`), and a seed that is
//! too low fills the candidate buffer (compaction), one that is too high
//! leaves out a pixel the rule needs (the window is computed again from the
//! row history: a rescan), and one that is right settles the window early
//! (strict admission). Results never depend on the seed: every frame is
//! checked bit for bit against the reference, and the engine's counters
//! show that each path ran.
//!
//! Frames go in as whole rows (the engine's whole-row path for windows that
//! do not overlap) and in odd chunks (its general path), and both must agree
//! with the reference.

use brightpix::engine_runner::EngineBuffers;
use brightpix::reference::Reference;
use brightpix_firmware::engine::{Engine, EngineStats, SubapertureResult};
use brightpix_protocol::{Camera, LevelFilter, SelectionRule, SubapertureWindow};
use brightpix_tests::{Case, PixelCounts};

/// A small deterministic generator (xorshift64*), so the sequences need no
/// random-number crate and stay the same on every machine.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

const SIDE: u16 = 12;
const ACROSS: u16 = 3;

fn grid() -> Vec<SubapertureWindow> {
    (0..ACROSS * ACROSS)
        .map(|k| SubapertureWindow {
            x: (k % ACROSS) * SIDE,
            y: (k / ACROSS) * SIDE,
            width: SIDE,
            height: SIDE,
        })
        .collect()
}

/// The grid plus windows overlapping it: the general path.
fn overlapping() -> Vec<SubapertureWindow> {
    let mut windows = grid();
    windows.push(SubapertureWindow {
        x: 6,
        y: 6,
        width: SIDE,
        height: SIDE,
    });
    windows.push(SubapertureWindow {
        x: 18,
        y: 3,
        width: 10,
        height: 14,
    });
    windows
}

fn case(windows: Vec<SubapertureWindow>, rule: SelectionRule, n: u16, filter: bool) -> Case {
    case_at(windows, rule, n, filter, 12)
}

fn case_at(
    windows: Vec<SubapertureWindow>,
    rule: SelectionRule,
    n: u16,
    filter: bool,
    bit_depth: u8,
) -> Case {
    let camera = Camera {
        width: SIDE * ACROSS,
        height: SIDE * ACROSS,
        bit_depth,
    };
    Case {
        camera,
        windows,
        grid: None,
        background: Some(vec![40 * 16; camera.pixel_count()]),
        gain: None,
        threshold: None,
        rule,
        pixels: PixelCounts::All(n),
        level_filter: filter.then_some(LevelFilter { gain_shift: 2 }),
        reference_slopes: None,
        min_flux: 0,
        crop: None,
    }
}

/// What a frame of a sequence looks like: a spot per window of `flux`
/// (peak counts) at an offset, on a background of 40 counts with uniform
/// noise of +-`noise`.
#[derive(Clone, Copy)]
struct Scene {
    flux: f64,
    offset: (f64, f64),
    noise: f64,
}

fn frame(camera: Camera, scene: Scene, rng: &mut Rng) -> Vec<u16> {
    let side = SIDE as f64;
    let centre = (side - 1.0) / 2.0;
    let max = camera.max_raw() as f64;
    (0..camera.height)
        .flat_map(|y| (0..camera.width).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (i, j) = ((x % SIDE) as f64, (y % SIDE) as f64);
            let (dx, dy) = (i - centre - scene.offset.0, j - centre - scene.offset.1);
            let spot = scene.flux * (-(dx * dx + dy * dy) / 4.5).exp();
            let noise = (rng.unit() - 0.5) * 2.0 * scene.noise;
            (40.0 + spot + noise).round().clamp(0.0, max) as u16
        })
        .collect()
}

/// Sequences that move the cutoff slowly, step it up (seed too low) and
/// down (seed too high), and flatten it into ties.
fn scenes() -> Vec<Scene> {
    let mut out = Vec::new();
    for t in 0..8 {
        out.push(Scene {
            flux: 60.0,
            offset: (0.1 * t as f64, -0.05 * t as f64),
            noise: 3.0,
        });
    }
    // Much brighter: last frame's cutoff is far below this one's.
    out.push(Scene {
        flux: 600.0,
        offset: (0.5, 0.0),
        noise: 3.0,
    });
    out.push(Scene {
        flux: 600.0,
        offset: (0.6, 0.1),
        noise: 3.0,
    });
    // Much dimmer: the seed is above every pixel but the spot's core.
    out.push(Scene {
        flux: 8.0,
        offset: (-1.0, 1.0),
        noise: 3.0,
    });
    // No noise and no spot: every pixel ties.
    out.push(Scene {
        flux: 0.0,
        offset: (0.0, 0.0),
        noise: 0.0,
    });
    // Back to a spot: the seed from the flat frame is the background.
    out.push(Scene {
        flux: 60.0,
        offset: (0.0, 0.0),
        noise: 3.0,
    });
    out.push(Scene {
        flux: 60.0,
        offset: (2.5, -2.5),
        noise: 0.5,
    });
    out
}

/// Runs a case's sequence through the engine (rows whole, or in chunks of
/// `chunk` pixels) and the reference; panics at the first difference.
/// Returns the engine's counters.
fn run(case: &Case, chunk: Option<usize>, seed: u64) -> EngineStats {
    let config = case.view();
    let mut reference = Reference::new(&config).expect("valid configuration");
    let mut buffers = EngineBuffers::for_config(&config);
    let mut engine = Engine::new(config, buffers.memory()).expect("valid configuration");
    let mut rng = Rng(seed);
    let width = case.camera.width as usize;
    for (f, scene) in scenes().into_iter().enumerate() {
        let pixels = frame(case.camera, scene, &mut rng);
        let mut got: Vec<SubapertureResult> = Vec::new();
        let step = chunk.unwrap_or(width);
        for part in pixels.chunks(step) {
            engine
                .push(part, &mut |r: SubapertureResult| got.push(r))
                .expect("pixels are in range");
        }
        let want = reference
            .process_frame(&pixels)
            .expect("pixels are in range");
        assert_eq!(want.len(), got.len(), "frame {f}: results");
        got.sort_by_key(|r| r.index);
        for (w, g) in want.iter().zip(&got) {
            assert_eq!(
                (w.index, w.slope_x, w.slope_y, w.flux, w.valid),
                (g.index as usize, g.slope_x, g.slope_y, g.flux, g.valid),
                "frame {f} ({:?}, N {:?}, chunk {chunk:?}), sub-aperture {}",
                case.rule,
                case.pixels,
                w.index
            );
        }
    }
    engine.stats()
}

fn rules() -> [SelectionRule; 4] {
    [
        SelectionRule::SubtractNext,
        SelectionRule::Threshold,
        SelectionRule::SubtractNextDistinct,
        SelectionRule::SubtractMean { count: 3 },
    ]
}

fn add(total: &mut EngineStats, s: EngineStats) {
    total.windows += s.windows;
    total.candidates += s.candidates;
    total.compactions += s.compactions;
    total.rescans += s.rescans;
    total.attentions += s.attentions;
    total.kernel_frames += s.kernel_frames;
}

#[test]
fn every_seed_path_agrees_with_the_reference() {
    let mut total = EngineStats::default();
    let mut whole_frame_rescans = 0;
    for rule in rules() {
        for n in [1, 5, 20, 60] {
            for filter in [false, true] {
                if filter && !rule.subtracts() {
                    continue;
                }
                // 12 bits: the row kernel with its range check, whole rows
                // only; 16 bits: without, and for the windows wholly inside
                // a chunk (chunks of 7 pixels fall inside none of these,
                // of 38 some).
                for bit_depth in [12, 16] {
                    let c = case_at(grid(), rule, n, filter, bit_depth);
                    add(&mut total, run(&c, None, 7 + n as u64));
                    add(&mut total, run(&c, Some(7), 7 + n as u64));
                    add(&mut total, run(&c, Some(38), 7 + n as u64));
                    // A whole frame in one call: rescans read the caller's
                    // frame instead of the row history (not written then).
                    let whole = run(&c, Some(usize::MAX), 7 + n as u64);
                    whole_frame_rescans += whole.rescans;
                    add(&mut total, whole);
                }
            }
        }
    }
    // Each path ran (the counters are speed-only state: if a change to the
    // seeds stopped driving a path, this test would no longer test it).
    assert!(total.rescans > 0, "no window was rescanned: {total:?}");
    assert!(
        whole_frame_rescans > 0,
        "no window of a whole frame pushed at once was rescanned"
    );
    assert!(total.compactions > 0, "no buffer was compacted: {total:?}");
    assert!(
        total.attentions > 0,
        "the row kernel never stopped at a window: {total:?}"
    );
    assert!(total.windows > 0);
}

/// A rescan calibrates again only the pixels whose raw value can reach its
/// bound (`Calibrator::each_in_range`, one loop for each combination of
/// calibration steps): with every combination of background map, gain map
/// and fixed threshold, rescanned windows agree with the reference, rows
/// pushed one at a time and frames whole.
#[test]
fn rescans_agree_with_the_reference_under_every_calibration() {
    for background in [false, true] {
        for gain in [false, true] {
            for threshold in [false, true] {
                let mut rescans = 0;
                for rule in rules() {
                    for n in [5, 20] {
                        let mut c = case(grid(), rule, n, false);
                        let pixels = c.camera.pixel_count();
                        if !background {
                            c.background = None;
                        }
                        if gain {
                            // Gains of 0.75 to 1.25, varying from pixel to
                            // pixel.
                            c.gain =
                                Some((0..pixels).map(|k| 3072 + (k * 37 % 2049) as u16).collect());
                        }
                        if threshold {
                            // Two counts above the background, in the
                            // noise: some pixels zeroed near the cutoffs.
                            c.threshold = Some(if background { 2 * 16 } else { 42 * 16 });
                        }
                        for chunk in [None, Some(usize::MAX)] {
                            rescans += run(&c, chunk, 3 + n as u64).rescans;
                        }
                    }
                }
                assert!(
                    rescans > 0,
                    "no window was rescanned (background {background}, gain {gain}, threshold {threshold})"
                );
            }
        }
    }
}

/// Every frame of a sequence in one call (a frame whole from its first
/// pixel on, then the next): the rescans of each read that frame's rows in
/// the caller's slice, not the rows of another.
#[test]
fn frames_pushed_together_agree_with_the_reference() {
    let mut rescans = 0;
    for rule in rules() {
        for n in [5, 20] {
            let c = case(grid(), rule, n, false);
            let config = c.view();
            let mut reference = Reference::new(&config).expect("valid configuration");
            let mut buffers = EngineBuffers::for_config(&config);
            let mut engine = Engine::new(config, buffers.memory()).expect("valid configuration");
            let mut rng = Rng(11 + n as u64);
            let frames: Vec<Vec<u16>> = scenes()
                .into_iter()
                .map(|scene| frame(c.camera, scene, &mut rng))
                .collect();
            let mut got: Vec<SubapertureResult> = Vec::new();
            engine
                .push(&frames.concat(), &mut |r: SubapertureResult| got.push(r))
                .expect("pixels are in range");
            let windows = config.windows.len();
            assert_eq!(got.len(), frames.len() * windows);
            for (f, (pixels, results)) in frames.iter().zip(got.chunks_mut(windows)).enumerate() {
                results.sort_by_key(|r| r.index);
                let want = reference
                    .process_frame(pixels)
                    .expect("pixels are in range");
                for (w, g) in want.iter().zip(results.iter()) {
                    assert_eq!(
                        (w.index, w.slope_x, w.slope_y, w.flux, w.valid),
                        (g.index as usize, g.slope_x, g.slope_y, g.flux, g.valid),
                        "frame {f} ({rule:?}, N {n}), sub-aperture {}",
                        w.index
                    );
                }
            }
            rescans += engine.stats().rescans;
        }
    }
    assert!(rescans > 0, "no window was rescanned");
}

#[test]
fn overlapping_windows_take_the_general_path_and_agree() {
    let mut total = EngineStats::default();
    for rule in rules() {
        for n in [3, 20] {
            let c = case(overlapping(), rule, n, rule.subtracts());
            add(&mut total, run(&c, None, 99));
            add(&mut total, run(&c, Some(13), 99));
        }
    }
    assert!(total.rescans > 0, "no window was rescanned: {total:?}");
}

/// A seed that is right most of the time: the candidates held stay close to
/// N (the point of seeding), far below the window's pixel count.
#[test]
fn a_steady_spot_keeps_few_candidates() {
    let c = case(grid(), SelectionRule::SubtractNext, 20, false);
    let config = c.view();
    let mut buffers = EngineBuffers::for_config(&config);
    let mut engine = Engine::new(config, buffers.memory()).unwrap();
    let mut rng = Rng(3);
    let steady = Scene {
        flux: 200.0,
        offset: (0.3, -0.2),
        noise: 1.0,
    };
    for _ in 0..4 {
        let pixels = frame(c.camera, steady, &mut rng);
        engine
            .push(&pixels, &mut |_r: SubapertureResult| {})
            .unwrap();
    }
    let before = engine.stats();
    for _ in 0..8 {
        let pixels = frame(c.camera, steady, &mut rng);
        engine
            .push(&pixels, &mut |_r: SubapertureResult| {})
            .unwrap();
    }
    let after = engine.stats();
    let windows = after.windows - before.windows;
    let held = after.candidates - before.candidates;
    let per_window = held as f64 / windows as f64;
    let pixels = (SIDE * SIDE) as f64;
    assert!(
        per_window < pixels / 3.0,
        "{per_window:.1} candidates per window of {pixels} pixels at N = 20"
    );
}

/// The seed's margin (speed only): a steady cutoff admits less than a
/// count below it next frame (without a gain map calibrated values of a
/// window differ by whole counts, 16 units, so nothing below the hint's
/// level: a fall costs a rescan), but more than half a count, and in a
/// window ending in the frame's last row one count but not two; a cutoff
/// that fell by one count widens it to a count or more, one that fell by 4
/// counts to at least half that, one that fell by 40 to more than that; a
/// seed that was too high widens it further.
#[test]
fn the_seed_margin_follows_the_cutoffs_moves() {
    use brightpix_firmware::engine::seed::{MarginFloor, Seed};
    let margin = |seed: &Seed| {
        let (hint, low) = seed.thresholds(MarginFloor::ORDINARY);
        hint - low
    };
    let mut steady = Seed::RESET;
    assert_eq!(
        steady.thresholds(MarginFloor::ORDINARY),
        (i32::MIN, i32::MIN)
    );
    for _ in 0..400 {
        steady.observe(1_000, false);
    }
    assert_eq!(steady.thresholds(MarginFloor::ORDINARY).0, 1_000);
    assert!((8..16).contains(&margin(&steady)), "{}", margin(&steady));
    // A window ending in the frame's last row, whose rescan would delay
    // the frame's last results: one count below, not two.
    let (hint, low) = steady.thresholds(MarginFloor::LAST_ROW);
    assert!((16..32).contains(&(hint - low)), "{}", hint - low);

    let mut fell_a_count = steady;
    fell_a_count.observe(1_000 - 16, false);
    assert!(margin(&fell_a_count) >= 16, "{}", margin(&fell_a_count));

    let mut moving = steady;
    moving.observe(1_000 - 64, false);
    // At least half the fall of 4 counts (64 units) below the new hint.
    let after_move = margin(&moving);
    assert!(
        after_move >= 32 && after_move > margin(&steady),
        "{after_move}"
    );
    let mut too_high = steady;
    too_high.observe(1_000 - 64, true);
    assert!(margin(&too_high) > after_move);
    // A fall of 40 counts (a bright spot's): wider than the fall, since
    // a bright window's levels are sparse and a rescan costs more.
    let mut bright = steady;
    bright.observe(1_000 - 640, false);
    assert!(margin(&bright) > 640, "{}", margin(&bright));
    // The move is forgotten slowly: still wider after 20 steady frames.
    for _ in 0..20 {
        moving.observe(1_000 - 64, false);
    }
    assert!(margin(&moving) > margin(&steady));
}

/// A jump of the cutoff beyond 2^25 units (beyond any calibrated value's
/// range, SPEC.md §2, but an `i32` all the same) caps the spread at 2^29,
/// so the margin at 1.5 x 2^25 less the knee plus the floor, without
/// overflow (debug builds would panic), from either end of the `i32`s.
#[test]
fn the_seed_spread_is_capped_for_any_jump() {
    use brightpix_firmware::engine::seed::{MarginFloor, Seed};
    // The margin's floor: 10 units, 18 for a window ending in the last row.
    let capped = |floor: i32| (1 << 25) + (1 << 24) - 48 + floor;
    for (from, to) in [
        (1 << 30, 0),
        (-(1 << 30), 0),
        (i32::MAX, 0),
        (i32::MIN + 1, 0),
        (0, 1 << 25),
    ] {
        let mut seed = Seed::RESET;
        seed.observe(from, false);
        seed.observe(to, false);
        for (floor, units) in [(MarginFloor::ORDINARY, 10), (MarginFloor::LAST_ROW, 18)] {
            let (hint, low) = seed.thresholds(floor);
            assert_eq!((hint, hint - low), (to, capped(units)), "{from} -> {to}");
        }
    }
    // Beyond the cap the margin saturates at `i32::MIN`.
    let mut seed = Seed::RESET;
    seed.observe(i32::MAX, false);
    seed.observe(i32::MIN + 1, true);
    assert_eq!(
        seed.thresholds(MarginFloor::ORDINARY),
        (i32::MIN + 1, i32::MIN)
    );
    assert_eq!(
        seed.thresholds(MarginFloor::LAST_ROW),
        (i32::MIN + 1, i32::MIN)
    );
}
