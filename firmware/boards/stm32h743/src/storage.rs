//! Where the device's memory lives on the STM32H743, and how much there is.
//!
//! Sized for a 240 x 240 camera (e.g. an OCAM2-class EMCCD) with background
//! and gain maps, 1600 sub-apertures (a 40 x 40 Shack-Hartmann grid of 6 x 6
//! windows), in three memories (see the repository root's `memory.x`):
//!
//! | memory | what | bytes |
//! |---|---|---|
//! | DTCM (128 KiB, RAM: `.data`/`.bss`/stack) | engine memory (1600 sub-apertures, 128 open windows, 3072 candidate entries) | about 77 000 |
//! | | result queue (64 per row), link buffers, `PixelRows` batch | 5 600 |
//! | | camera run buffers (512 words, 1024 pixels) | 4 096 |
//! | | stack (at least, checked by the linker), executor task, USB, defmt | >= 16 384 + ~10 000 |
//! | AXI SRAM (512 KiB, DMA-reachable) | DCMI DMA ring: 1920 words = 16 rows of 240 pixels at 16 bits | 7 680 |
//! | | background maps, 2 slots x 57 600 x i32 | 460 800 |
//! | | the engine's row history (16 rows of 240) and rescan scratch (a 16 x 16 window) | 10 240 |
//! | | upload vetting scratch (2 x 1600 x u16; touched only by an upload) | 6 400 |
//! | | the bench request's buffers (256 windows, 64 frames, a camera run) | 25 600 |
//! | D2 SRAM1-3 (288 KiB) | gain maps, 2 slots x 57 600 x u16 | 230 400 |
//! | | windows, pixel counts, reference slopes: 2 slots x 1600 x 18 | 57 600 |
//!
//! The engine is never touched by DMA, so it goes in the DTCM (zero wait
//! states); only the DMA ring must be in AXI SRAM. Two configuration slots
//! (active and staging, for atomic commits) double the maps: a single 240 x
//! 240 slot with maps is 345 600 bytes, two do not fit the AXI SRAM alone.
//! Every size is checked at compile time below and by the linker.

use core::mem::{size_of, MaybeUninit};
use core::sync::atomic::{AtomicBool, Ordering};

use brightpix_firmware::device::storage::PIXEL_BATCH;
use brightpix_firmware::device::{ConfigSlot, DeviceBuffers};
use brightpix_firmware::engine::select::Entry;
use brightpix_firmware::engine::{EngineMemory, StaticEngineMemory, SubapertureResult};
use brightpix_protocol::wire::MAX_FRAME_LEN;
use brightpix_protocol::SubapertureWindow;

/// Camera pixels of calibration maps per configuration slot.
pub const CAMERA_PIXELS: usize = 240 * 240;
/// Sub-apertures per configuration.
pub const SUBAPERTURES: usize = 1600;
/// Windows open at once (one grid row of 40, with room for irregular layouts).
pub const OPEN_WINDOWS: usize = 128;
/// Candidate pool entries, 8 bytes each (e.g. a grid row of 40 windows of
/// 6x6, 36 each; 20 windows of 16x16 with N = 20 get their preferred 148
/// each, 41 of them their least, 74: a window's buffer is about
/// 4 (N + 1) + 64 entries when the pool holds that for every open window,
/// else what it holds down to about 2 (N + 1) + 32, at most its pixels;
/// see `engine::memory`).
pub const POOL_ENTRIES: usize = 3072;
/// Row-history pixels: selecting windows up to 16 rows tall on a 240-pixel
/// wide camera.
pub const HISTORY_PIXELS: usize = 16 * 240;
/// Scratch entries: selecting windows up to 256 pixels (16 x 16).
pub const SCRATCH_ENTRIES: usize = 256;
/// Results one camera row may finish.
pub const RESULTS_PER_ROW: usize = 64;
/// The DCMI DMA ring, in 32-bit words: 16 rows of a 240-pixel camera in an
/// extended (16 bits per pixel) mode, 32 rows in 8-bit mode. The camera
/// source is woken once per half (the DMA's half-transfer and
/// transfer-complete interrupts; there is no line interrupt), so a half is
/// the trade-off: 8 rows between wake-ups bound the work left after a
/// frame's last pixel to 8 rows, and give the device loop 8 rows of slack
/// (185 us at 180 frames/s of 240 rows) before an overrun. A multiple of
/// 16 words (each half whole cache lines), below the DMA's 65 535.
pub const RING_WORDS: usize = 1920;
/// Words per pixel run handed to the device loop, at most: 10- to 16-bit
/// pixels are read in the words (`camera::packing::as_pixels`), so a run of
/// 512 words is about nine rows of a 112-pixel camera. Longer runs cost the
/// camera source fewer of its ~250 instructions a run (CANARY on the QEMU
/// bench: 29 runs a frame of 256 words, 14 of 512; 13.46 against 13.09
/// instructions a pixel on Cortex-M4 with the engine's last row prepared
/// where the last run starts), within a ring half (960 words), which is
/// what a wake-up finds.
pub const RUN_WORDS: usize = 512;
/// Pixels 8-bit words are unpacked into: a run of 256 words of four.
pub const RUN_PIXELS: usize = 1024;
// The bench measures the camera path with these buffers.
const _: () = assert!(
    RUN_WORDS == brightpix_bench::workloads::CAMERA_RUN_WORDS
        && RUN_PIXELS == brightpix_bench::workloads::CAMERA_RUN_PIXELS
);

/// The capacities this build has, kept in the ELF for
/// `scripts/board-memory` (the README's figures): sub-apertures, open
/// windows, pool entries, ring words, camera pixels per map, results per
/// row.
#[no_mangle]
#[used]
pub static BRIGHTPIX_MEMORY_FIGURES: [u32; 6] = [
    SUBAPERTURES as u32,
    OPEN_WINDOWS as u32,
    POOL_ENTRIES as u32,
    RING_WORDS as u32,
    CAMERA_PIXELS as u32,
    RESULTS_PER_ROW as u32,
];

/// AXI SRAM: the DMA ring and the background maps.
#[repr(C, align(32))]
pub struct AxiSram {
    pub ring: [u32; RING_WORDS],
    pub background: [[i32; CAMERA_PIXELS]; 2],
    pub engine: EngineSram,
    /// The bench request's own buffers (per window and per frame; the
    /// frames and maps it borrows from the staging slot).
    pub bench: crate::bench::Buffers,
}

/// The engine's memory that is touched only when a window needs a rescan
/// (and the history, written once per pixel): it need not be in the DTCM.
#[repr(C)]
pub struct EngineSram {
    pub history: [u16; HISTORY_PIXELS],
    pub scratch: [i32; SCRATCH_ENTRIES],
    pub rescan: [Entry; SCRATCH_ENTRIES],
    /// The device's scratch for vetting an upload (touched only then): out
    /// of the DTCM since the engine's memory there grew (the lean row path).
    pub vet_order: [u16; SUBAPERTURES],
    pub vet_scratch: [u16; SUBAPERTURES],
}

/// D2 SRAM1-3: the gain maps and the per-sub-aperture tables.
#[repr(C, align(32))]
pub struct D2Sram {
    pub gain: [[u16; CAMERA_PIXELS]; 2],
    pub windows: [[SubapertureWindow; SUBAPERTURES]; 2],
    pub pixel_counts: [[u16; SUBAPERTURES]; 2],
    pub reference_slopes: [[[i32; 2]; SUBAPERTURES]; 2],
}

const NO_RESULT: SubapertureResult = SubapertureResult {
    index: 0,
    slope_x: 0,
    slope_y: 0,
    flux: 0,
    valid: false,
};

/// Word-aligned storage. The row kernels read pixels two to a 32-bit word
/// and take a row only when it starts on a word (`Engine::push_whole_row`,
/// which otherwise falls back to the portable path); a `[u16; N]` field on
/// its own may start 2 bytes past one.
#[repr(C, align(4))]
pub struct WordAligned<T>(pub T);

/// DTCM: everything the CPU works on per pixel, and the small buffers.
pub struct Dtcm {
    pub engine: StaticEngineMemory<SUBAPERTURES, OPEN_WINDOWS, POOL_ENTRIES, 0, 0>,
    pub results: [SubapertureResult; RESULTS_PER_ROW],
    pub rx: [u8; MAX_FRAME_LEN],
    pub tx: [u8; MAX_FRAME_LEN],
    pub pixels: WordAligned<[u16; PIXEL_BATCH]>,
    pub run_words: [u32; RUN_WORDS],
    pub run_pixels: WordAligned<[u16; RUN_PIXELS]>,
}

impl Dtcm {
    pub const fn new() -> Self {
        Dtcm {
            engine: StaticEngineMemory::new(),
            results: [NO_RESULT; RESULTS_PER_ROW],
            rx: [0; MAX_FRAME_LEN],
            tx: [0; MAX_FRAME_LEN],
            pixels: WordAligned([0; PIXEL_BATCH]),
            run_words: [0; RUN_WORDS],
            run_pixels: WordAligned([0; RUN_PIXELS]),
        }
    }
}

const _: () = assert!(size_of::<AxiSram>() <= 512 * 1024);
const _: () = assert!(size_of::<D2Sram>() <= 288 * 1024);
const _: () = assert!(size_of::<Dtcm>() <= 96 * 1024);
const _: () = assert!(RING_WORDS.is_multiple_of(brightpix_firmware::camera::RING_GRANULE_WORDS));
const _: () = assert!(RING_WORDS <= 65_535);

#[link_section = ".axisram"]
static mut AXI_SRAM: MaybeUninit<AxiSram> = MaybeUninit::uninit();
#[link_section = ".sram123"]
static mut D2_SRAM: MaybeUninit<D2Sram> = MaybeUninit::uninit();
/// In `.data`: initialised by cortex-m-rt (its initial image is in flash).
static mut DTCM: Dtcm = Dtcm::new();

static TAKEN: AtomicBool = AtomicBool::new(false);

/// All of it, once: AXI and D2 SRAM zeroed (all-zero is a valid value of
/// every field), the D2 SRAM clocks enabled first.
pub fn take() -> (&'static mut AxiSram, &'static mut D2Sram, &'static mut Dtcm) {
    assert!(!TAKEN.swap(true, Ordering::AcqRel), "storage taken twice");
    // Referenced, so the linker keeps the symbol.
    core::hint::black_box(&BRIGHTPIX_MEMORY_FIGURES);
    embassy_stm32::pac::RCC.ahb2enr().modify(|w| {
        w.set_sram1en(true);
        w.set_sram2en(true);
        w.set_sram3en(true);
    });
    cortex_m::asm::dsb();
    // SAFETY: taken once (above); the sections are NOLOAD and only ever
    // reached through these references; zero is a valid bit pattern for
    // every field (integers, integer arrays, `SubapertureWindow`).
    unsafe {
        let axi = (&raw mut AXI_SRAM).cast::<AxiSram>();
        axi.write_bytes(0, 1);
        let d2 = (&raw mut D2_SRAM).cast::<D2Sram>();
        d2.write_bytes(0, 1);
        let dtcm = &raw mut DTCM;
        (&mut *axi, &mut *d2, &mut *dtcm)
    }
}

/// The device's buffers: the engine and small buffers from the DTCM,
/// configuration slots across AXI (backgrounds) and D2 SRAM (the rest).
pub fn device_buffers<'d>(
    background: &'d mut [[i32; CAMERA_PIXELS]; 2],
    engine_sram: &'d mut EngineSram,
    d2: &'d mut D2Sram,
    dtcm: DtcmDevice<'d>,
) -> DeviceBuffers<'d> {
    let [bg_a, bg_b] = background;
    let [gain_a, gain_b] = &mut d2.gain;
    let [win_a, win_b] = &mut d2.windows;
    let [cnt_a, cnt_b] = &mut d2.pixel_counts;
    let [ref_a, ref_b] = &mut d2.reference_slopes;
    DeviceBuffers {
        slots: [
            ConfigSlot::new(win_a, cnt_a, ref_a, bg_a, gain_a),
            ConfigSlot::new(win_b, cnt_b, ref_b, bg_b, gain_b),
        ],
        engine: EngineMemory {
            history: &mut engine_sram.history,
            scratch: &mut engine_sram.scratch,
            rescan: &mut engine_sram.rescan,
            ..dtcm.engine.borrow()
        },
        order: &mut engine_sram.vet_order,
        scratch: &mut engine_sram.vet_scratch,
        results: dtcm.results,
        rx: dtcm.rx,
        tx: dtcm.tx,
        pixels: dtcm.pixels,
    }
}

/// The device's part of the DTCM, split from the camera's run buffers.
pub struct DtcmDevice<'a> {
    pub engine: &'a mut StaticEngineMemory<SUBAPERTURES, OPEN_WINDOWS, POOL_ENTRIES, 0, 0>,
    pub results: &'a mut [SubapertureResult],
    pub rx: &'a mut [u8],
    pub tx: &'a mut [u8],
    pub pixels: &'a mut [u16],
}

impl Dtcm {
    /// The device's buffers and the camera's run buffers (words, pixels).
    pub fn split(&mut self) -> (DtcmDevice<'_>, &mut [u32], &mut [u16]) {
        (
            DtcmDevice {
                engine: &mut self.engine,
                results: &mut self.results,
                rx: &mut self.rx,
                tx: &mut self.tx,
                pixels: &mut self.pixels.0,
            },
            &mut self.run_words,
            &mut self.run_pixels.0,
        )
    }
}
