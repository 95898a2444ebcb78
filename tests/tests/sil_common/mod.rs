//! The simulation-in-loop cases shared by `sil_pty.rs` (the firmware's
//! device loop in-process) and `sil_qemu.rs` (the firmware ELF in QEMU):
//! configurations and frames, and the checks every case must pass.

#![allow(dead_code)]

use std::time::{Duration, Instant};

use brightpix::config_file::{PixelCounts, ProcessingConfig};
use brightpix::link::verify::Verifier;
use brightpix::link::{pixel_rows_frames, Client, FrameOutcome, LinkError};
use brightpix::sil::{canary_config, canary_frames, stream_and_verify, tiled_frames};
use brightpix::simulator::{SimulationParams, Simulator};
use brightpix_protocol::wire::{
    DeviceError, EngineCounters, FrameFault, HostMessage, UploadPlan, MAX_CHUNK_BYTES,
};
use brightpix_protocol::{Camera, LevelFilter, SelectionRule, SubapertureWindow};

/// Frames per case (the issue asks for at least 100).
pub const FRAMES: usize = 100;

/// A configuration and the frames streamed with it.
pub struct Case {
    pub name: &'static str,
    pub config: ProcessingConfig,
    pub frames: Vec<Vec<u16>>,
}

/// splitmix64: deterministic, dependency-free.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed ^ 0x5DEE_CE66_D1CE_4E5B)
    }
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `0..=max`.
    pub fn upto(&mut self, max: u32) -> u32 {
        (self.next() % (max as u64 + 1)) as u32
    }
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The small camera of the edge cases: 40x24 pixels; a 4x2 grid of 8x8
/// windows with gaps between them, a window overlapping two of them, an odd
/// 5x7 one and a 40x2 strip along the bottom (10 windows).
pub fn small_config(bit_depth: u8) -> ProcessingConfig {
    let mut windows = Vec::new();
    for r in 0..2u16 {
        for c in 0..4u16 {
            windows.push(SubapertureWindow {
                x: 1 + 9 * c,
                y: 2 + 10 * r,
                width: 8,
                height: 8,
            });
        }
    }
    windows.push(SubapertureWindow {
        x: 5,
        y: 4,
        width: 10,
        height: 6,
    });
    windows.push(SubapertureWindow {
        x: 34,
        y: 13,
        width: 5,
        height: 7,
    });
    windows.push(SubapertureWindow {
        x: 0,
        y: 22,
        width: 40,
        height: 2,
    });
    ProcessingConfig::new(
        Camera {
            width: 40,
            height: 24,
            bit_depth,
        },
        windows,
    )
}

/// `count` frames of `camera`, pixel by pixel from `pixel(rng, frame, x, y)`
/// clamped to the camera's range.
pub fn frames_of(
    camera: Camera,
    count: usize,
    seed: u64,
    mut pixel: impl FnMut(&mut Rng, usize, usize, usize) -> i64,
) -> Vec<Vec<u16>> {
    let mut rng = Rng::new(seed);
    let max = camera.max_raw() as i64;
    (0..count)
        .map(|f| {
            let mut frame = Vec::with_capacity(camera.pixel_count());
            for y in 0..camera.height as usize {
                for x in 0..camera.width as usize {
                    frame.push(pixel(&mut rng, f, x, y).clamp(0, max) as u16);
                }
            }
            frame
        })
        .collect()
}

/// Gaussian spots (one per 8x8 cell, centre moving per frame) of `peak`
/// counts over `background` with uniform noise of `noise` counts.
pub fn spot_frames(
    camera: Camera,
    count: usize,
    seed: u64,
    peak: f64,
    background: i64,
    noise: u32,
) -> Vec<Vec<u16>> {
    let mut centres = Rng::new(seed ^ 0xABCD);
    let per_frame: Vec<Vec<(f64, f64)>> = (0..count)
        .map(|_| {
            (0..(camera.width as usize / 9 + 1) * (camera.height as usize / 10 + 1))
                .map(|_| (1.5 + 5.0 * centres.unit(), 1.5 + 5.0 * centres.unit()))
                .collect()
        })
        .collect();
    let columns = camera.width as usize / 9 + 1;
    frames_of(camera, count, seed, |rng, f, x, y| {
        let (cx, cy) = (x / 9, y / 10);
        let (sx, sy) = per_frame[f][cy * columns + cx];
        let (dx, dy) = ((x % 9) as f64 - sx, (y % 10) as f64 - sy);
        let spot = peak * (-(dx * dx + dy * dy) / 3.0).exp();
        background + spot.round() as i64 + rng.upto(noise) as i64
    })
}

/// Every case: the paper's default NGS spots (CANARY), elongated Rayleigh
/// LGS spots (CANARY, 1000 m gate), the edge cases on the small camera,
/// and windows the row kernel cannot take.
pub fn all_cases() -> Vec<Case> {
    let mut cases = vec![canary_case(), rayleigh_case()];
    cases.extend(edge_cases());
    cases.push(odd_windows_case());
    cases
}

/// 16-bit pixels on a 40x21 camera in three rows of 7x7 windows that
/// cover every camera row: no window is whole 32-bit words (odd width), so
/// the engine's row kernel never takes one (`OpenWindow::kernel_ready`)
/// and, with a window open in every row, is never called (a row with no
/// window open goes to the kernel, which then takes no pixel).
pub fn odd_windows_case() -> Case {
    let mut windows = Vec::new();
    for r in 0..3u16 {
        for c in 0..4u16 {
            windows.push(SubapertureWindow {
                x: 1 + 9 * c,
                y: 7 * r,
                width: 7,
                height: 7,
            });
        }
    }
    let config = ProcessingConfig {
        pixels: PixelCounts::All(8),
        ..ProcessingConfig::new(
            Camera {
                width: 40,
                height: 21,
                bit_depth: 16,
            },
            windows,
        )
    };
    let frames = spot_frames(config.camera, FRAMES, 30, 8000.0, 300, 200);
    Case {
        name: "row kernel cannot run: 16-bit, every window 7 pixels wide",
        config,
        frames,
    }
}

/// Whether the engine's row kernel must run in `case`'s frames: 16-bit
/// pixels (no bit-depth check keeps whole rows off the kernel), an even
/// camera width (every row word-aligned when the device's pixel buffer is
/// and messages start at even pixels, as the host's do) and a selecting
/// window of whole words (even first column and width). `Some(false)`:
/// it cannot (no window of whole words, and a window open in every camera
/// row: a row without one still calls the kernel, which takes no pixel
/// there), `None`: it depends on the pixels.
pub fn kernel_expected(case: &Case) -> Option<bool> {
    let c = &case.config;
    let n = |k: usize| match &c.pixels {
        PixelCounts::All(n) => *n,
        PixelCounts::PerSubaperture(v) => v[k],
    };
    let words = |w: &SubapertureWindow| (w.x | w.width) & 1 == 0;
    let every_row_has_a_window =
        (0..c.camera.height).all(|y| c.windows.iter().any(|w| (w.y..w.y + w.height).contains(&y)));
    if !c.windows.iter().any(words) {
        return every_row_has_a_window.then_some(false);
    }
    let selects = c
        .windows
        .iter()
        .enumerate()
        .any(|(k, w)| words(w) && u32::from(n(k)) < u32::from(w.width) * u32::from(w.height));
    if c.camera.bit_depth == 16 && c.camera.width.is_multiple_of(2) && selects {
        Some(true)
    } else {
        None
    }
}

/// Requires the device's engine counters over a case (`Status.engine`,
/// after minus before) to show the row kernel where it must run and not
/// where it cannot ([`kernel_expected`]).
pub fn check_kernel(case: &Case, engine: &EngineCounters, frames: u64) {
    match kernel_expected(case) {
        // Not necessarily in every frame: the first after the
        // configuration has no seeds (its windows open on the general
        // path), and a window may leave the kernel for a frame (a rescan,
        // a full buffer). A pixel buffer that is not word-aligned keeps it
        // out of every frame.
        Some(true) => assert!(
            engine.kernel_frames > 0 && engine.kernel_frames <= frames,
            "{}: the row kernel must run (is the device's pixel buffer word-aligned?): {engine:?}",
            case.name
        ),
        Some(false) => assert_eq!(
            engine.kernel_frames, 0,
            "{}: the row kernel cannot take these windows: {engine:?}",
            case.name
        ),
        None => {}
    }
}

pub fn canary_case() -> Case {
    Case {
        name: "canary NGS spots (the paper's default)",
        config: canary_config(),
        frames: canary_frames(FRAMES, 11),
    }
}

pub fn rayleigh_case() -> Case {
    let config = canary_config();
    let sim = Simulator::new(SimulationParams::canary_rayleigh(1000.0)).unwrap();
    Case {
        name: "canary Rayleigh LGS elongated spots (1000 m gate)",
        frames: tiled_frames(&sim, config.camera, 7, 7, FRAMES, 12),
        config,
    }
}

/// Name, rule, N, threshold (1/16 count), level filter gain shift.
type RuleCase = (&'static str, SelectionRule, u16, Option<i32>, Option<u8>);

pub fn edge_cases() -> Vec<Case> {
    let mut cases = Vec::new();

    // Ties: a 2-bit camera, every pixel 0..=3: almost every selection ends
    // in a tie.
    let config = ProcessingConfig {
        pixels: PixelCounts::All(5),
        ..small_config(2)
    };
    let frames = frames_of(config.camera, FRAMES, 1, |rng, _, _, _| rng.upto(3) as i64);
    cases.push(Case {
        name: "ties: 2-bit pixels, subtract-next N=5",
        config,
        frames,
    });

    // Ties with few distinct values, DARC's rule.
    let config = ProcessingConfig {
        rule: SelectionRule::SubtractNextDistinct,
        pixels: PixelCounts::All(3),
        ..small_config(4)
    };
    let frames = frames_of(config.camera, FRAMES, 2, |rng, _, _, _| {
        if rng.upto(40) == 0 {
            15
        } else {
            rng.upto(2) as i64
        }
    });
    cases.push(Case {
        name: "ties: 4-bit pixels, subtract-next-distinct N=3",
        config,
        frames,
    });

    // Saturation: spots far above an 8-bit camera's range, with background
    // and gain maps and reference slopes.
    let mut rng = Rng::new(3);
    let base = small_config(8);
    let pixels = base.camera.pixel_count();
    let config = ProcessingConfig {
        background: Some((0..pixels).map(|_| rng.upto(40 * 16) as i32).collect()),
        gain: Some((0..pixels).map(|_| 3000 + rng.upto(2000) as u16).collect()),
        reference_slopes: Some(
            (0..base.windows.len())
                .map(|_| {
                    [
                        rng.upto(1 << 17) as i32 - (1 << 16),
                        rng.upto(1 << 17) as i32 - (1 << 16),
                    ]
                })
                .collect(),
        ),
        pixels: PixelCounts::All(10),
        ..base
    };
    let frames = spot_frames(config.camera, FRAMES, 4, 900.0, 20, 30);
    cases.push(Case {
        name: "saturation: 8-bit camera, spots clipped at 255, background and gain maps, reference slopes",
        config,
        frames,
    });

    // Empty sub-apertures: alternate windows dark (all zero) or flat (one
    // value everywhere), the others spots; a background above the dark
    // level and a minimum flux.
    let config = ProcessingConfig {
        background: Some(vec![5 * 16; small_config(12).camera.pixel_count()]),
        min_flux: 16,
        pixels: PixelCounts::All(20),
        ..small_config(12)
    };
    let spots = spot_frames(config.camera, FRAMES, 5, 2000.0, 10, 8);
    let frames = spots
        .into_iter()
        .enumerate()
        .map(|(f, mut frame)| {
            for (i, p) in frame.iter_mut().enumerate() {
                let (x, y) = (i % 40, i / 40);
                match (x / 9 + y / 10 + f) % 3 {
                    0 => *p = 0,
                    1 => *p = 7,
                    _ => {}
                }
            }
            frame
        })
        .collect();
    cases.push(Case {
        name: "empty sub-apertures: dark and flat windows, background above them, minimum flux",
        config,
        frames,
    });

    // Per-sub-aperture N, from 1 to more than a window's pixels.
    let config = ProcessingConfig {
        pixels: PixelCounts::PerSubaperture(vec![1, 2, 5, 63, 64, 100, 20, 7, 3, 80, 9]),
        ..small_config(16)
    };
    let frames = spot_frames(config.camera, FRAMES, 6, 20000.0, 300, 200);
    cases.push(Case {
        name: "per-sub-aperture N: 1, 2, 5, 63, 64, 100, 20, 7, 3, 80, 9",
        config,
        frames,
    });

    // Each rule, and the level filter with each subtracting rule.
    let rules: [RuleCase; 7] = [
        (
            "rule threshold (T = 200 counts)",
            SelectionRule::Threshold,
            0,
            Some(200 * 16),
            None,
        ),
        (
            "rule subtract-next N=12",
            SelectionRule::SubtractNext,
            12,
            None,
            None,
        ),
        (
            "rule subtract-next-distinct N=6",
            SelectionRule::SubtractNextDistinct,
            6,
            None,
            None,
        ),
        (
            "rule subtract-mean M=4 N=8",
            SelectionRule::SubtractMean { count: 4 },
            8,
            None,
            None,
        ),
        (
            "level filter: subtract-next N=6, gain 2^-3",
            SelectionRule::SubtractNext,
            6,
            None,
            Some(3),
        ),
        (
            "level filter: subtract-mean M=16 N=10, gain 2^-1",
            SelectionRule::SubtractMean { count: 16 },
            10,
            None,
            Some(1),
        ),
        (
            "level filter: subtract-next-distinct N=4, gain 2^-16",
            SelectionRule::SubtractNextDistinct,
            4,
            Some(-3 * 16),
            Some(16),
        ),
    ];
    for (k, (name, rule, n, threshold, gain_shift)) in rules.into_iter().enumerate() {
        let config = ProcessingConfig {
            rule,
            pixels: PixelCounts::All(n.max(1)),
            threshold,
            level_filter: gain_shift.map(|gain_shift| LevelFilter { gain_shift }),
            ..small_config(16)
        };
        let frames = spot_frames(config.camera, FRAMES, 10 + k as u64, 5000.0, 200, 300);
        cases.push(Case {
            name,
            config,
            frames,
        });
    }
    cases
}

/// What [`run_case`] measured.
pub struct CaseRun {
    /// The stream's duration.
    pub stream: Duration,
    /// The device's engine counters over the case (after minus before).
    pub engine: EngineCounters,
}

/// Configures the device for `case`, streams its frames, and requires every
/// result to equal the reference's, and the device's engine counters to
/// show its row kernel where it must run and not where it cannot
/// ([`check_kernel`]).
pub fn run_case(client: &mut Client, case: &Case) -> CaseRun {
    let view = case.config.view();
    view.validate()
        .unwrap_or_else(|e| panic!("{}: invalid test configuration: {e}", case.name));
    let configured = client
        .configure(&view)
        .unwrap_or_else(|e| panic!("{}: configure: {e}", case.name));
    let before = client.status().unwrap();
    assert_eq!(
        before.config_id,
        Some(configured.config_id),
        "{}",
        case.name
    );
    let run = stream_and_verify(client, &view, &case.frames, 0, 5);
    if let Some(e) = &run.error {
        panic!("{}: streaming failed: {e}", case.name);
    }
    let v = &run.verifier;
    assert!(
        v.all_match() && v.frames_verified as usize == case.frames.len(),
        "{}: {} of {} frames verified, {} mismatches, first: {:#?}",
        case.name,
        v.frames_verified,
        case.frames.len(),
        v.mismatch_count,
        v.mismatches
    );
    let after = client.status().unwrap();
    assert_eq!(
        after.frames_processed - before.frames_processed,
        case.frames.len() as u64,
        "{}",
        case.name
    );
    assert_eq!(after.frames_dropped, before.frames_dropped, "{}", case.name);
    let (a, b) = (after.engine, before.engine);
    let engine = EngineCounters {
        windows: a.windows - b.windows,
        candidates: a.candidates - b.candidates,
        compactions: a.compactions - b.compactions,
        rescans: a.rescans - b.rescans,
        attentions: a.attentions - b.attentions,
        kernel_frames: a.kernel_frames - b.kernel_frames,
    };
    // Windows with selection only (none where N covers a whole window).
    assert!(
        engine.windows <= (case.frames.len() * case.config.windows.len()) as u64,
        "{}: {engine:?}",
        case.name
    );
    check_kernel(case, &engine, case.frames.len() as u64);
    CaseRun {
        stream: run.report.elapsed,
        engine,
    }
}

/// Flips one bit of the `nth` data byte of a COBS frame (not a code byte,
/// not the delimiter), so that the frame still cuts and un-stuffs but its
/// CRC no longer matches.
pub fn corrupt(frame: &mut [u8], nth: usize) {
    let mut data = Vec::new();
    let mut i = 0;
    while i < frame.len() && frame[i] != 0 {
        let code = frame[i] as usize;
        data.extend(i + 1..(i + code).min(frame.len() - 1));
        i += code;
    }
    let at = data[nth.min(data.len() - 1)];
    frame[at] ^= if frame[at] == 1 { 0x02 } else { 0x01 };
    assert_ne!(frame[at], 0);
}

/// A configuration upload that fails half-way leaves the old configuration
/// in force: (1) the link is cut after some chunks (the client is dropped
/// and a new one connects), (2) a chunk arrives corrupted. Streaming after
/// each proves the old configuration still runs. `connect` opens a new
/// client on the same device.
pub fn failed_uploads_keep_old_config(connect: &mut dyn FnMut() -> Client, old: &Case) {
    let view = old.config.view();
    let mut client = connect();
    let applied = client.configure(&view).unwrap().config_id;
    let half = old.frames.len() / 2;

    // A different configuration, whose results would differ.
    let new = ProcessingConfig {
        rule: SelectionRule::Threshold,
        threshold: Some(100 * 16),
        ..old.config.clone()
    };

    // (1) Cut after ConfigBegin and two chunks.
    let mut plan = UploadPlan::new(new.view(), 0x0BAD_0001, MAX_CHUNK_BYTES);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    for _ in 0..3 {
        let message = plan.next(&mut scratch).unwrap();
        assert!(
            !matches!(message, HostMessage::ConfigCommit { .. }),
            "the configuration needs more chunks"
        );
        client.request(&message).unwrap();
    }
    drop(client); // the link is cut
    let mut client = connect();
    let status = client.status().unwrap();
    assert_eq!(
        status.config_id,
        Some(applied),
        "the old configuration must stay active"
    );
    assert_eq!(
        status.upload_id, None,
        "the new session discarded the dead client's upload"
    );
    client.assume_configured(&view);
    let run = stream_and_verify(&mut client, &view, &old.frames[..half], 0, 5);
    assert!(
        run.error.is_none() && run.verifier.all_match(),
        "after a cut upload: {:?} {:?}",
        run.error,
        run.verifier.mismatches
    );
    assert_eq!(run.verifier.frames_verified as usize, half);

    // (2) A corrupted chunk: the device drops it (Crc), the next chunk is
    // out of order (the upload is discarded), the commit finds no upload.
    let mut plan = UploadPlan::new(new.view(), 0x0BAD_0002, MAX_CHUNK_BYTES);
    let mut errors = Vec::new();
    let mut k = 0;
    while let Some(message) = plan.next(&mut scratch) {
        let kind = message.kind();
        let mut frame = client.encode(&message).unwrap().to_vec();
        if k == 2 {
            corrupt(&mut frame, 5);
        }
        k += 1;
        match client.request_raw(&frame, kind) {
            Ok(_) => {}
            Err(LinkError::Device { error, .. }) => errors.push(error),
            Err(e) => panic!("corrupted chunk: {e}"),
        }
    }
    assert_eq!(errors.first(), Some(&DeviceError::Crc), "{errors:?}");
    assert!(
        errors
            .iter()
            .any(|e| matches!(e, DeviceError::ChunkOutOfOrder { .. })),
        "{errors:?}"
    );
    assert_eq!(errors.last(), Some(&DeviceError::NoUpload), "{errors:?}");
    let status = client.status().unwrap();
    assert_eq!(status.config_id, Some(applied));
    assert_eq!(status.upload_id, None);
    // The level filters (if any) run on: continue the same frame sequence.
    let mut verifier = Verifier::new(&view, 5).unwrap();
    let mut outcomes = Vec::new();
    client
        .stream_frames(0, &old.frames, |o| outcomes.push(o))
        .unwrap();
    brightpix::sil::verify_outcomes(&mut verifier, &old.frames, 0, &outcomes);
    // Frames 0..half were streamed above on the same configuration; with a
    // level filter the state would carry over, so the cases used here have none.
    assert!(old.config.level_filter.is_none());
    assert!(
        verifier.all_match(),
        "after a corrupted chunk: {:?}",
        verifier.mismatches
    );
    assert_eq!(verifier.frames_verified as usize, old.frames.len());
}

/// Issue 10, fault 1: a client killed in the middle of a frame (its last
/// message cut off) must not make the next client's verification pass with
/// a frame missing. The next client configures and streams three frames:
/// all three are verified, and nothing of the dead client's counts.
pub fn dead_client_leaves_nothing_behind(connect: &mut dyn FnMut() -> Client, case: &Case) {
    let view = case.config.view();
    let mut client = connect();
    client.configure(&view).unwrap();
    // Frame 57 up to the middle of one of its messages, then the client dies.
    let bytes = brightpix::link::encode_pixel_rows(57, &case.frames[0]);
    client.send_raw(&bytes[..bytes.len() / 2 + 3]).unwrap();
    drop(client);

    let mut client = connect();
    client.configure(&view).unwrap();
    let run = stream_and_verify(&mut client, &view, &case.frames[1..4], 0, 5);
    assert!(run.error.is_none(), "{:?}", run.error);
    assert_eq!(
        (run.verifier.frames_verified, run.verifier.frames_failed),
        (3, 0),
        "every frame requested verified: {:?}",
        run.verifier.mismatches
    );
    assert_eq!(run.report.frames_done, 3);
    assert_eq!(run.outcomes.len(), 3, "{:?}", run.outcomes);
    let status = client.status().unwrap();
    assert_eq!(status.session, Some(client.session()));
    assert!(
        status.frames_dropped >= 1,
        "frame 57 was dropped: {status:?}"
    );
}

/// A `PixelRows` frame with a flipped byte is counted (`crc_errors`) and
/// rejected (its frame is dropped with a gap), and the next frames verify.
pub fn corrupted_pixel_frame_is_rejected(client: &mut Client, case: &Case) {
    assert!(case.config.level_filter.is_none());
    let view = case.config.view();
    client.configure(&view).unwrap();
    let before = client.status().unwrap();
    let mut verifier = Verifier::new(&view, 5).unwrap();

    // Frames 0..10 verify.
    let mut outcomes = Vec::new();
    client
        .stream_frames(0, &case.frames[..10], |o| outcomes.push(o))
        .unwrap();
    brightpix::sil::verify_outcomes(&mut verifier, &case.frames[..10], 0, &outcomes);
    assert!(verifier.all_match());

    // Frame 10 with one damaged message in the middle.
    let mut messages = pixel_rows_frames(10, &case.frames[10]);
    assert!(messages.len() >= 2);
    // Not the last message: a later one of the same frame reveals the gap.
    let middle = (messages.len() - 1) / 2;
    corrupt(&mut messages[middle], 7);
    let bytes: Vec<u8> = messages.concat();
    client.send_raw(&bytes).unwrap();
    let outcome = client.next_outcome().unwrap();
    match &outcome {
        FrameOutcome::Dropped {
            slopes,
            fault: FrameFault::Gap { .. },
        } => assert_eq!(slopes.frame, 10),
        other => panic!("expected frame 10 dropped with a gap, got {other:?}"),
    }
    verifier.check(&case.frames[10], &outcome); // counted as dropped, reference not advanced
    let status = client.status().unwrap();
    assert_eq!(status.crc_errors, before.crc_errors + 1);
    assert_eq!(status.overruns, before.overruns + 1);
    // Frame 10 never completed. (`frames_dropped` counts it only if the
    // device had started it, i.e. the damaged message was not its first.)
    assert_eq!(status.frames_processed, before.frames_processed + 10);
    assert_eq!(
        status.frames_dropped,
        before.frames_dropped + u64::from(middle > 0)
    );
    assert!(
        client.notices.contains(&DeviceError::Crc),
        "{:?}",
        client.notices
    );

    // The next frames verify.
    let mut outcomes = Vec::new();
    client
        .stream_frames(11, &case.frames[11..], |o| outcomes.push(o))
        .unwrap();
    let mut rest = Verifier::new(&view, 5).unwrap();
    // The reference has seen frames 0..10 only (no level filter: no state).
    brightpix::sil::verify_outcomes(&mut rest, &case.frames[11..], 11, &outcomes);
    assert!(rest.all_match(), "{:?}", rest.mismatches);
    assert_eq!(rest.frames_verified as usize, case.frames.len() - 11);
}

/// Times a closure, for the report.
pub fn timed<T>(name: &str, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let v = f();
    eprintln!("  {name}: {:.2} s", t.elapsed().as_secs_f64());
    v
}
