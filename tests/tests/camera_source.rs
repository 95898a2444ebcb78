//! The firmware's DCMI camera source (`brightpix_firmware::camera`) against
//! a simulated circular DMA, camera and D-cache (`camera_sim`): row assembly
//! from the words the DMA writes, frame tracking, overruns, cache
//! maintenance.

mod camera_sim;

use brightpix_firmware::camera::packing::{as_pixels, pack, unpack};
use brightpix_firmware::camera::{
    CameraStats, DataWidth, DcmiSource, DmaProgress, DmaRing, FrameMarks, Mark, MARK_SLOTS,
};
use brightpix_firmware::device::{CameraRefused, PixelSource};
use brightpix_protocol::Camera;
use camera_sim::*;

const WIDTHS: [DataWidth; 4] = [
    DataWidth::Bits8,
    DataWidth::Bits10,
    DataWidth::Bits12,
    DataWidth::Bits14,
];

fn camera(width: u16, height: u16, data: DataWidth) -> Camera {
    Camera {
        width,
        height,
        bit_depth: data.bits(),
    }
}

/// Run buffers sized for `words` words per run.
fn buffers(words: usize) -> (Vec<u32>, Vec<u16>) {
    (vec![0; words], vec![0; words * 4])
}

// --- packing, positions, marks ------------------------------------------------

#[test]
fn pixels_are_packed_first_in_the_low_bits() {
    let mut out = [0u16; 8];
    // 8-bit: four pixels per word, first in bits 7:0.
    assert_eq!(
        unpack(DataWidth::Bits8, &[0x4433_2211, 0x0807_0605], &mut out),
        8
    );
    assert_eq!(out, [0x11, 0x22, 0x33, 0x44, 0x05, 0x06, 0x07, 0x08]);
    // Extended modes: one pixel per halfword, taken whole (not masked).
    for width in [
        DataWidth::Bits10,
        DataWidth::Bits12,
        DataWidth::Bits14,
        DataWidth::Bits16,
    ] {
        let mut out = [0u16; 4];
        assert_eq!(unpack(width, &[0x0ABC_0123, 0xFFFF_0001], &mut out), 4);
        assert_eq!(out, [0x0123, 0x0ABC, 0x0001, 0xFFFF]);
        // Read in place, the same pixels.
        assert_eq!(
            as_pixels(width, &[0x0ABC_0123, 0xFFFF_0001]),
            Some(&[0x0123, 0x0ABC, 0x0001, 0xFFFF][..])
        );
    }
    // Four to a word: unpacked, never read in place.
    assert_eq!(as_pixels(DataWidth::Bits8, &[0x4433_2211]), None);
    let mut rng = Rng::new(1);
    for width in WIDTHS {
        let pixels: Vec<u16> = (0..64)
            .map(|_| (rng.next() & ((1 << width.bits()) - 1)) as u16)
            .collect();
        let mut words = vec![0; 64 / width.pixels_per_word()];
        assert_eq!(pack(width, &pixels, &mut words), words.len());
        let mut back = vec![0; 64];
        assert_eq!(unpack(width, &words, &mut back), 64);
        assert_eq!(back, pixels);
        if let Some(in_place) = as_pixels(width, &words) {
            assert_eq!(in_place, &pixels[..]);
        }
    }
    assert_eq!(DataWidth::Bits8.edm(), Some(0));
    assert_eq!(DataWidth::Bits14.edm(), Some(3));
    assert_eq!(DataWidth::Bits16.edm(), None);
}

#[test]
fn positions_follow_the_half_events_even_one_event_late() {
    let len = 8;
    let at = |half_events, write_index| {
        DmaProgress {
            half_events,
            write_index,
        }
        .position(len)
    };
    assert_eq!(at(0, 0), 0);
    assert_eq!(at(0, 3), 3);
    assert_eq!(at(1, 4), 4);
    assert_eq!(at(1, 6), 6);
    assert_eq!(at(2, 0), 8);
    assert_eq!(at(3, 5), 13);
    // The event at word 4 happened but is not counted yet.
    assert_eq!(at(0, 5), 5);
    // The wrap (event 2) happened, not counted: the index is back at 0..4.
    assert_eq!(at(1, 0), 8);
    assert_eq!(at(1, 2), 10);
    // Positions wrap at 2^32.
    let start = 0u32.wrapping_sub(4); // even
    assert_eq!(at(start, 0), 0u32.wrapping_sub(16));
    assert_eq!(at(start.wrapping_add(4), 1), 1);
    // The exhaustive version: every position with 0 or 1 event uncounted.
    for len in [16usize, 48, 1024] {
        let half = len as u64 / 2;
        for true_position in 0..4 * len as u64 {
            let events = true_position / half;
            for counted in events.saturating_sub(1)..=events {
                let p = DmaProgress {
                    half_events: counted as u32,
                    write_index: (true_position % len as u64) as u32,
                };
                assert_eq!(p.position(len) as u64, true_position);
            }
        }
    }
}

#[test]
fn consistent_readings_retry_when_an_event_is_counted_in_between() {
    let calls = std::cell::Cell::new(0);
    let p = DmaProgress::read(
        || {
            calls.set(calls.get() + 1);
            // The count changes between the first and second reading.
            if calls.get() == 1 {
                3
            } else {
                4
            }
        },
        || 2,
    );
    assert_eq!(
        p,
        DmaProgress {
            half_events: 4,
            write_index: 2
        }
    );
}

#[test]
fn frame_marks_keep_the_newest_frames() {
    let marks = FrameMarks::new();
    assert_eq!(marks.get(0), Mark::Pending);
    let total = MARK_SLOTS as u32 + 5;
    for k in 0..total {
        marks.record(DmaProgress {
            half_events: k,
            write_index: 100 + k,
        });
    }
    assert_eq!(marks.ended(), total);
    for k in 0..5 {
        assert_eq!(marks.get(k), Mark::Lost, "frame {k}");
    }
    for k in 5..total {
        assert_eq!(
            marks.get(k),
            Mark::At(DmaProgress {
                half_events: k,
                write_index: 100 + k
            })
        );
    }
    assert_eq!(marks.get(total), Mark::Pending);
    assert_eq!(marks.get(total + 7), Mark::Pending);
    marks.reset();
    assert_eq!(marks.ended(), 0);
    for k in 0..total {
        assert_eq!(marks.get(k), Mark::Pending);
    }
    marks.record(DmaProgress {
        half_events: 0,
        write_index: 9,
    });
    assert!(matches!(marks.get(0), Mark::At(_)));
}

// --- delivery -------------------------------------------------------------------

struct Scenario {
    data: DataWidth,
    width: u16,
    height: u16,
    ring: usize,
    run_words: usize,
    frames: u32,
    behaviour: Behaviour,
    seed: u64,
}

struct Outcome {
    runs: Vec<Run>,
    stats: CameraStats,
    assembler: Assembler,
    sim: SimRing,
}

/// The camera sends `frames` frames; the consumer keeps up.
fn run_scenario(s: &Scenario, max_chunk: usize) -> Outcome {
    let sim = SimRing::new(s.ring, s.behaviour, s.seed);
    let (mut words, mut pixels) = buffers(s.run_words);
    let mut source = DcmiSource::new(sim.clone(), s.data, &mut words, &mut pixels);
    let cam = camera(s.width, s.height, s.data);
    source.start(cam, None).unwrap();
    for f in 0..s.frames {
        sim.send_frame(s.data, &frame_pixels(f, cam.pixel_count(), s.data.bits()));
    }
    let mut rng = Rng::new(s.seed ^ 0x55);
    let runs = drive(
        &mut source,
        &sim,
        &mut rng,
        |r| r.range(1, max_chunk),
        |_| 0,
    );
    let stats = source.stats();
    let mut assembler = Assembler::new(cam.pixel_count());
    for run in &runs {
        assembler.push(run);
    }
    Outcome {
        runs,
        stats,
        assembler,
        sim,
    }
}

fn expect_all_frames(s: &Scenario, o: &Outcome) {
    check_runs(&o.runs, s.data.bits(), &[]);
    assert_eq!(o.stats.overruns, 0, "{:?}", o.stats);
    assert_eq!(o.stats.frames_dropped, 0, "{:?}", o.stats);
    assert_eq!(o.stats.frames_delivered, s.frames);
    assert_eq!(
        o.assembler.completed_frames(),
        (0..s.frames).collect::<Vec<_>>()
    );
    assert!(o.assembler.incomplete.is_empty() && o.assembler.gaps == 0);
}

#[test]
fn random_chunks_deliver_every_frame_in_raster_order() {
    let mut rng = Rng::new(7);
    for case in 0..300 {
        let data = WIDTHS[case % 4];
        let per_word = data.pixels_per_word();
        let ring = 16 * rng.range(1, 12);
        let width = (per_word * rng.range(1, 12)) as u16;
        let height = rng.range(1, 9) as u16;
        let run_words = rng.range(1, 40);
        let behaviour = Behaviour {
            late_events: rng.chance(50),
            race_words: 0,
            speculate_percent: [0, 5, 30][case % 3],
            start_events: if rng.chance(50) {
                0u32.wrapping_sub(2 * rng.range(0, 40) as u32)
            } else {
                0
            },
            // The STM32H743's reading (FIFO hold-back, steps back): never
            // an overrun, never a wrong word.
            fifo_hold_back: case % 2 == 1,
        };
        let s = Scenario {
            data,
            width,
            height,
            ring,
            run_words,
            frames: rng.range(1, 12) as u32,
            behaviour,
            seed: case as u64,
        };
        // The DMA never gets more than the consumer takes per poll ahead.
        let max_chunk = run_words.min(ring / 4).max(1);
        eprintln!(
            "case {case}: {data:?} {width}x{height} ring {ring} run {run_words} {behaviour:?}"
        );
        let o = run_scenario(&s, max_chunk);
        expect_all_frames(&s, &o);
        // Runs are nonempty, within the frame, and a frame's runs tile it;
        // a run that crosses a row end ends at one (the engine's fast path
        // takes whole rows), unless it is the one word after a gap.
        let width = width as usize;
        for run in &o.runs {
            assert_eq!(run.pixels.len() % per_word, 0);
            assert!(run.pixels.len() <= run_words * per_word);
            let (into_row, len) = (run.first_pixel as usize % width, run.pixels.len());
            if into_row + len > width {
                assert_eq!((into_row + len) % width, 0, "case {case}: {run:?}");
            }
        }
    }
}

#[test]
fn frames_spanning_many_ring_wraps() {
    for data in WIDTHS {
        let s = Scenario {
            data,
            width: 64,
            height: 48,
            ring: 32,
            run_words: 16,
            frames: 6,
            behaviour: Behaviour {
                late_events: true,
                speculate_percent: 10,
                start_events: u32::MAX - 1,
                fifo_hold_back: true,
                ..Behaviour::default()
            },
            seed: 11,
        };
        let o = run_scenario(&s, 8);
        expect_all_frames(&s, &o);
        let frame_words = 64 * 48 / data.pixels_per_word() as u64;
        assert_eq!(o.sim.written(), 6 * frame_words);
        // Far more than the ring: the positions went round it (and round
        // 2^32, from the start value) many times.
        assert!(6 * frame_words > 100 * 32);
    }
}

#[test]
fn one_word_frames_and_a_ring_of_one_granule() {
    let s = Scenario {
        data: DataWidth::Bits8,
        width: 2,
        height: 2,
        ring: 16,
        run_words: 1,
        frames: 40,
        behaviour: Behaviour {
            late_events: true,
            ..Behaviour::default()
        },
        seed: 3,
    };
    let o = run_scenario(&s, 3);
    expect_all_frames(&s, &o);
}

#[test]
fn eight_and_sixteen_bit_words_become_the_same_rows() {
    // A 12 x 2 camera: 8-bit packs 3 words a row, 12-bit 6 words a row.
    for (data, words_per_frame) in [(DataWidth::Bits8, 6u64), (DataWidth::Bits12, 12)] {
        let sim = SimRing::new(32, Behaviour::default(), 1);
        let (mut words, mut pixels) = buffers(64);
        let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
        source.start(camera(12, 2, data), None).unwrap();
        let frame: Vec<u16> = (0..24).map(|k| 10 * k as u16 + 1).collect();
        sim.send_frame(data, &frame);
        assert_eq!(poll_next(&mut source), None);
        // The first row arrives: delivered at once.
        sim.advance(words_per_frame as usize / 2);
        let run = poll_next(&mut source).unwrap();
        assert_eq!((run.frame, run.first_pixel), (0, 0));
        assert_eq!(run.pixels, frame[..12]);
        // The second row, but for its last word (held back until the
        // frame's end is known).
        sim.advance(words_per_frame as usize / 2 - 1);
        let run = poll_next(&mut source).unwrap();
        let per_word = data.pixels_per_word();
        assert_eq!(run.first_pixel, 12);
        assert_eq!(run.pixels, frame[12..24 - per_word]);
        assert_eq!(poll_next(&mut source), None);
        // Last word and frame end.
        sim.advance(1);
        let run = poll_next(&mut source).unwrap();
        assert_eq!(run.first_pixel as usize, 24 - per_word);
        assert_eq!(run.pixels, frame[24 - per_word..]);
        assert_eq!(poll_next(&mut source), None);
        assert_eq!(source.stats().frames_delivered, 1);
    }
}

// --- the cache ----------------------------------------------------------------

#[test]
fn invalidation_covers_every_word_read_and_only_lines_of_the_ring() {
    let s = Scenario {
        data: DataWidth::Bits12,
        width: 30,
        height: 7,
        ring: 48,
        run_words: 13,
        frames: 20,
        behaviour: Behaviour {
            late_events: true,
            speculate_percent: 50,
            ..Behaviour::default()
        },
        seed: 5,
    };
    let o = run_scenario(&s, 9);
    expect_all_frames(&s, &o);
    let st = o.sim.state.borrow();
    // Each copy invalidates the lines it reads (whole 8-word lines, so at
    // least words / 8 of them).
    assert!(st.lines_invalidated * 8 >= st.words_copied);
    assert_eq!(st.words_copied, 20 * 30 * 7 / 2);
}

#[test]
fn without_invalidation_the_cache_model_serves_stale_words() {
    // The same scenario through a ring whose invalidation does nothing:
    // the model must catch it (else the test above proves nothing).
    let data = DataWidth::Bits8;
    let sim = SimRing::new(
        32,
        Behaviour {
            speculate_percent: 40,
            ..Behaviour::default()
        },
        9,
    );
    let (mut words, mut pixels) = buffers(8);
    let mut source = DcmiSource::new(NoInvalidate(sim.clone()), data, &mut words, &mut pixels);
    let cam = camera(16, 16, data);
    source.start(cam, None).unwrap();
    for f in 0..10 {
        sim.send_frame(data, &frame_pixels(f, cam.pixel_count(), 8));
    }
    let mut rng = Rng::new(4);
    let runs = drive(&mut source, &sim, &mut rng, |r| r.range(1, 6), |_| 0);
    let wrong = runs
        .iter()
        .flat_map(|r| {
            r.pixels
                .iter()
                .enumerate()
                .map(move |(k, &p)| p != pixel(r.frame, r.first_pixel as usize + k, 8))
        })
        .filter(|&w| w)
        .count();
    assert!(wrong > 0, "stale cache lines were never read");
}

// --- overruns and resync ---------------------------------------------------------

#[test]
fn an_overrun_is_counted_and_never_completes_a_wrong_frame() {
    for data in WIDTHS {
        // Frames are 32 words, the ring 64: stalls of more than 64 words
        // overrun; 700 words (22 frames) also loses the oldest marks.
        for (stall_at, stall) in [(100u64, 70usize), (130, 200), (64, 64 + 33), (150, 700)] {
            let sim = SimRing::new(64, Behaviour::default(), 2);
            let (mut words, mut pixels) = buffers(16);
            let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
            let cam = camera(16, 8, data);
            source.start(cam, None).unwrap();
            let frames = 40;
            for f in 0..frames {
                sim.send_frame(data, &frame_pixels(f, cam.pixel_count(), data.bits()));
            }
            let mut rng = Rng::new(stall as u64);
            let mut stalled = false;
            let runs = drive(
                &mut source,
                &sim,
                &mut rng,
                |r| r.range(1, 8),
                |written| {
                    if !stalled && written >= stall_at {
                        stalled = true;
                        stall
                    } else {
                        0
                    }
                },
            );
            let stats = source.stats();
            check_runs(&runs, data.bits(), &[]);
            let mut a = Assembler::new(cam.pixel_count());
            for run in &runs {
                a.push(run);
            }
            let fell_behind = stall > 64;
            assert_eq!(
                stats.overruns, fell_behind as u32,
                "{data:?} {stall}: {stats:?}"
            );
            assert_eq!(
                stats.frames_delivered + stats.frames_dropped,
                frames,
                "{stats:?}"
            );
            assert_eq!(a.completed.len() as u32, stats.frames_delivered);
            if fell_behind {
                // The device loop sees the overrun as a gap (and counts it).
                assert!(a.gaps + a.incomplete.len() as u32 >= 1, "{a:?}");
                assert!(stats.frames_dropped >= 1);
                // Frames after the stall are delivered again.
                assert_eq!(a.completed_frames().last(), Some(&(frames - 1)));
            } else {
                assert_eq!(stats.frames_dropped, 0);
            }
        }
    }
}

#[test]
fn words_overwritten_during_the_copy_are_discarded() {
    let data = DataWidth::Bits8;
    let sim = SimRing::new(32, Behaviour::default(), 2);
    let (mut words, mut pixels) = buffers(16);
    let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
    let cam = camera(32, 8, data); // 64 words a frame
    source.start(cam, None).unwrap();
    for f in 0..4 {
        sim.send_frame(data, &frame_pixels(f, cam.pixel_count(), 8));
    }
    sim.advance(20);
    let first = poll_next(&mut source).unwrap();
    assert_eq!(
        (first.frame, first.first_pixel, first.pixels.len()),
        (0, 0, 64)
    );
    sim.advance(10);
    // The DMA laps the ring in the middle of the next copy.
    sim.state.borrow_mut().race_once = 40;
    let mut runs = vec![first];
    let mut rng = Rng::new(1);
    runs.extend(drive(&mut source, &sim, &mut rng, |r| r.range(1, 8), |_| 0));
    check_runs(&runs, 8, &[]);
    let stats = source.stats();
    assert_eq!(stats.overruns, 1, "{stats:?}");
    let mut a = Assembler::new(cam.pixel_count());
    for run in &runs {
        a.push(run);
    }
    assert!(!a.completed_frames().contains(&0));
    assert_eq!(a.gaps, 1, "the device loop is told by a gap");
    assert_eq!(a.completed_frames(), [2, 3]);
    assert_eq!(stats.frames_dropped, 2);
}

#[test]
fn frames_of_the_wrong_length_are_dropped_and_the_next_frame_resyncs() {
    for data in WIDTHS {
        let sim = SimRing::new(128, Behaviour::default(), 6);
        let (mut words, mut pixels) = buffers(8);
        let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
        let cam = camera(16, 6, data);
        source.start(cam, None).unwrap();
        let per_word = data.pixels_per_word();
        let frame_words = cam.pixel_count() / per_word;
        let words_of = |f: u32| {
            let mut w = vec![0; frame_words];
            pack(
                data,
                &frame_pixels(f, cam.pixel_count(), data.bits()),
                &mut w,
            );
            w
        };
        // Frame 2 loses 3 words mid-frame, frame 5 has 2 extra words at the
        // end, frame 7 one word too few at the end.
        for f in 0..10u32 {
            let mut w = words_of(f);
            match f {
                2 => {
                    w.drain(5..8);
                }
                5 => w.extend([0xFFFF_FFFF, 0x1234_5678]),
                7 => {
                    w.pop();
                }
                _ => {}
            }
            sim.send_frame_words(&w);
        }
        let mut rng = Rng::new(8);
        let runs = drive(&mut source, &sim, &mut rng, |r| r.range(1, 5), |_| 0);
        // Frame 2's words after the loss are shifted: wrong, but the frame
        // never completes.
        check_runs(&runs, data.bits(), &[2]);
        let stats = source.stats();
        assert_eq!(stats.length_errors, 3, "{stats:?}");
        assert_eq!(stats.frames_dropped, 3);
        assert_eq!(stats.frames_delivered, 7);
        let mut a = Assembler::new(cam.pixel_count());
        for run in &runs {
            a.push(run);
        }
        assert_eq!(a.completed_frames(), [0, 1, 3, 4, 6, 8, 9]);
        // No pixel beyond the frame's length was ever delivered.
        for run in &runs {
            assert!(run.first_pixel as usize + run.pixels.len() <= cam.pixel_count());
        }
    }
}

#[test]
fn a_consumer_many_frames_behind_resyncs_on_the_newest_marks() {
    // Tiny frames (4 words), a ring of 64 frames: falling 40 frames behind
    // is no overrun, but the marks of the oldest frames are gone.
    let data = DataWidth::Bits8;
    let sim = SimRing::new(256, Behaviour::default(), 12);
    let (mut words, mut pixels) = buffers(2);
    let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
    let cam = camera(4, 4, data);
    source.start(cam, None).unwrap();
    for f in 0..100 {
        sim.send_frame(data, &frame_pixels(f, 16, 8));
    }
    let mut rng = Rng::new(3);
    let mut stalled = false;
    let runs = drive(
        &mut source,
        &sim,
        &mut rng,
        |r| r.range(1, 2),
        |written| {
            if !stalled && written >= 42 {
                stalled = true;
                160
            } else {
                0
            }
        },
    );
    check_runs(&runs, 8, &[]);
    let stats = source.stats();
    assert_eq!(stats.overruns, 0);
    assert!(stats.marks_lost >= 1, "{stats:?}");
    assert!(stats.frames_dropped >= 40 - MARK_SLOTS as u32, "{stats:?}");
    assert_eq!(stats.frames_delivered + stats.frames_dropped, 100);
    let mut a = Assembler::new(16);
    for run in &runs {
        a.push(run);
    }
    assert_eq!(a.completed.len() as u32, stats.frames_delivered);
    assert_eq!(a.completed_frames().last(), Some(&99));
}

#[test]
fn random_stalls_never_deliver_wrong_pixels() {
    let mut rng = Rng::new(99);
    for case in 0..300u64 {
        let data = WIDTHS[case as usize % 4];
        let per_word = data.pixels_per_word();
        let ring = 16 * rng.range(1, 6);
        let cam = camera(
            (per_word * rng.range(1, 8)) as u16,
            rng.range(1, 6) as u16,
            data,
        );
        let behaviour = Behaviour {
            late_events: rng.chance(50),
            race_words: if rng.chance(20) {
                rng.range(0, ring)
            } else {
                0
            },
            speculate_percent: 10,
            start_events: 0u32.wrapping_sub(2 * rng.range(0, 100) as u32),
            fifo_hold_back: case % 2 == 1,
        };
        let sim = SimRing::new(ring, behaviour, case);
        let (mut words, mut pixels) = buffers(rng.range(1, 20));
        let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
        source.start(cam, None).unwrap();
        let frames = rng.range(1, 30) as u32;
        for f in 0..frames {
            sim.send_frame(data, &frame_pixels(f, cam.pixel_count(), data.bits()));
        }
        let max_chunk = rng.range(1, 2 * ring);
        let stall_chance = rng.range(0, 20) as u64;
        let mut stall_rng = Rng::new(case + 1000);
        let runs = drive(
            &mut source,
            &sim,
            &mut rng.clone(),
            |r| r.range(1, max_chunk),
            |_| {
                if stall_rng.chance(stall_chance) {
                    stall_rng.range(1, 3 * ring)
                } else {
                    0
                }
            },
        );
        check_runs(&runs, data.bits(), &[]);
        let stats = source.stats();
        let mut a = Assembler::new(cam.pixel_count());
        for run in &runs {
            a.push(run);
        }
        if a.completed.len() as u32 != stats.frames_delivered {
            eprintln!("{data:?} {cam:?} ring {ring} {behaviour:?} frames {frames}");
            for r in &runs {
                eprintln!("run {} {} {}", r.frame, r.first_pixel, r.pixels.len());
            }
            eprintln!("{a:?} {stats:?}");
        }
        assert_eq!(
            a.completed.len() as u32,
            stats.frames_delivered,
            "case {case}"
        );
        assert_eq!(
            stats.frames_delivered + stats.frames_dropped,
            frames,
            "case {case}: {stats:?}"
        );
        for (f, pixels) in &a.completed {
            assert_eq!(*pixels, frame_pixels(*f, cam.pixel_count(), data.bits()));
        }
        rng.next();
    }
}

// --- start and stop ------------------------------------------------------------------

#[test]
fn start_refuses_what_the_interface_cannot_deliver() {
    let sim = SimRing::new(32, Behaviour::default(), 1);
    let (mut words, mut pixels) = buffers(8);
    let mut source = DcmiSource::new(sim.clone(), DataWidth::Bits12, &mut words, &mut pixels);
    let refused = |s: &mut DcmiSource<'_, SimRing>, c| s.start(c, None) == Err(CameraRefused);
    // Deeper than the bus.
    assert!(refused(&mut source, camera(8, 8, DataWidth::Bits14)));
    // Not a whole number of words (two 12-bit pixels a word).
    assert!(refused(
        &mut source,
        Camera {
            width: 3,
            height: 3,
            bit_depth: 12
        }
    ));
    assert!(!source.is_running());
    assert_eq!(sim.state.borrow().starts, 0);
    // A shallower camera on a wider bus is fine.
    assert!(source
        .start(
            Camera {
                width: 3,
                height: 2,
                bit_depth: 10
            },
            None
        )
        .is_ok());
}

#[test]
fn stop_then_start_begins_again_at_frame_zero() {
    let data = DataWidth::Bits10;
    let sim = SimRing::new(64, Behaviour::default(), 1);
    let (mut words, mut pixels) = buffers(64);
    let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
    let cam = camera(8, 4, data);
    source.start(cam, None).unwrap();
    sim.send_frame(data, &frame_pixels(0, 32, 10));
    sim.advance(1000);
    let run = poll_next(&mut source).unwrap();
    assert_eq!((run.frame, run.first_pixel, run.pixels.len()), (0, 0, 32));
    sim.send_frame(data, &frame_pixels(1, 32, 10));
    sim.advance(5);
    // Five words (ten pixels) are there: the run stops at the row's end.
    let run = poll_next(&mut source).unwrap();
    assert_eq!((run.frame, run.first_pixel, run.pixels.len()), (1, 0, 8));
    source.stop();
    assert!(!sim.state.borrow().running);
    // Stopped: nothing, whatever the DMA did.
    sim.advance(1000);
    assert_eq!(poll_next(&mut source), None);
    // Started again (the camera interface begins at the next frame start):
    // frames count from 0 again, at the ring's word 0.
    source.start(cam, None).unwrap();
    assert_eq!(sim.state.borrow().starts, 2);
    sim.send_frame(data, &frame_pixels(0, 32, 10));
    sim.send_frame(data, &frame_pixels(1, 32, 10));
    let mut rng = Rng::new(5);
    let runs = drive(&mut source, &sim, &mut rng, |r| r.range(1, 7), |_| 0);
    check_runs(&runs, 10, &[]);
    let mut a = Assembler::new(32);
    for run in &runs {
        a.push(run);
    }
    assert_eq!(a.completed_frames(), [0, 1]);
    // Frame 1 of the first capture was cut short by the stop: dropped.
    let stats = source.stats();
    assert_eq!(stats.frames_delivered, 3, "{stats:?}");
    assert_eq!(source.ring().capacity(), 64);
}
