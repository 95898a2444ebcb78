//! The engine at the sizes the issue names, and its refusals: ELT-class
//! 80x80 sub-apertures, 64x64-pixel windows, a 1024x1024 camera, and
//! configurations too large for the engine's memory.

use brightpix::engine_runner::{EngineBuffers, HostEngine};
use brightpix::reference::Reference;
use brightpix_firmware::engine::{Engine, MemorySize};
use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, ConfigError, MemoryKind, PixelCount, RegularGrid,
    Selection, SelectionRule, SubapertureWindow,
};

/// A xorshift generator: reproducible values without a dependency.
fn xorshift(seed: u64) -> impl FnMut() -> u64 {
    let mut state = seed | 1;
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    }
}

fn frame(camera: Camera, seed: u64) -> Vec<u16> {
    let mut next = xorshift(seed);
    (0..camera.pixel_count())
        .map(|_| (next() % (camera.max_raw() as u64 + 1)) as u16)
        .collect()
}

fn config<'a>(
    camera: Camera,
    windows: &'a [SubapertureWindow],
    rule: SelectionRule,
    n: u16,
) -> Config<'a> {
    Config {
        camera,
        windows,
        calibration: Calibration::default(),
        selection: Selection {
            rule,
            count: PixelCount::All(n),
            level_filter: None,
        },
        centroid: Centroid::default(),
        crop: None,
    }
}

fn assert_engine_matches_reference(config: Config<'_>, frames: &[Vec<u16>], chunk: usize) {
    let mut reference = Reference::new(&config).unwrap();
    let mut engine = HostEngine::new(config).unwrap();
    let results = engine
        .process(frames.iter().map(Vec::as_slice), chunk)
        .unwrap();
    for (frame, got) in frames.iter().zip(results) {
        let want = reference.process_frame(frame).unwrap();
        assert_eq!(want.len(), got.len());
        for (w, g) in want.iter().zip(&got) {
            assert_eq!(
                (w.index, w.slope_x, w.slope_y, w.flux, w.valid),
                (g.index as usize, g.slope_x, g.slope_y, g.flux, g.valid)
            );
        }
    }
}

#[test]
fn elt_class_80x80_grid_on_a_960x960_camera() {
    let camera = Camera {
        width: 960,
        height: 960,
        bit_depth: 12,
    };
    let grid = RegularGrid {
        x: 0,
        y: 0,
        columns: 80,
        rows: 80,
        width: 12,
        height: 12,
        pitch_x: 12,
        pitch_y: 12,
    };
    let windows: Vec<_> = grid.windows().collect();
    assert_eq!(windows.len(), 6400);
    let config = config(camera, &windows, SelectionRule::SubtractNext, 20);
    let mut buffers = EngineBuffers::for_config(&config);
    let needed = Engine::new(config, buffers.memory())
        .unwrap()
        .memory_needed();
    // One grid row of windows open at a time: the memory budget of memory.rs.
    assert_eq!(needed.open_windows, 80);
    // A candidate buffer of its preferred 4 (N + 1) + 64 = 148 entries per
    // open window, capped at the window's 144 pixels; the 12 rows of the
    // windows in the history, one window's pixels of scratch.
    assert_eq!(needed.pool_entries, 80 * 144);
    assert_eq!(needed.history_pixels, 12 * 960);
    assert_eq!(needed.scratch_entries, 144);
    assert_engine_matches_reference(config, &[frame(camera, 7)], 4096);
}

#[test]
fn windows_of_64x64_on_a_1024x1024_camera_with_large_n() {
    let camera = Camera {
        width: 1024,
        height: 1024,
        bit_depth: 16,
    };
    let grid = RegularGrid {
        x: 0,
        y: 0,
        columns: 16,
        rows: 16,
        width: 64,
        height: 64,
        pitch_x: 64,
        pitch_y: 64,
    };
    let windows: Vec<_> = grid.windows().collect();
    let frames = [frame(camera, 3)];
    for (rule, n) in [
        (SelectionRule::SubtractNext, 4095),
        (SelectionRule::Threshold, 1000),
        (SelectionRule::SubtractMean { count: 16 }, 20),
        (SelectionRule::SubtractNextDistinct, 4096),
    ] {
        assert_engine_matches_reference(config(camera, &windows, rule, n), &frames, 1000);
    }
}

#[test]
fn overlapping_and_unordered_windows() {
    let camera = Camera {
        width: 64,
        height: 40,
        bit_depth: 10,
    };
    let windows = [
        SubapertureWindow {
            x: 30,
            y: 5,
            width: 20,
            height: 30,
        },
        SubapertureWindow {
            x: 0,
            y: 0,
            width: 64,
            height: 40,
        },
        SubapertureWindow {
            x: 10,
            y: 5,
            width: 30,
            height: 10,
        },
        SubapertureWindow {
            x: 63,
            y: 39,
            width: 1,
            height: 1,
        },
        SubapertureWindow {
            x: 10,
            y: 5,
            width: 30,
            height: 10,
        },
    ];
    let frames: Vec<_> = (0..3).map(|s| frame(camera, s + 11)).collect();
    for chunk in [1, 7, 64, 65, 10_000] {
        assert_engine_matches_reference(
            config(camera, &windows, SelectionRule::Threshold, 9),
            &frames,
            chunk,
        );
    }
}

/// CANARY's camera (112x112 at `bit_depth`) and its 7x7 windows of 16x16.
fn canary(bit_depth: u8) -> (Camera, Vec<SubapertureWindow>) {
    let camera = Camera {
        width: 112,
        height: 112,
        bit_depth,
    };
    let grid = RegularGrid {
        x: 0,
        y: 0,
        columns: 7,
        rows: 7,
        width: 16,
        height: 16,
        pitch_x: 16,
        pitch_y: 16,
    };
    (camera, grid.windows().collect())
}

/// A pool too small for every open window's preferred buffer gives each
/// what it holds, down to the least: the results stay those of the
/// reference (only speed changes), and the smallest pool compacts.
#[test]
fn a_smaller_pool_gives_smaller_buffers_and_the_same_results() {
    let (camera, windows) = canary(12);
    let config = config(camera, &windows, SelectionRule::SubtractNext, 20);
    let frames: Vec<_> = (0..4).map(|seed| frame(camera, seed + 3)).collect();
    let mut reference = Reference::new(&config).unwrap();
    let want: Vec<_> = frames
        .iter()
        .map(|f| reference.process_frame(f).unwrap())
        .collect();
    let preferred = EngineBuffers::needed(&config).unwrap();
    assert_eq!(preferred.pool_entries, 7 * 148);
    for (pool, stride) in [
        (7 * 74, 74),
        (7 * 100 + 6, 100),
        (7 * 148, 148),
        (7 * 300, 148),
    ] {
        let mut buffers = EngineBuffers::with_capacity(MemorySize {
            pool_entries: pool,
            ..preferred
        });
        let mut engine = Engine::new(config, buffers.memory()).unwrap();
        assert_eq!(
            engine.memory_needed().pool_entries,
            7 * stride,
            "pool {pool}"
        );
        for (frame, want) in frames.iter().zip(&want) {
            let mut got = Vec::new();
            engine.push(frame, &mut |r| got.push(r)).unwrap();
            got.sort_by_key(|r| r.index);
            let got: Vec<_> = got
                .iter()
                .map(|g| (g.index as usize, g.slope_x, g.slope_y, g.flux, g.valid))
                .collect();
            let want: Vec<_> = want
                .iter()
                .map(|w| (w.index, w.slope_x, w.slope_y, w.flux, w.valid))
                .collect();
            assert_eq!(got, want, "pool {pool}");
        }
        if stride == 74 {
            assert!(engine.stats().compactions > 0, "{:?}", engine.stats());
        }
    }
}

/// Memory of the given sizes.
fn small_memory_result(config: Config<'_>, size: MemorySize) -> Result<(), ConfigError> {
    let mut buffers = EngineBuffers::with_capacity(size);
    Engine::new(config, buffers.memory()).map(|_| ())
}

#[test]
fn configurations_too_large_for_the_memory_are_refused_with_the_need() {
    let (camera, windows) = canary(16);
    let config = config(camera, &windows, SelectionRule::SubtractNext, 20);
    let enough = MemorySize {
        subapertures: 49,
        open_windows: 7,
        pool_entries: 7 * 74,
        history_pixels: 16 * 112,
        scratch_entries: 256,
    };
    let less = |change: fn(&mut MemorySize)| {
        let mut size = enough;
        change(&mut size);
        small_memory_result(config, size)
    };
    assert_eq!(small_memory_result(config, enough), Ok(()));
    assert_eq!(
        less(|s| s.subapertures = 48),
        Err(ConfigError::MemoryBudget {
            needed: 49,
            available: 48,
            what: MemoryKind::Subapertures
        })
    );
    assert_eq!(
        less(|s| s.open_windows = 6),
        Err(ConfigError::MemoryBudget {
            needed: 7,
            available: 6,
            what: MemoryKind::OpenWindows
        })
    );
    assert_eq!(
        less(|s| s.pool_entries = 7 * 74 - 1),
        Err(ConfigError::MemoryBudget {
            needed: 518,
            available: 517,
            what: MemoryKind::SelectionEntries
        })
    );
    assert_eq!(
        less(|s| s.history_pixels = 16 * 112 - 1),
        Err(ConfigError::MemoryBudget {
            needed: 1792,
            available: 1791,
            what: MemoryKind::RowHistory
        })
    );
    assert_eq!(
        less(|s| s.scratch_entries = 255),
        Err(ConfigError::MemoryBudget {
            needed: 256,
            available: 255,
            what: MemoryKind::ScratchEntries
        })
    );
    // Validation comes first: an invalid configuration is refused as such.
    let bad = Config {
        camera: Camera { width: 0, ..camera },
        ..config
    };
    assert_eq!(
        small_memory_result(bad, enough),
        Err(ConfigError::CameraSize {
            width: 0,
            height: 112
        })
    );
}

#[test]
fn invalid_configurations_get_specific_errors() {
    let camera = Camera {
        width: 32,
        height: 32,
        bit_depth: 12,
    };
    let window = SubapertureWindow {
        x: 0,
        y: 0,
        width: 16,
        height: 16,
    };
    let windows = [window];
    let good = config(camera, &windows, SelectionRule::SubtractNext, 20);
    assert_eq!(good.validate(), Ok(()));
    let outside = [SubapertureWindow { x: 20, ..window }];
    let empty = [SubapertureWindow { width: 0, ..window }];
    let huge = [SubapertureWindow {
        width: 65,
        height: 65,
        ..window
    }];
    let short_map = vec![0i32; 10];
    let wide_background = vec![(1 << 20) + 1; 32 * 32];
    let per = [0u16];
    let cases: Vec<(Config<'_>, ConfigError)> = vec![
        (
            config(camera, &windows, SelectionRule::SubtractNext, 0),
            ConfigError::PixelCountZeroAll,
        ),
        (
            Config {
                selection: Selection {
                    count: PixelCount::PerSubaperture(&per),
                    ..good.selection
                },
                ..good
            },
            ConfigError::PixelCountZero { index: 0 },
        ),
        (
            Config {
                selection: Selection {
                    count: PixelCount::PerSubaperture(&[]),
                    ..good.selection
                },
                ..good
            },
            ConfigError::PixelCountListLength {
                expected: 1,
                found: 0,
            },
        ),
        (
            Config {
                windows: &outside,
                ..good
            },
            ConfigError::WindowOutsideCamera { index: 0 },
        ),
        (
            Config {
                windows: &empty,
                ..good
            },
            ConfigError::EmptyWindow { index: 0 },
        ),
        (
            Config {
                windows: &huge,
                camera: Camera {
                    width: 100,
                    height: 100,
                    ..camera
                },
                ..good
            },
            ConfigError::WindowTooLarge {
                index: 0,
                width: 65,
                height: 65,
            },
        ),
        (
            Config {
                windows: &[],
                ..good
            },
            ConfigError::NoSubapertures,
        ),
        (
            Config {
                camera: Camera {
                    bit_depth: 17,
                    ..camera
                },
                ..good
            },
            ConfigError::BitDepth { bit_depth: 17 },
        ),
        (
            Config {
                calibration: Calibration {
                    background: Some(&short_map),
                    ..Calibration::default()
                },
                ..good
            },
            ConfigError::MapSize {
                map: brightpix_protocol::MapKind::Background,
                expected: 1024,
                found: 10,
            },
        ),
        (
            Config {
                calibration: Calibration {
                    background: Some(&wide_background),
                    ..Calibration::default()
                },
                ..good
            },
            ConfigError::BackgroundOutOfRange {
                pixel: 0,
                value: (1 << 20) + 1,
            },
        ),
        (
            Config {
                calibration: Calibration {
                    threshold: Some(1 << 26),
                    ..Calibration::default()
                },
                ..good
            },
            ConfigError::ThresholdOutOfRange { value: 1 << 26 },
        ),
        (
            Config {
                selection: Selection {
                    rule: SelectionRule::SubtractMean { count: 17 },
                    ..good.selection
                },
                ..good
            },
            ConfigError::MeanCount { count: 17 },
        ),
        (
            Config {
                selection: Selection {
                    rule: SelectionRule::Threshold,
                    level_filter: Some(brightpix_protocol::LevelFilter { gain_shift: 3 }),
                    ..good.selection
                },
                ..good
            },
            ConfigError::LevelFilterWithoutSubtraction,
        ),
        (
            Config {
                selection: Selection {
                    level_filter: Some(brightpix_protocol::LevelFilter { gain_shift: 0 }),
                    ..good.selection
                },
                ..good
            },
            ConfigError::LevelFilterGain { gain_shift: 0 },
        ),
        (
            Config {
                centroid: Centroid {
                    min_flux: -1,
                    ..Centroid::default()
                },
                ..good
            },
            ConfigError::NegativeMinFlux,
        ),
    ];
    for (config, error) in cases {
        assert_eq!(config.validate(), Err(error));
        assert_eq!(
            HostEngine::new(config).err(),
            Some(error),
            "the engine refuses it too"
        );
        assert!(
            Reference::new(&config).is_err(),
            "the reference refuses it too"
        );
        // Every refusal has a message for a person.
        assert!(!error.to_string().is_empty());
    }
}

/// The bounds SPEC.md §2 and §5 rely on, at their edges: raw 65535 with the
/// most negative background and the largest gain (|p| just under 2^25) on
/// 64-pixel-wide windows, every rule, with overflow checks on (test profile).
#[test]
fn extreme_values_at_the_arithmetic_bounds() {
    let camera = Camera {
        width: 128,
        height: 64,
        bit_depth: 16,
    };
    let windows = [
        SubapertureWindow {
            x: 0,
            y: 0,
            width: 64,
            height: 64,
        },
        SubapertureWindow {
            x: 64,
            y: 0,
            width: 64,
            height: 64,
        },
    ];
    let pixels = camera.pixel_count();
    // Left window: everything at the positive extreme; right: alternating
    // extremes of both signs.
    let background: Vec<i32> = (0..pixels)
        .map(|k| {
            if k % 128 < 64 || k % 2 == 0 {
                -(1 << 20)
            } else {
                1 << 20
            }
        })
        .collect();
    let gain = vec![u16::MAX; pixels];
    let frames: Vec<Vec<u16>> = vec![
        vec![u16::MAX; pixels],
        (0..pixels)
            .map(|k| if k % 3 == 0 { u16::MAX } else { 0 })
            .collect(),
        frame(camera, 5),
    ];
    for rule in [
        SelectionRule::Threshold,
        SelectionRule::SubtractNext,
        SelectionRule::SubtractNextDistinct,
        SelectionRule::SubtractMean { count: 16 },
    ] {
        for n in [1, 20, 4095, 4096] {
            let config = Config {
                calibration: Calibration {
                    background: Some(&background),
                    gain: Some(&gain),
                    threshold: None,
                },
                ..config(camera, &windows, rule, n)
            };
            assert_engine_matches_reference(config, &frames, 100);
        }
    }
}

/// SPEC.md §5's slope, written here from the spec: `clamp(floor((S 2^16 +
/// F) / 2F) - r)` with `S = 2 sum(w i) - (w - 1) F`.
fn spec_slope(sum_wi: i64, flux: i64, width: u16, reference: i32) -> i32 {
    let s = 2 * sum_wi as i128 - (width as i128 - 1) * flux as i128;
    let q = (s * (1 << 16) + flux as i128).div_euclid(2 * flux as i128);
    (q - reference as i128).clamp(i32::MIN as i128, i32::MAX as i128) as i32
}

/// The centroider's 32-bit path (flux below 2^22, coordinate sums below
/// 2^29, quotients below 2^14 pixels) and its 64-bit one, at and around
/// each bound, against the spec's arithmetic: fluxes of 1 and 2^22 - 1 ..
/// 2^22 + 1, sums at +-2^29 and quotients at +-2^14, references at the
/// ends of i32 (the saturation), every window size's extremes.
#[test]
fn slopes_at_the_bounds_of_the_32_bit_path() {
    use brightpix_firmware::engine::centroid::{Centroider, Moments};
    let references: Vec<[i32; 2]> = vec![[0, 0], [i32::MIN, i32::MAX], [-12345, 67890]];
    let fluxes = [
        1i64,
        2,
        3,
        255,
        256,
        257,
        (1 << 21) + 7,
        (1 << 22) - 1,
        1 << 22,
        (1 << 22) + 1,
        1 << 30,
        (1 << 38) - 1,
    ];
    let mut checked = 0usize;
    for (r, reference) in references.iter().enumerate() {
        let parameters = Centroid {
            reference_slopes: Some(&references),
            ..Centroid::default()
        };
        let centroider = Centroider::new(parameters);
        for &flux in &fluxes {
            for width in [1u16, 2, 16, 63, 64] {
                // Sums at the 32-bit path's bounds, at the quotient's
                // (|S / 2F| near 2^14), and at the window's own extremes.
                let centre = (width as i64 - 1) * flux / 2;
                let mut sums = vec![
                    0,
                    centre,
                    (width as i64 - 1) * flux,
                    (1 << 29) - 1,
                    1 << 29,
                    -(1 << 29),
                    -(1 << 29) - 1,
                    1 << 30,
                    (1 << 31) - 1,
                    -(1 << 31),
                    1 << 40,
                ];
                let powers = (10..21).flat_map(|k| [(1i64 << k) - 1, 1 << k]);
                for q in powers.flat_map(|q| [q, -q, -q - 1]) {
                    // S = 2 sum - (w - 1) F near q 2F.
                    let s = q * 2 * flux;
                    sums.push((s + (width as i64 - 1) * flux) / 2);
                    sums.push((s + (width as i64 - 1) * flux) / 2 + 1);
                }
                // Within SPEC.md §5's bounds: |sum(w i)| < 2^26 4096 64 = 2^44.
                sums.retain(|s: &i64| s.abs() < 1 << 44);
                for &sum_wi in &sums {
                    for &sum_wj in &[sums[1], sum_wi] {
                        let moments = Moments {
                            sum_w: flux,
                            sum_wi,
                            sum_wj,
                        };
                        let result = centroider.result(r as u16, moments, width, 64 - width + 1);
                        assert!(result.valid);
                        assert_eq!(
                            (result.slope_x, result.slope_y),
                            (
                                spec_slope(sum_wi, flux, width, reference[0]),
                                spec_slope(sum_wj, flux, 64 - width + 1, reference[1])
                            ),
                            "flux {flux}, sums {sum_wi} {sum_wj}, width {width}, reference {reference:?}"
                        );
                        checked += 1;
                    }
                }
            }
        }
    }
    // Random moments within the spec's bounds, fluxes spread over every
    // scale (log-uniform), so that remainders near the divisor occur at
    // each flux bound.
    let centroider = Centroider::new(Centroid::default());
    let mut next = xorshift(0x9e37_79b9_7f4a_7c15);
    for _ in 0..200_000 {
        let flux = ((next() >> 26) >> (next() % 38)).max(1) as i64;
        let width = (next() % 64 + 1) as u16;
        let spread = 1i64 << (next() % 45);
        let sum_wi = (next() % (2 * spread as u64)) as i64 - spread;
        let moments = Moments {
            sum_w: flux,
            sum_wi,
            sum_wj: sum_wi / 3,
        };
        let result = centroider.result(0, moments, width, width);
        assert_eq!(
            (result.slope_x, result.slope_y),
            (
                spec_slope(sum_wi, flux, width, 0),
                spec_slope(sum_wi / 3, flux, width, 0)
            ),
            "flux {flux}, sum {sum_wi}, width {width}"
        );
        checked += 1;
    }
    assert!(checked > 200_000);
}

/// `subtract-next-distinct` lowers a window's hint (one above the previous
/// level) to the level once its front holds N, and admits `p >= old hint`
/// from then on: the pre-filter's raw floor must be the old hint's. With a
/// background map of 0s and 1s (a sixteenth of a count apart) and the same
/// frame again, a level from a pixel of background 1 and a copy of the old
/// hint at background 0 are common: a floor one value higher (3ca79bd's
/// `Raise::LOWER` numbering, whose bit 1 asked for the floor above the
/// hint) dropped that copy, and the flux came out one short.
#[test]
fn lowered_hint_keeps_the_old_hints_copies() {
    let (camera, windows) = canary(12);
    let pixels = camera.pixel_count();
    let mut next = xorshift(12345);
    for _ in 0..40 {
        let background: Vec<i32> = (0..pixels).map(|_| (next() % 2) as i32).collect();
        // A spot in each window over a noisy floor, the frame repeated.
        let frame: Vec<u16> = (0..pixels)
            .map(|k| {
                let (x, y) = ((k % 112 % 16) as u64, (k / 112 % 16) as u64);
                let d = x.abs_diff(8).pow(2) + y.abs_diff(8).pow(2);
                (100 + 400 / (1 + d) + next() % 6) as u16
            })
            .collect();
        let frames = vec![frame.clone(), frame.clone(), frame];
        for n in [5u16, 10, 20] {
            let config = Config {
                calibration: Calibration {
                    background: Some(&background),
                    gain: None,
                    threshold: None,
                },
                ..config(camera, &windows, SelectionRule::SubtractNextDistinct, n)
            };
            assert_engine_matches_reference(config, &frames, 112 * 3);
        }
    }
}
