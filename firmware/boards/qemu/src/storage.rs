//! The device's buffers, sized for the 4 MiB of RAM of the mps2 boards.
//!
//! | what | limit | why |
//! |---|---|---|
//! | sub-apertures per configuration | [`MAX_SUBAPERTURES`] = 6400 | an 80x80 ELT-class grid (without maps); 1024 is plenty for 8 m-class |
//! | camera pixels of background/gain maps | [`MAX_MAP_PIXELS`] = 65536 | maps for cameras up to 256x256 (no limit on the camera without maps) |
//! | open windows (crossing one camera row) | [`MAX_OPEN_WINDOWS`] = 256 | a grid row of 256 windows, or several rows of overlapping ones |
//! | candidate pool entries | [`POOL_ENTRIES`] = 256 x 271 | every open window of 16x16 with any N and rule (a window's buffer never exceeds its pixels, 256), with room to spare; fewer open windows leave room for larger windows. |
//! | row history pixels | [`HISTORY_PIXELS`] = 64 x 4096 | the tallest window (64 rows) of the widest camera (4096) |
//! | scratch entries | [`SCRATCH_ENTRIES`] = 4096 | the largest window, 64 x 64 |
//! | results finished by one camera row | [`MAX_RESULTS_PER_ROW`] = 1024 | |
//!
//! Bytes (`TOTAL_BYTES`, logged at boot): two configuration slots of
//! 18 B per sub-aperture + 6 B per map pixel (1.0 MB), the engine's 26 B
//! per sub-aperture, 8 B per pool entry, 2 B per history pixel and 12 B per
//! scratch entry (1.1 MB), vetting scratch, result queue, link buffers and
//! the pixel stream's buffers: about 2.2 MB in all, leaving over 1.5 MB of
//! RAM for the stack and the rest.
//!
//! Every buffer is its own `static` whose initial value is all zero bytes
//! (so it lands in `.bss`, zeroed at boot), except the open windows'
//! state (a few KiB in `.data`). One `DeviceStorage` static would work
//! too, but its non-zero parts would put all 1.6 MB in `.data`: in the
//! flash image and copied at every boot.

use brightpix_firmware::device::{DeviceBuffers, SlotStorage};
use brightpix_firmware::engine::select::Entry;
use brightpix_firmware::engine::{EngineMemory, OpenWindow, SubapertureResult, SubapertureState};
use brightpix_protocol::wire::{MAX_FRAME_LEN, MAX_PIXEL_BYTES};
use static_cell::ConstStaticCell;

pub const MAX_SUBAPERTURES: usize = 6400;
pub const MAX_MAP_PIXELS: usize = 256 * 256;
pub const MAX_OPEN_WINDOWS: usize = 256;
/// Pool entries per open window: every N and rule on 16x16 windows needs
/// at most 256 (kept from the previous engine's budget, 255 + 16).
pub const POOL_STRIDE_16X16: usize = 255 + 16;
pub const POOL_ENTRIES: usize = MAX_OPEN_WINDOWS * POOL_STRIDE_16X16;
pub const HISTORY_PIXELS: usize = 64 * 4096;
pub const SCRATCH_ENTRIES: usize = 64 * 64;
pub const MAX_RESULTS_PER_ROW: usize = 1024;
/// The pixel stream (`--pixels`) reads its file into this buffer: the most
/// one semihosting read asks for.
pub const STREAM_BUFFER_BYTES: usize = 4096;
/// Pixels of one `PixelRows` message.
pub const PIXEL_BATCH: usize = MAX_PIXEL_BYTES / 2;

const S: usize = MAX_SUBAPERTURES;
const P: usize = MAX_MAP_PIXELS;
const OPEN: usize = MAX_OPEN_WINDOWS;
const ENTRIES: usize = POOL_ENTRIES;
const Q: usize = MAX_RESULTS_PER_ROW;

const NO_RESULT: SubapertureResult = SubapertureResult {
    index: 0,
    slope_x: 0,
    slope_y: 0,
    flux: 0,
    valid: false,
};

static SLOT_A: ConstStaticCell<SlotStorage<S, P>> = ConstStaticCell::new(SlotStorage::new());
static SLOT_B: ConstStaticCell<SlotStorage<S, P>> = ConstStaticCell::new(SlotStorage::new());
static ENGINE_ORDER: ConstStaticCell<[u16; S]> = ConstStaticCell::new([0; S]);
static SUBAPERTURE_STATES: ConstStaticCell<[SubapertureState; S]> =
    ConstStaticCell::new([SubapertureState::RESET; S]);
/// One more than the open windows: the row kernel's end mark.
static OPEN_WINDOWS: ConstStaticCell<[OpenWindow; OPEN + 1]> =
    ConstStaticCell::new([OpenWindow::CLOSED; OPEN + 1]);
static FREE: ConstStaticCell<[u16; OPEN]> = ConstStaticCell::new([0; OPEN]);
static POOL: ConstStaticCell<[Entry; ENTRIES]> = ConstStaticCell::new([Entry::ZERO; ENTRIES]);
static HISTORY: ConstStaticCell<WordAligned<[u16; HISTORY_PIXELS]>> =
    ConstStaticCell::new(WordAligned([0; HISTORY_PIXELS]));
static SCRATCH: ConstStaticCell<[i32; SCRATCH_ENTRIES]> =
    ConstStaticCell::new([0; SCRATCH_ENTRIES]);
static RESCAN: ConstStaticCell<[Entry; SCRATCH_ENTRIES]> =
    ConstStaticCell::new([Entry::ZERO; SCRATCH_ENTRIES]);
static VET_ORDER: ConstStaticCell<[u16; S]> = ConstStaticCell::new([0; S]);
static VET_SCRATCH: ConstStaticCell<[u16; S]> = ConstStaticCell::new([0; S]);
static RESULTS: ConstStaticCell<[SubapertureResult; Q]> = ConstStaticCell::new([NO_RESULT; Q]);
static RX: ConstStaticCell<[u8; MAX_FRAME_LEN]> = ConstStaticCell::new([0; MAX_FRAME_LEN]);
static TX: ConstStaticCell<[u8; MAX_FRAME_LEN]> = ConstStaticCell::new([0; MAX_FRAME_LEN]);
/// Word-aligned storage. The row kernels read pixels two to a 32-bit word
/// and take a row only when it starts on a word (`Engine::push_whole_row`,
/// which otherwise falls back to the portable path); a `[u16; N]` static on
/// its own may start 2 bytes past one, and then no row of an even-width
/// camera would ever reach the kernels.
#[repr(C, align(4))]
struct WordAligned<T>(T);

static PIXELS: ConstStaticCell<WordAligned<[u16; PIXEL_BATCH]>> =
    ConstStaticCell::new(WordAligned([0; PIXEL_BATCH]));
static STREAM_FRAMES: ConstStaticCell<[u8; STREAM_BUFFER_BYTES]> =
    ConstStaticCell::new([0; STREAM_BUFFER_BYTES]);
static STREAM_PIXELS: ConstStaticCell<WordAligned<[u16; PIXEL_BATCH]>> =
    ConstStaticCell::new(WordAligned([0; PIXEL_BATCH]));

/// Bytes of all the buffers above.
pub const TOTAL_BYTES: usize = 2 * core::mem::size_of::<SlotStorage<S, P>>()
    + S * (2 + core::mem::size_of::<SubapertureState>())
    + (OPEN + 1) * core::mem::size_of::<OpenWindow>()
    + OPEN * 2
    + ENTRIES * 8
    + HISTORY_PIXELS * 2
    + SCRATCH_ENTRIES * 12
    + 2 * S * 2
    + Q * core::mem::size_of::<SubapertureResult>()
    + 2 * MAX_FRAME_LEN
    + 2 * PIXEL_BATCH * 2
    + STREAM_BUFFER_BYTES;

/// The device's buffers. Panics if called twice.
pub fn device_buffers() -> DeviceBuffers<'static> {
    DeviceBuffers {
        slots: [SLOT_A.take().borrow(), SLOT_B.take().borrow()],
        engine: EngineMemory {
            order: ENGINE_ORDER.take(),
            subapertures: SUBAPERTURE_STATES.take(),
            open: OPEN_WINDOWS.take(),
            free: FREE.take(),
            entries: POOL.take(),
            history: &mut HISTORY.take().0,
            scratch: SCRATCH.take(),
            rescan: RESCAN.take(),
        },
        order: VET_ORDER.take(),
        scratch: VET_SCRATCH.take(),
        results: RESULTS.take(),
        rx: RX.take(),
        tx: TX.take(),
        pixels: &mut PIXELS.take().0,
    }
}

/// The pixel stream's buffers: frames read from the file, pixels of one
/// message. Panics if called twice.
pub fn stream_buffers() -> (&'static mut [u8], &'static mut [u16]) {
    (STREAM_FRAMES.take(), &mut STREAM_PIXELS.take().0)
}
