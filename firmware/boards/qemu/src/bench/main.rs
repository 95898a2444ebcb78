//! `brightpix-qemu-bench`: the streaming engine on Cortex-M4F in QEMU, in
//! instructions per pixel, counted deterministically with `-icount`.
//!
//! ```sh
//! cd firmware/boards/qemu && cargo run --release --bin brightpix-qemu-bench
//! ```
//!
//! (the runner, `scripts/qemu-run`, adds `-icount shift=6,sleep=off` for this
//! binary). Under `-icount shift=S` every instruction takes 2^S ns of
//! virtual time, and the CMSDK timer0 ticks every 40 ns, so a tick count is an
//! instruction count: the benchmark measures ticks per instruction on a loop
//! of known length rather than trusting S, and says so if QEMU does not run
//! with `-icount` (the figures are then host-time noise, not counts).
//! QEMU counts instructions, not cycles: no caches, wait states, pipeline or
//! dual issue are modelled.
//!
//! Workloads, all on the same deterministic spot frames generated here (the
//! paper's CANARY layout: 112x112, 7x7 sub-apertures of 16x16, 50 counts of
//! background, 200-photon Gaussian spots at random offsets, +-3 counts of
//! noise; `frames.rs`):
//! - plain sum of the pixels (the memory floor);
//! - a centre of gravity above a fixed threshold (the floor for any
//!   selection; the host benchmark's `threshold_cog`);
//! - the engine without selection (N >= 256), with each rule at N = 20,
//!   whole frames and row by row;
//! - a full sort per sub-aperture (`sort_unstable` in the engine's integer
//!   arithmetic: the paper's and DARC's method), checked equal to the
//!   engine's subtract-next results;
//!
//! and the latency after the last pixel, for CANARY and an 80x80 grid of
//! 16x16 (1280x1280, ELT class): what is left to do when the final camera
//! row has arrived (the engine: that row; sorting: the last row of
//! sub-apertures), in instructions and in µs at 480 MHz with one
//! instruction per cycle.
#![no_std]
#![no_main]

mod frames;
mod workloads;

use core::sync::atomic::{compiler_fence, Ordering};

use brightpix_board_qemu::{exit, exit_code, timer};
use brightpix_firmware::engine::centroid::Centroider;
use brightpix_firmware::engine::{Engine, StaticEngineMemory, SubapertureResult};
use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, PixelCount, RegularGrid, Selection, SelectionRule,
    SubapertureWindow,
};
use cortex_m_rt::entry;
use semihosting::println;
use static_cell::ConstStaticCell;

use frames::{Rng, CANARY_PIXELS, CANARY_WIDTH, ELT_ACROSS, ELT_WIDTH, SIDE};
use workloads::{sort_window, threshold_cog, CANARY_WINDOWS};

/// Spot frames per CANARY measurement.
const FRAMES: usize = 8;
/// N of the paper's recommendation.
const N: u16 = 20;
/// Clock of the latency estimate (STM32H743 class), MHz.
const CLOCK_MHZ: f64 = 480.0;

const ELT_WINDOWS: usize = ELT_ACROSS * ELT_ACROSS;
const ELT_OPEN: usize = ELT_ACROSS;

static CANARY_FRAMES: ConstStaticCell<[u16; FRAMES * CANARY_PIXELS]> =
    ConstStaticCell::new([0; FRAMES * CANARY_PIXELS]);
static CANARY_BACKGROUND: ConstStaticCell<[i32; CANARY_PIXELS]> =
    ConstStaticCell::new([0; CANARY_PIXELS]);
static CANARY_MEMORY: ConstStaticCell<
    StaticEngineMemory<CANARY_WINDOWS, 8, { 8 * 272 }, { 16 * CANARY_WIDTH }, 256>,
> = ConstStaticCell::new(StaticEngineMemory::new());
static ELT_GRID: ConstStaticCell<[SubapertureWindow; ELT_WINDOWS]> = ConstStaticCell::new(
    [SubapertureWindow {
        x: 0,
        y: 0,
        width: 0,
        height: 0,
    }; ELT_WINDOWS],
);
static ELT_MEMORY: ConstStaticCell<
    StaticEngineMemory<ELT_WINDOWS, ELT_OPEN, { ELT_OPEN * 80 }, { SIDE * ELT_WIDTH }, 256>,
> = ConstStaticCell::new(StaticEngineMemory::new());
/// The last row of sub-apertures of the ELT frame (16 camera rows).
static ELT_LAST_ROWS: ConstStaticCell<[u16; SIDE * ELT_WIDTH]> =
    ConstStaticCell::new([0; SIDE * ELT_WIDTH]);

/// Converts timer ticks to instructions.
struct Meter {
    ticks_per_instruction: f64,
    /// Ticks of two back-to-back timer readings.
    overhead: u32,
}

impl Meter {
    /// Measures ticks per instruction on a loop of known length.
    fn calibrate() -> (Meter, Option<u32>) {
        let mut overhead = u32::MAX;
        for _ in 0..16 {
            let t0 = timer::ticks();
            let t1 = timer::ticks();
            overhead = overhead.min(t1.wrapping_sub(t0));
        }
        const ITERATIONS: u32 = 1_000_000;
        let t0 = timer::ticks();
        // SAFETY: a register-only countdown loop, two instructions per iteration.
        unsafe {
            core::arch::asm!(
                "2:",
                "subs {n}, {n}, #1",
                "bne 2b",
                n = inout(reg) ITERATIONS => _,
                options(nomem, nostack),
            );
        }
        let t1 = timer::ticks();
        let ticks = t1.wrapping_sub(t0).saturating_sub(overhead);
        let ticks_per_instruction = ticks as f64 / (2.0 * ITERATIONS as f64);
        // -icount shift=S: 2^S ns per instruction, 40 ns per tick.
        let ns = ticks_per_instruction * timer::NS_PER_TICK as f64;
        let shift = (0..=10).find(|&s| {
            let exact = (1u32 << s) as f64;
            (ns - exact).abs() < exact * 0.001
        });
        let meter = Meter {
            ticks_per_instruction,
            overhead,
        };
        (meter, shift)
    }

    /// Instructions `f` takes (from ticks, less the timer overhead).
    #[inline(always)]
    fn count<R>(&self, f: impl FnOnce() -> R) -> (f64, R) {
        compiler_fence(Ordering::SeqCst);
        let t0 = timer::ticks();
        compiler_fence(Ordering::SeqCst);
        let r = f();
        compiler_fence(Ordering::SeqCst);
        let t1 = timer::ticks();
        compiler_fence(Ordering::SeqCst);
        let ticks = t1.wrapping_sub(t0).saturating_sub(self.overhead);
        (ticks as f64 / self.ticks_per_instruction, r)
    }
}

fn canary_config<'a>(
    windows: &'a [SubapertureWindow],
    background: &'a [i32],
    rule: SelectionRule,
    n: u16,
) -> Config<'a> {
    Config {
        camera: Camera {
            width: CANARY_WIDTH as u16,
            height: CANARY_WIDTH as u16,
            bit_depth: 16,
        },
        windows,
        calibration: Calibration {
            background: Some(background),
            ..Calibration::default()
        },
        selection: Selection {
            rule,
            count: PixelCount::All(n),
            level_filter: None,
        },
        centroid: Centroid::default(),
    }
}

fn fail(what: &str) -> ! {
    println!("FAILED: {}", what);
    exit(1)
}

struct Row<'a> {
    name: &'a str,
    per_pixel: f64,
}

#[entry]
fn main() -> ! {
    timer::start();
    let (meter, shift) = Meter::calibrate();
    match shift {
        Some(s) => println!(
            "brightpix engine on Cortex-M4F, QEMU mps2-an386, -icount shift={} ({:.4} timer ticks per instruction measured); instruction counts are exact",
            s, meter.ticks_per_instruction
        ),
        None => println!(
            "WARNING: QEMU does not run with -icount ({:.4} ticks per instruction on the calibration loop): the figures below follow host time, they are not instruction counts",
            meter.ticks_per_instruction
        ),
    }

    // --- CANARY frames and configuration --------------------------------------
    let frames = CANARY_FRAMES.take();
    let mut rng = Rng::new(0x2545_f491_4f6c_dd1d);
    for frame in frames.chunks_exact_mut(CANARY_PIXELS) {
        frames::canary_frame(&mut rng, frame);
    }
    let background = CANARY_BACKGROUND.take();
    background.fill(50 * 16);
    let grid = RegularGrid {
        x: 0,
        y: 0,
        columns: 7,
        rows: 7,
        width: SIDE as u16,
        height: SIDE as u16,
        pitch_x: SIDE as u16,
        pitch_y: SIDE as u16,
    };
    let mut windows = [SubapertureWindow {
        x: 0,
        y: 0,
        width: 0,
        height: 0,
    }; CANARY_WINDOWS];
    for (w, g) in windows.iter_mut().zip(grid.windows()) {
        *w = g;
    }
    let memory = CANARY_MEMORY.take();
    let pixels = (FRAMES * CANARY_PIXELS) as f64;
    println!(
        "CANARY: {}x{} camera, 7x7 sub-apertures of 16x16, background map (50 counts), {} spot frames ({} pixels)",
        CANARY_WIDTH, CANARY_WIDTH, FRAMES, pixels as u32
    );

    let mut rows: heapless::Vec<Row<'static>, 16> = heapless::Vec::new();
    let mut add = |name: &'static str, instructions: f64| {
        let _ = rows.push(Row {
            name,
            per_pixel: instructions / pixels,
        });
    };

    // Memory floor.
    let (count, sum) = meter.count(|| {
        let mut sum = 0u32;
        for frame in frames.chunks_exact(CANARY_PIXELS) {
            sum = sum.wrapping_add(workloads::sum_pixels(core::hint::black_box(frame)));
        }
        sum
    });
    core::hint::black_box(sum);
    add("plain sum of pixels (memory floor)", count);

    // Floor for any selection.
    let mut cog = [(0i64, 0i64, 0i64); CANARY_WINDOWS];
    let (count, ()) = meter.count(|| {
        for frame in frames.chunks_exact(CANARY_PIXELS) {
            threshold_cog(core::hint::black_box(frame), 50, &mut cog);
            core::hint::black_box(&cog);
        }
    });
    add("threshold CoG, i64 (floor for any selection)", count);
    let floor = count;

    // The engine, whole frames.
    let mut engine_results = [[NO_RESULT; CANARY_WINDOWS]; FRAMES];
    let variants: [(&'static str, SelectionRule, u16); 5] = [
        (
            "engine, no selection (N >= 256)",
            SelectionRule::Threshold,
            256,
        ),
        ("engine, subtract-next N=20", SelectionRule::SubtractNext, N),
        ("engine, threshold N=20", SelectionRule::Threshold, N),
        (
            "engine, subtract-next-distinct N=20",
            SelectionRule::SubtractNextDistinct,
            N,
        ),
        (
            "engine, subtract-mean M=4 N=20",
            SelectionRule::SubtractMean { count: 4 },
            N,
        ),
    ];
    for (name, rule, n) in variants {
        let config = canary_config(&windows, background, rule, n);
        let mut engine = match Engine::new(config, memory.borrow()) {
            Ok(e) => e,
            Err(_) => fail("engine refused the CANARY configuration"),
        };
        let keep = rule == SelectionRule::SubtractNext;
        // Warm up: the seeds come from earlier frames of a running camera.
        for frame in frames.chunks_exact(CANARY_PIXELS) {
            let _ = engine.push(frame, &mut |_r: SubapertureResult| {});
        }
        let before = engine.stats();
        let mut total = 0.0;
        for (k, frame) in frames.chunks_exact(CANARY_PIXELS).enumerate() {
            let out = &mut engine_results[k];
            let (count, pushed) = meter.count(|| {
                engine.push(frame, &mut |r: SubapertureResult| {
                    if keep {
                        out[r.index as usize] = r;
                    }
                })
            });
            if pushed.is_err() {
                fail("pixel out of range");
            }
            total += count;
        }
        let st = engine.stats();
        println!(
            "{}: windows {} candidates {} compactions {} rescans {}",
            name,
            st.windows - before.windows,
            st.candidates - before.candidates,
            st.compactions - before.compactions,
            st.rescans - before.rescans
        );
        add(name, total);
    }

    // The engine, one camera row per push (as a DMA row buffer delivers).
    let config = canary_config(&windows, background, SelectionRule::SubtractNext, N);
    let mut engine = match Engine::new(config, memory.borrow()) {
        Ok(e) => e,
        Err(_) => fail("engine refused the CANARY configuration"),
    };
    let mut total = 0.0;
    let mut last_row = 0.0;
    let mut rows_total = 0.0;
    for frame in frames.chunks_exact(CANARY_PIXELS) {
        for (y, row) in frame.chunks_exact(CANARY_WIDTH).enumerate() {
            let (count, _) = meter.count(|| engine.push(row, &mut |_r: SubapertureResult| {}));
            total += count;
            if y == CANARY_WIDTH - 1 {
                last_row += count;
            } else {
                rows_total += count;
            }
        }
    }
    add("engine, subtract-next N=20, row by row", total);
    let canary_last_row = last_row / FRAMES as f64;
    let canary_mean_row = rows_total / (FRAMES * (CANARY_WIDTH - 1)) as f64;

    // Latency if pixels arrive one by one: the very last pixel alone.
    let mut last_pixel = 0.0;
    for frame in frames.chunks_exact(CANARY_PIXELS) {
        let (head, tail) = frame.split_at(CANARY_PIXELS - 1);
        let _ = engine.push(head, &mut |_r: SubapertureResult| {});
        let (count, _) = meter.count(|| engine.push(tail, &mut |_r: SubapertureResult| {}));
        last_pixel += count;
    }
    let canary_last_pixel = last_pixel / FRAMES as f64;

    // The paper's / DARC's method: full sort per sub-aperture.
    let centroider = Centroider::new(Centroid::default());
    let mut sorted = [NO_RESULT; CANARY_WINDOWS];
    let mut total = 0.0;
    let mut last_grid_row = 0.0;
    for (k, frame) in frames.chunks_exact(CANARY_PIXELS).enumerate() {
        for sy in 0..7 {
            let at = sy * SIDE * CANARY_WIDTH;
            let (count, ()) = meter.count(|| {
                for sx in 0..7 {
                    let index = sy * 7 + sx;
                    sorted[index] = sort_window(
                        &frame[at..],
                        Some(&background[at..]),
                        CANARY_WIDTH,
                        sx * SIDE,
                        N as usize,
                        &centroider,
                        index as u16,
                    );
                }
            });
            total += count;
            if sy == 6 {
                last_grid_row += count;
            }
        }
        if sorted != engine_results[k] {
            fail("the sorting baseline differs from the engine (subtract-next N=20)");
        }
    }
    add(
        "sort per sub-aperture (i32, sort_unstable), subtract-next N=20",
        total,
    );
    let canary_sort_last = last_grid_row / FRAMES as f64;

    println!("{:<66} {:>12} {:>9}", "variant", "instr/pixel", "x floor");
    for row in &rows {
        println!(
            "{:<66} {:>12.2} {:>9.2}",
            row.name,
            row.per_pixel,
            row.per_pixel / (floor / pixels)
        );
    }
    println!("(the sorting baseline's slopes equal the engine's on every frame)");

    // --- ELT: 80x80 sub-apertures of 16x16 on 1280x1280 ------------------------
    let elt_windows = ELT_GRID.take();
    let grid = RegularGrid {
        columns: ELT_ACROSS as u16,
        rows: ELT_ACROSS as u16,
        ..grid
    };
    for (w, g) in elt_windows.iter_mut().zip(grid.windows()) {
        *w = g;
    }
    let elt_config = Config {
        camera: Camera {
            width: ELT_WIDTH as u16,
            height: ELT_WIDTH as u16,
            bit_depth: 16,
        },
        windows: &elt_windows[..],
        calibration: Calibration::default(),
        selection: Selection {
            rule: SelectionRule::SubtractNext,
            count: PixelCount::All(N),
            level_filter: None,
        },
        centroid: Centroid::default(),
    };
    let elt_memory = ELT_MEMORY.take();
    let mut engine = match Engine::new(elt_config, elt_memory.borrow()) {
        Ok(e) => e,
        Err(_) => fail("engine refused the ELT configuration"),
    };
    let last_rows = ELT_LAST_ROWS.take();
    let mut row = [0u16; ELT_WIDTH];
    let mut generator = frames::EltFrame::new(Rng::new(0x9e37_79b9_7f4a_7c15));
    let mut elt_total = 0.0;
    let mut elt_last_row = 0.0;
    let mut elt_rows_before = 0.0;
    let mut elt_results = [NO_RESULT; ELT_ACROSS];
    for y in 0..ELT_WIDTH {
        generator.row(y, &mut row);
        let last = y >= ELT_WIDTH - SIDE;
        if last {
            last_rows[(y - (ELT_WIDTH - SIDE)) * ELT_WIDTH..][..ELT_WIDTH].copy_from_slice(&row);
        }
        let (count, _) = meter.count(|| {
            engine.push(&row, &mut |r: SubapertureResult| {
                if last {
                    elt_results[r.index as usize % ELT_ACROSS] = r;
                }
            })
        });
        elt_total += count;
        if y == ELT_WIDTH - 1 {
            elt_last_row = count;
        } else if y >= ELT_WIDTH - SIDE {
            elt_rows_before += count;
        }
    }
    let mut elt_sorted = [NO_RESULT; ELT_ACROSS];
    let first = (ELT_ACROSS - 1) * ELT_ACROSS;
    let (elt_sort_last, ()) = meter.count(|| {
        for (sx, out) in elt_sorted.iter_mut().enumerate() {
            *out = sort_window(
                &last_rows[..],
                None,
                ELT_WIDTH,
                sx * SIDE,
                N as usize,
                &centroider,
                (first + sx) as u16,
            );
        }
    });
    if elt_sorted != elt_results {
        fail("the sorting baseline differs from the engine (ELT, last row of sub-apertures)");
    }
    let elt_pixels = (ELT_WIDTH * ELT_WIDTH) as f64;
    println!(
        "ELT: {}x{} camera, 80x80 sub-apertures of 16x16, no calibration maps, subtract-next N=20, one spot frame, row by row: {:.2} instr/pixel",
        ELT_WIDTH,
        ELT_WIDTH,
        elt_total / elt_pixels
    );

    println!(
        "Latency after the last pixel: instructions, and us at {} MHz assuming 1 instruction per cycle",
        CLOCK_MHZ as u32
    );
    let latency = |name: &str, instructions: f64| {
        println!(
            "{:<74} {:>10.0} {:>8.2} us",
            name,
            instructions,
            instructions / CLOCK_MHZ
        );
    };
    latency(
        "CANARY engine: final camera row pushed (112 px, 7 sub-apertures end)",
        canary_last_row,
    );
    latency(
        "CANARY engine: (any other camera row, for comparison)",
        canary_mean_row,
    );
    latency(
        "CANARY engine: final pixel pushed alone (1 sub-aperture ends)",
        canary_last_pixel,
    );
    latency(
        "CANARY sort: last row of 7 sub-apertures (calibrate, sort, CoG)",
        canary_sort_last,
    );
    latency(
        "ELT engine: final camera row pushed (1280 px, 80 sub-apertures end)",
        elt_last_row,
    );
    latency(
        "ELT engine: (the 15 camera rows before it, mean, for comparison)",
        elt_rows_before / (SIDE - 1) as f64,
    );
    latency(
        "ELT sort: last row of 80 sub-apertures (calibrate, sort, CoG)",
        elt_sort_last,
    );
    exit(exit_code::OK)
}

const NO_RESULT: SubapertureResult = SubapertureResult {
    index: 0,
    slope_x: 0,
    slope_y: 0,
    flux: 0,
    valid: false,
};
