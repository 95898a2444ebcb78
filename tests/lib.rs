//! Shared helpers for the cross-crate tests: random configurations and
//! frames for the differential tests (engine against reference).

pub use brightpix::config_file::{PixelCounts, ProcessingConfig};
use brightpix_protocol::{Camera, LevelFilter, SelectionRule, SubapertureWindow};
use proptest::prelude::*;

/// Proptest cases a differential test runs: `PROPTEST_CASES` if set, else
/// `default`.
pub fn cases_or(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The differential tests' proptest configuration: `cases` cases, and a
/// failure shrunk for up to 2,000 steps (their cases are large).
pub fn differential_config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        max_shrink_iters: 2000,
        ..ProptestConfig::default()
    }
}

/// A random configuration: the host's owned configuration type.
pub type Case = ProcessingConfig;

/// Any of the four rules.
pub fn rule() -> impl Strategy<Value = SelectionRule> {
    prop_oneof![
        Just(SelectionRule::Threshold),
        Just(SelectionRule::SubtractNext),
        Just(SelectionRule::SubtractNextDistinct),
        (1u16..=16).prop_map(|count| SelectionRule::SubtractMean { count }),
    ]
}

fn window_in(width: u16, height: u16, max_side: u16) -> impl Strategy<Value = SubapertureWindow> {
    (1..=width.min(max_side), 1..=height.min(max_side)).prop_flat_map(move |(w, h)| {
        (0..=width - w, 0..=height - h).prop_map(move |(x, y)| SubapertureWindow {
            x,
            y,
            width: w,
            height: h,
        })
    })
}

/// Windows: a random list (may overlap) or a regular grid with skipped cells.
fn windows(width: u16, height: u16) -> impl Strategy<Value = Vec<SubapertureWindow>> {
    let random = prop::collection::vec(window_in(width, height, 20), 1..10);
    let grid = (1..=width.min(12), 1..=height.min(12)).prop_flat_map(move |(w, h)| {
        let columns = width / w;
        let rows = height / h;
        prop::collection::vec(any::<bool>(), (columns * rows) as usize).prop_map(move |keep| {
            let mut out: Vec<SubapertureWindow> = (0..rows)
                .flat_map(|r| {
                    (0..columns).map(move |c| SubapertureWindow {
                        x: c * w,
                        y: r * h,
                        width: w,
                        height: h,
                    })
                })
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(w, _)| w)
                .collect();
            if out.is_empty() {
                out.push(SubapertureWindow {
                    x: 0,
                    y: 0,
                    width: w,
                    height: h,
                });
            }
            out
        })
    });
    prop_oneof![random, grid]
}

/// How pixel values are drawn: heavy ties, small, full range, or saturated.
#[derive(Clone, Copy, Debug)]
pub enum PixelDistribution {
    Tiny(u16),
    Range(u16),
    Full,
    MostlySaturated,
}

pub fn pixel_distribution() -> impl Strategy<Value = PixelDistribution> {
    prop_oneof![
        (1u16..=4).prop_map(PixelDistribution::Tiny),
        (5u16..=300).prop_map(PixelDistribution::Range),
        Just(PixelDistribution::Full),
        Just(PixelDistribution::MostlySaturated),
    ]
}

/// Frames for `camera` drawn from `distribution`.
pub fn frames(
    camera: Camera,
    distribution: PixelDistribution,
    count: usize,
) -> impl Strategy<Value = Vec<Vec<u16>>> {
    let max = camera.max_raw();
    let pixel = match distribution {
        PixelDistribution::Tiny(k) => (0..=k.min(max)).boxed(),
        PixelDistribution::Range(k) => (0..=k.min(max)).boxed(),
        PixelDistribution::Full => (0..=max).boxed(),
        PixelDistribution::MostlySaturated => prop_oneof![3 => Just(max), 1 => 0..=max].boxed(),
    };
    prop::collection::vec(prop::collection::vec(pixel, camera.pixel_count()), count)
}

/// A full random case: configuration, frames and chunk lengths.
pub fn case() -> impl Strategy<Value = (Case, Vec<Vec<u16>>, Vec<usize>)> {
    (1u16..=40, 1u16..=40, 8u8..=16).prop_flat_map(|(width, height, bit_depth)| {
        let camera = Camera {
            width,
            height,
            bit_depth,
        };
        let pixels = camera.pixel_count();
        (
            windows(width, height),
            prop::option::of(prop_oneof![
                prop::collection::vec(-2000i32..=2000, pixels),
                prop::collection::vec(-(1i32 << 20)..=(1 << 20), pixels),
                // Within a few sixteenths of a count of each other: many
                // pixels at the window's least background, and values that
                // differ by one sixteenth, where a raw floor one value too
                // high drops a pixel (3ca79bd's `Raise::LOWER`).
                prop::collection::vec(-3i32..=3, pixels),
            ]),
            prop::option::of(prop_oneof![
                prop::collection::vec(3000u16..=5000, pixels),
                prop::collection::vec(0u16..=u16::MAX, pixels),
                // Within a few 1/4096 of unity: the raw floors' rounding
                // at the window's largest gain decides single pixels.
                prop::collection::vec(4094u16..=4098, pixels),
            ]),
            prop::option::of(-5000i32..=5000),
            rule(),
            prop::option::of((1u8..=16).prop_map(|gain_shift| LevelFilter { gain_shift })),
            any::<bool>(),
            prop_oneof![3 => Just(0i64), 1 => 0i64..100_000],
            pixel_distribution(),
            1usize..=3,
            // The same frame again: the seeds' hints then sit on this
            // frame's cutoffs and levels, as in a steady closed loop.
            any::<bool>(),
        )
            .prop_flat_map(
                move |(
                    windows,
                    background,
                    gain,
                    threshold,
                    rule,
                    level_filter,
                    per_subaperture,
                    min_flux,
                    distribution,
                    frame_count,
                    repeat,
                )| {
                    let count = windows.len();
                    let level_filter = level_filter.filter(|_| rule.subtracts());
                    let n = if per_subaperture {
                        prop::collection::vec(1u16..=50, count)
                            .prop_map(PixelCounts::PerSubaperture)
                            .boxed()
                    } else {
                        (1u16..=50).prop_map(PixelCounts::All).boxed()
                    };
                    let references = prop::option::of(prop::collection::vec(
                        [-(1i32 << 20)..=(1 << 20), -(1i32 << 20)..=(1 << 20)],
                        count,
                    ));
                    (
                        n,
                        references,
                        frames(camera, distribution, frame_count).prop_map(move |mut frames| {
                            if repeat {
                                let first = frames[0].clone();
                                frames.iter_mut().for_each(|f| f.clone_from(&first));
                            }
                            frames
                        }),
                        prop::collection::vec(1usize..=(2 * width as usize + 3), 1..8),
                    )
                        .prop_map(
                            move |(count, reference_slopes, frames, chunks)| {
                                (
                                    Case {
                                        camera,
                                        windows: windows.clone(),
                                        grid: None,
                                        background: background.clone(),
                                        gain: gain.clone(),
                                        threshold,
                                        rule,
                                        pixels: count,
                                        level_filter,
                                        reference_slopes,
                                        min_flux,
                                        crop: None,
                                    },
                                    frames,
                                    chunks,
                                )
                            },
                        )
                },
            )
    })
}

/// The engine on `frames`, pushed in pieces of `chunks`' lengths (cycled),
/// against the reference frame by frame, bit for bit: the first
/// difference as a proptest failure naming the frame and sub-aperture.
pub fn engine_matches_reference(
    case: &Case,
    frames: &[Vec<u16>],
    chunks: &[usize],
) -> Result<(), TestCaseError> {
    let config = case.view();
    let mut reference =
        brightpix::reference::Reference::new(&config).expect("generated configurations are valid");
    let mut engine = brightpix::engine_runner::HostEngine::new(config)
        .expect("generated configurations are valid");
    let mut chunk_lengths = chunks.iter().copied().cycle();
    let engine_frames = engine
        .process_chunked(frames.iter().map(Vec::as_slice), &mut chunk_lengths)
        .expect("generated frames are in range");
    prop_assert_eq!(engine_frames.len(), frames.len());
    for (f, (frame, engine_results)) in frames.iter().zip(&engine_frames).enumerate() {
        let expected = reference
            .process_frame(frame)
            .expect("generated frames are in range");
        prop_assert_eq!(expected.len(), engine_results.len());
        for (want, got) in expected.iter().zip(engine_results) {
            prop_assert_eq!(
                (
                    want.index,
                    want.slope_x,
                    want.slope_y,
                    want.flux,
                    want.valid
                ),
                (
                    got.index as usize,
                    got.slope_x,
                    got.slope_y,
                    got.flux,
                    got.valid
                ),
                "frame {} sub-aperture {} window {:?}",
                f,
                want.index,
                case.windows[want.index]
            );
        }
    }
    Ok(())
}

/// The engine itself on whole frames, results in emission order: what a
/// device or a camera source must reproduce.
pub fn direct(
    config: brightpix_protocol::Config<'_>,
    frames: &[Vec<u16>],
) -> Vec<Vec<brightpix_firmware::engine::SubapertureResult>> {
    let mut buffers = brightpix::engine_runner::EngineBuffers::for_config(&config);
    let mut engine = brightpix_firmware::engine::Engine::new(config, buffers.memory()).unwrap();
    frames
        .iter()
        .map(|f| {
            let mut out = Vec::new();
            engine.push(f, &mut |r| out.push(r)).unwrap();
            out
        })
        .collect()
}

/// A device link in memory: what the host sends is queued for the device's
/// reads, what the device writes is collected for the test.
pub mod memory_link {
    use brightpix_firmware::device::embedded_io_async::{ErrorType, Read, Write};
    use std::cell::RefCell;
    use std::collections::VecDeque;
    use std::convert::Infallible;
    use std::rc::Rc;
    use std::task::Poll;

    #[derive(Default)]
    pub struct LinkState {
        pub input: VecDeque<u8>,
        pub output: Vec<u8>,
        /// When the input is empty: end of stream (read returns 0) or wait.
        pub closed: bool,
        /// Largest read (at least 1), to exercise frames split across reads.
        pub max_read: usize,
    }

    /// The device's end of the link.
    #[derive(Clone)]
    pub struct MemoryLink(pub Rc<RefCell<LinkState>>);

    impl ErrorType for MemoryLink {
        type Error = Infallible;
    }

    impl Read for MemoryLink {
        async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
            std::future::poll_fn(|_| {
                let mut s = self.0.borrow_mut();
                if !s.input.is_empty() {
                    let n = buf.len().min(s.input.len()).min(s.max_read.max(1));
                    for b in &mut buf[..n] {
                        *b = s.input.pop_front().unwrap();
                    }
                    Poll::Ready(Ok(n))
                } else if s.closed {
                    Poll::Ready(Ok(0))
                } else {
                    Poll::Pending
                }
            })
            .await
        }
    }

    impl Write for MemoryLink {
        async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
            self.0.borrow_mut().output.extend_from_slice(buf);
            Ok(buf.len())
        }
        async fn flush(&mut self) -> Result<(), Infallible> {
            Ok(())
        }
    }
}
