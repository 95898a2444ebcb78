//! `brightpix-qemu-bench`: the streaming engine on Cortex-M in QEMU, in
//! instructions per pixel, counted deterministically with `-icount`, next to
//! its floors measured the same way in the same run.
//!
//! ```sh
//! cd firmware/boards/qemu && scripts/run-bench m4        # mps2-an386, Cortex-M4F
//! cd firmware/boards/qemu && scripts/run-bench m7        # mps2-an500, built for Cortex-M7
//! scripts/run-bench m4 --config upload.bin --frames frames.u16   # a user's configuration
//! ```
//!
//! (`cargo run --release --bin brightpix-qemu-bench` runs the M4 build; the
//! runner, `scripts/qemu-run`, adds `-icount shift=6,sleep=off`.) QEMU
//! counts instructions, not cycles: no caches, wait states, pipeline or dual
//! issue are modelled.
//!
//! Every workload (`workloads.rs`) is measured on frames generated here
//! (`frames.rs`), after warm-up frames (a running camera's seeds), one
//! camera row per push as a DMA row buffer delivers them:
//! - the engine, and the work left after the frame's final row arrives;
//! - **the floor** (`floor.rs`): a streaming centre of gravity above the
//!   known `v(N+1)` of each window, with the engine's pre-filter; its slopes
//!   equal the engine's subtract-next slopes bit for bit (checked);
//! - the floor without the pre-filter (every pixel calibrated), and every
//!   pixel read once (the memory floor);
//! - for CANARY, the paper's and DARC's sort per sub-aperture (slopes
//!   checked equal).
//!
//! Besides the table, one line per workload for tools (`brightpix bench`):
//! `BENCH {"workload": ..., "core": "cortex-m4", "instr_per_px": ...,
//! "floor_instr_per_px": ..., "last_row_instructions": ..., ...}`.
#![no_std]
#![no_main]

// The workloads, frames, floor and sort are `brightpix-bench`'s (one
// implementation, shared with the boards' bench request), compiled here as
// modules of this binary, which does not link that crate: in one crate
// with the timed loops, as they always were, so the code around the timed
// calls, and with it every figure of the QEMU tables, is what it was (see
// firmware/bench/src/lib.rs).
#[path = "../../../../bench/src/camera_feed.rs"]
mod camera_feed;
#[path = "../../../../bench/src/counter.rs"]
mod counter;
#[path = "../../../../bench/src/floor.rs"]
mod floor;
#[path = "../../../../bench/src/floor_row.rs"]
mod floor_row;
#[path = "../../../../bench/src/frames.rs"]
mod frames;
mod meter;
#[path = "../../../../bench/src/sort.rs"]
mod sort;
mod user;
// (FrameCounts and floor_comparable serve the boards' bench request.)
#[path = "../../../../bench/src/workloads.rs"]
#[allow(dead_code)]
mod workloads;

use brightpix_board_qemu::{exit, exit_code};
use brightpix_firmware::engine::calibrate::WindowBounds;
use brightpix_firmware::engine::centroid::{
    prefix_sums_background, prefix_sums_background_portable, sums_above, sums_above_portable,
};
use brightpix_firmware::engine::prefilter::{
    any_at_least, any_at_least_portable, copy_words, copy_words_portable, uqsub16, uqsub16_portable,
};
use brightpix_firmware::engine::scan::{check_complement_row, check_row_kernel};
use brightpix_firmware::engine::select::Entry;
use brightpix_firmware::engine::{StaticEngineMemory, SubapertureResult};
use brightpix_protocol::SubapertureWindow;
use cortex_m_rt::entry;
use semihosting::println;
use static_cell::ConstStaticCell;

use counter::Counter;
use frames::Rng;
use meter::Meter;
use workloads::{
    Buffers, Measured, Workload, CAMERA_RUN_PIXELS, CAMERA_RUN_WORDS, MAX_MAP_PIXELS, MAX_PIXELS,
    MAX_WINDOWS,
};

/// Clock of the latency estimate (STM32H743 class), MHz.
const CLOCK_MHZ: f64 = 480.0;

const NO_RESULT: SubapertureResult = SubapertureResult {
    index: 0,
    slope_x: 0,
    slope_y: 0,
    flux: 0,
    valid: false,
};
const NO_WINDOW: SubapertureWindow = SubapertureWindow {
    x: 0,
    y: 0,
    width: 0,
    height: 0,
};

/// Engine memory for every workload: 6400 sub-apertures, 128 open windows
/// of up to 256 candidates, 32 rows of an 800-pixel camera, 32x32 scratch.
type Memory = StaticEngineMemory<MAX_WINDOWS, 128, { 128 * 256 }, { 32 * 800 }, 1024>;

/// Word-aligned, as a camera's DMA buffer is.
#[repr(C, align(4))]
struct Aligned<T>(T);

static FRAME: ConstStaticCell<Aligned<[u16; MAX_PIXELS]>> =
    ConstStaticCell::new(Aligned([0; MAX_PIXELS]));
static BACKGROUND: ConstStaticCell<[i32; MAX_MAP_PIXELS]> =
    ConstStaticCell::new([0; MAX_MAP_PIXELS]);
static WINDOWS: ConstStaticCell<[SubapertureWindow; MAX_WINDOWS]> =
    ConstStaticCell::new([NO_WINDOW; MAX_WINDOWS]);
static LEVELS: ConstStaticCell<[i32; MAX_WINDOWS]> = ConstStaticCell::new([0; MAX_WINDOWS]);
static BOUNDS: ConstStaticCell<[WindowBounds; MAX_WINDOWS]> =
    ConstStaticCell::new([WindowBounds::NONE; MAX_WINDOWS]);
static ENGINE_RESULTS: ConstStaticCell<[SubapertureResult; MAX_WINDOWS]> =
    ConstStaticCell::new([NO_RESULT; MAX_WINDOWS]);
static FLOOR_RESULTS: ConstStaticCell<[SubapertureResult; MAX_WINDOWS]> =
    ConstStaticCell::new([NO_RESULT; MAX_WINDOWS]);

/// The camera source's run buffers, as the STM32H743's.
static CAMERA_WORDS: ConstStaticCell<[u32; CAMERA_RUN_WORDS]> =
    ConstStaticCell::new([0; CAMERA_RUN_WORDS]);
static CAMERA_PIXELS: ConstStaticCell<[u16; CAMERA_RUN_PIXELS]> =
    ConstStaticCell::new([0; CAMERA_RUN_PIXELS]);

static MEMORY: ConstStaticCell<Memory> = ConstStaticCell::new(Memory::new());

fn fail(what: &str) -> ! {
    println!("FAILED: {}", what);
    exit(1)
}

/// The DSP functions against their portable twins, on random inputs.
fn dsp_selftest() {
    let mut rng = Rng::new(0x9e37_79b9_7f4a_7c15);
    let mut word = || ((rng.next() * 65536.0) as u32) << 16 | (rng.next() * 65536.0) as u32;
    for _ in 0..20_000 {
        let (a, b) = (word(), word());
        if uqsub16(a, b) != uqsub16_portable(a, b) {
            fail("UQSUB16 differs from its portable twin");
        }
    }
    let mut raw = [0u16; 67];
    for round in 0..2_000 {
        let len = round % raw.len();
        let start = (round / 7) % 3;
        let top = 1 + (round % 5) * 13_000;
        for r in raw.iter_mut() {
            *r = (rng.next() * top as f32) as u16;
        }
        let floor = 1 + (rng.next() * top as f32) as u16;
        let run = &raw[start.min(len)..len];
        if any_at_least(run, floor) != any_at_least_portable(run, floor) {
            fail("the pre-filter differs from its portable twin");
        }
        if floor::read_every_pixel(run) != floor::read_every_pixel_portable(run) {
            fail("the memory floor differs from its portable twin");
        }
        let mut words = [0u32; 71];
        let mut twin = [0u32; 71];
        for w in words.iter_mut() {
            *w = (rng.next() * 4e9) as u32;
        }
        let n = round % words.len();
        let mut copied = [0u32; 71];
        copy_words(&words[..n], &mut copied[..n]);
        copy_words_portable(&words[..n], &mut twin[..n]);
        if copied != twin {
            fail("the word copy differs from its portable twin");
        }
        let mut background = [0i32; 67];
        for b in background.iter_mut() {
            *b = ((rng.next() - 0.5) * 32.0 * top as f32) as i32;
        }
        // SAFETY: the background is as long as the run.
        let sums = unsafe { prefix_sums_background(run, &background[..run.len()]) };
        if sums != prefix_sums_background_portable(run, &background[..run.len()]) {
            fail("the no-selection sums differ from their portable twin");
        }
    }
    sums_above_selftest(&mut rng);
    if let Err(e) = check_row_kernel(0x2545_f491_4f6c_dd1d, 3_000) {
        println!(
            "round {}, detail {:#x}, entries {:?}",
            e.round, e.window, e.entries
        );
        fail(e.what);
    }
    if let Err(e) = check_complement_row(0x9e37_79b9_7f4a_7c15, 3_000) {
        println!(
            "round {}, detail {:#x}, entries {:?}",
            e.round, e.window, e.entries
        );
        fail(e.what);
    }
    floor_row_selftest(&mut rng);
}

/// The closed form's sums against their portable twin: random values
/// around the level (ties with it included), every packed position of a
/// 64x64 window, up to 80 entries.
fn sums_above_selftest(rng: &mut Rng) {
    let mut entries = [Entry::ZERO; 80];
    for round in 0..3_000 {
        let len = round % (entries.len() + 1);
        let spread = [4.0, 300.0, 1e5, 6e7][round % 4];
        let u = ((rng.next() - 0.5) * spread) as i32;
        for e in entries[..len].iter_mut() {
            *e = Entry {
                value: u + ((rng.next() - 0.4) * spread) as i32,
                position: (rng.next() * 4096.0) as u32 & 0xfff,
            };
        }
        if round % 5 == 0 {
            for e in entries[..len].iter_mut().step_by(3) {
                e.value = u;
            }
        }
        let run = &entries[..len];
        if sums_above(run, u) != sums_above_portable(run, u) {
            fail("the closed form's sums differ from their portable twin");
        }
    }
}

/// The floor's row kernel against its portable twin: random rows, levels,
/// raw floors and backgrounds, segments of an odd and an even number of
/// words, with and without a background map.
fn floor_row_selftest(rng: &mut Rng) {
    use floor_row::{floor_row, floor_row_portable, FloorRow, FloorWindow};
    let mut row = Aligned([0u16; 96]);
    let mut background = [0i32; 96];
    for round in 0..600 {
        let side = [2, 4, 6, 10, 16, 32][round % 6];
        let across = 1 + round % (96 / side).min(7);
        let top = 1 + (round % 5) * 13_000;
        for r in row.0.iter_mut() {
            *r = (rng.next() * top as f32) as u16;
        }
        for b in background.iter_mut() {
            *b = ((rng.next() - 0.3) * 16.0 * top as f32) as i32;
        }
        let mut windows = [FloorWindow::default(); 7];
        for w in windows.iter_mut() {
            let floor = (rng.next() * top as f32) as u32;
            *w = FloorWindow {
                lanes: if floor == 0 || round % 11 == 0 {
                    u32::MAX
                } else {
                    (floor - 1).min(65_534) * 0x0001_0001
                },
                level: ((rng.next() - 0.2) * 16.0 * top as f32) as i32,
                sum_w: round as u64,
                sum_wcol: 3 * round as u64,
                sum_wj: 5 * round as u64,
            };
        }
        let mut twin = windows;
        let width = across * side;
        let map = (round % 2 == 0).then_some(&background[..width]);
        let j = round % 16;
        let a = FloorRow::new(&row.0[..width], map, &mut windows[..across], side, j);
        let b = FloorRow::new(&row.0[..width], map, &mut twin[..across], side, j);
        // SAFETY: made by FloorRow::new from live slices.
        unsafe {
            if map.is_some() {
                floor_row::<true>(&a);
                floor_row_portable::<true>(&b);
            } else {
                floor_row::<false>(&a);
                floor_row_portable::<false>(&b);
            }
        }
        if windows != twin {
            fail("the floor's row kernel differs from its portable twin");
        }
    }
}

#[entry]
fn main() -> ! {
    // A name that is no workload is refused before any work (else the
    // bench would measure nothing and say nothing of it).
    let only = only_workload();
    if let Some(name) = &only {
        if !workloads::ALL.iter().any(|w| w.name == name.as_str()) {
            println!("--only {}: no such workload; the workloads are:", name);
            for w in workloads::ALL {
                println!("  {}", w.name);
            }
            fail("--only names no workload");
        }
    }
    let (meter, shift) = Meter::calibrate();
    let core = meter::core_name();
    match shift {
        Some(s) => println!(
            "brightpix engine on {} (QEMU), -icount shift={} ({:.4} timer ticks per instruction measured): instruction counts are exact",
            core, s, meter.ticks_per_instruction
        ),
        None => println!(
            "WARNING: QEMU does not run with -icount ({:.4} ticks per instruction on the calibration loop): the figures below follow host time, they are not instruction counts",
            meter.ticks_per_instruction
        ),
    }
    dsp_selftest();

    let mut buffers = Buffers {
        frame: &mut FRAME.take().0,
        background: BACKGROUND.take(),
        windows: WINDOWS.take(),
        levels: LEVELS.take(),
        bounds: BOUNDS.take(),
        engine_results: ENGINE_RESULTS.take(),
        floor_results: FLOOR_RESULTS.take(),
        camera_words: CAMERA_WORDS.take(),
        camera_pixels: CAMERA_PIXELS.take(),
    };
    let memory = MEMORY.take();

    if let Some(request) = user::Request::from_semihosting() {
        user::run(&request, &meter, core, &mut buffers, memory);
        exit(exit_code::OK);
    }

    println!(
        "{:<34} {:>9} {:>9} {:>7} {:>11} {:>9} {:>9} {:>9} {:>8}",
        "workload",
        "instr/px",
        "floor",
        "x floor",
        "last row",
        "floor row",
        "calib-all",
        "memory",
        "rescans"
    );
    for w in workloads::ALL {
        if only.as_ref().is_some_and(|name| name.as_str() != w.name) {
            continue;
        }
        let m = match workloads::measure::<{ floor::MAX_ACROSS }>(
            w,
            &meter,
            &mut buffers,
            memory.borrow(),
        ) {
            Ok(m) => m,
            Err(e) => {
                println!("{}: {} (window {})", w.name, e.what, e.index);
                fail(e.what)
            }
        };
        report(w, &m, core);
    }
    println!(
        "(floor: centre of gravity above each window's known v(N+1), with the engine's pre-filter; its slopes equal the engine's subtract-next slopes, checked on every frame)"
    );
    exit(exit_code::OK)
}

/// `--only NAME`: measure one workload.
fn only_workload() -> Option<heapless::String<64>> {
    let args = semihosting::experimental::env::args::<1024>().ok()?;
    let mut args = (&args).skip(1);
    while let Some(Ok(arg)) = args.next() {
        if arg == "--only" {
            return args
                .next()?
                .ok()
                .and_then(|v| heapless::String::try_from(v).ok());
        }
    }
    None
}

fn report(w: &Workload, m: &Measured, core: &str) {
    let engine = m.per_pixel(m.engine);
    let floor = m.per_pixel(m.floor);
    println!(
        "{:<34} {:>9.2} {:>9.2} {:>7.2} {:>11.0} {:>9.0} {:>9.2} {:>9.2} {:>4}/{:<4}",
        w.name,
        engine,
        floor,
        engine / floor,
        m.engine_last_row,
        m.floor_last_row,
        m.per_pixel(m.calibrate_all),
        m.per_pixel(m.memory),
        m.stats.rescans,
        m.stats.windows
    );
    if let (Some(sort), Some(last)) = (m.sort, m.sort_last_row) {
        println!(
            "{:<34} {:>9.2} {:>9.2} {:>7.2} {:>11.0}   (the paper's sort per sub-aperture, {:.0} us at {} MHz after the last row)",
            "  sort per sub-aperture",
            m.per_pixel(sort),
            floor,
            m.per_pixel(sort) / floor,
            last,
            last / CLOCK_MHZ,
            CLOCK_MHZ as u32
        );
    }
    println!(
        "BENCH {{\"workload\":\"{}\",\"core\":\"{}\",\"instr_per_px\":{:.3},\"floor_instr_per_px\":{:.3},\"x_floor\":{:.3},\"last_row_instructions\":{:.0},\"floor_last_row_instructions\":{:.0},\"calibrate_all_floor_instr_per_px\":{:.3},\"memory_floor_instr_per_px\":{:.3},\"sort_instr_per_px\":{},\"sort_last_row_instructions\":{},\"pixels\":{},\"frames\":{},\"windows\":{},\"candidates\":{},\"compactions\":{},\"rescans\":{},\"attentions\":{}}}",
        w.name,
        core,
        engine,
        floor,
        engine / floor,
        m.engine_last_row,
        m.floor_last_row,
        m.per_pixel(m.calibrate_all),
        m.per_pixel(m.memory),
        Json(m.sort.map(|s| m.per_pixel(s))),
        Json(m.sort_last_row),
        m.pixels,
        m.frames,
        m.stats.windows,
        m.stats.candidates,
        m.stats.compactions,
        m.stats.rescans,
        m.stats.attentions
    );
}

/// A number or `null`.
struct Json(Option<f64>);

impl core::fmt::Display for Json {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            Some(v) => write!(f, "{:.3}", v),
            None => write!(f, "null"),
        }
    }
}
