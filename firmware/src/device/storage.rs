//! The device's static storage: two configuration slots (active and
//! staging), the engine's memory, scratch for vetting an upload, the result
//! queue and the link buffers. Sized by const generics, chosen by the board.

use brightpix_protocol::wire::tables::TableSlices;
use brightpix_protocol::wire::{ConfigHeader, MAX_FRAME_LEN, MAX_PIXEL_BYTES};
use brightpix_protocol::{Config, SubapertureWindow};

use crate::engine::{EngineMemory, StaticEngineMemory, SubapertureResult};

const NO_WINDOW: SubapertureWindow = SubapertureWindow {
    x: 0,
    y: 0,
    width: 0,
    height: 0,
};

const NO_RESULT: SubapertureResult = SubapertureResult {
    index: 0,
    slope_x: 0,
    slope_y: 0,
    flux: 0,
    valid: false,
};

/// Pixels converted from one `PixelRows` message at a time.
pub const PIXEL_BATCH: usize = MAX_PIXEL_BYTES / 2;

/// One configuration's tables, for up to `S` sub-apertures and `P` camera
/// pixels of calibration maps.
pub struct SlotStorage<const S: usize, const P: usize> {
    windows: [SubapertureWindow; S],
    pixel_counts: [u16; S],
    reference_slopes: [[i32; 2]; S],
    background: [i32; P],
    gain: [u16; P],
}

impl<const S: usize, const P: usize> SlotStorage<S, P> {
    pub const fn new() -> Self {
        SlotStorage {
            windows: [NO_WINDOW; S],
            pixel_counts: [0; S],
            reference_slopes: [[0; 2]; S],
            background: [0; P],
            gain: [0; P],
        }
    }

    pub fn borrow(&mut self) -> ConfigSlot<'_> {
        ConfigSlot::new(
            &mut self.windows,
            &mut self.pixel_counts,
            &mut self.reference_slopes,
            &mut self.background,
            &mut self.gain,
        )
    }
}

impl<const S: usize, const P: usize> Default for SlotStorage<S, P> {
    fn default() -> Self {
        Self::new()
    }
}

/// A configuration slot: a header (when the slot holds a complete,
/// validated configuration) and the tables it describes.
pub struct ConfigSlot<'d> {
    pub(crate) header: Option<ConfigHeader>,
    pub windows: &'d mut [SubapertureWindow],
    pub pixel_counts: &'d mut [u16],
    pub reference_slopes: &'d mut [[i32; 2]],
    pub background: &'d mut [i32],
    pub gain: &'d mut [u16],
}

impl<'d> ConfigSlot<'d> {
    /// An empty slot over these tables (per sub-aperture: `windows`,
    /// `pixel_counts`, `reference_slopes`; per camera pixel: `background`,
    /// `gain`).
    pub fn new(
        windows: &'d mut [SubapertureWindow],
        pixel_counts: &'d mut [u16],
        reference_slopes: &'d mut [[i32; 2]],
        background: &'d mut [i32],
        gain: &'d mut [u16],
    ) -> Self {
        ConfigSlot {
            header: None,
            windows,
            pixel_counts,
            reference_slopes,
            background,
            gain,
        }
    }

    /// The configuration this slot holds, if any.
    pub fn config(&self) -> Option<Config<'_>> {
        self.header.as_ref()?.config(self.tables())
    }

    /// The configuration `header` describes over this slot's tables.
    pub(crate) fn config_with<'s>(&'s self, header: &ConfigHeader) -> Option<Config<'s>> {
        header.config(self.tables())
    }

    fn tables(&self) -> TableSlices<'_> {
        TableSlices {
            windows: self.windows,
            pixel_counts: self.pixel_counts,
            background: self.background,
            gain: self.gain,
            reference_slopes: self.reference_slopes,
        }
    }

    /// Sub-apertures this slot holds.
    pub fn subaperture_capacity(&self) -> usize {
        self.windows
            .len()
            .min(self.pixel_counts.len())
            .min(self.reference_slopes.len())
    }

    /// Camera pixels of calibration maps this slot holds.
    pub fn pixel_capacity(&self) -> usize {
        self.background.len().min(self.gain.len())
    }
}

/// Everything a [`Device`](super::Device) needs, borrowed. A board either
/// takes it from one [`DeviceStorage`] or assembles it from buffers in
/// different memories (e.g. the engine in DTCM, the maps in AXI SRAM).
pub struct DeviceBuffers<'d> {
    /// Active and staging configuration; they swap on a successful commit.
    pub slots: [ConfigSlot<'d>; 2],
    pub engine: EngineMemory<'d>,
    /// Scratch for vetting an upload (one entry per sub-aperture each).
    pub order: &'d mut [u16],
    pub scratch: &'d mut [u16],
    /// Results of one camera row wait here to be sent.
    pub results: &'d mut [SubapertureResult],
    /// Receive buffer: the longest frame accepted, delimiter excluded.
    pub rx: &'d mut [u8],
    /// Transmit buffer: at least [`MAX_FRAME_LEN`].
    pub tx: &'d mut [u8],
    /// Pixels decoded from `PixelRows`, a batch at a time.
    pub pixels: &'d mut [u16],
}

/// All of a device's storage in one place, for a `static`:
/// - `S`: sub-apertures per configuration;
/// - `P`: camera pixels of the background and gain maps (0: no maps);
/// - `OPEN`, `ENTRIES`, `HISTORY`, `SCRATCH`: the engine's open windows,
///   candidate pool entries, row-history pixels and scratch entries (see
///   `engine/memory.rs` for the budget);
/// - `Q`: results that one camera row may finish (`S` is always enough).
///
/// Bytes: about `2 * (18 * S + 6 * P) + 38 * S + 24 * Q` plus the engine's
/// `OPEN`, `ENTRIES`, `HISTORY` and `SCRATCH` and 3 KiB of buffers.
///
/// Const-constructible, so it can be placed in a `static` without passing
/// through the stack, e.g. with `static_cell::ConstStaticCell`.
pub struct DeviceStorage<
    const S: usize,
    const P: usize,
    const OPEN: usize,
    const ENTRIES: usize,
    const HISTORY: usize,
    const SCRATCH: usize,
    const Q: usize,
> {
    slots: [SlotStorage<S, P>; 2],
    engine: StaticEngineMemory<S, OPEN, ENTRIES, HISTORY, SCRATCH>,
    order: [u16; S],
    scratch: [u16; S],
    results: [SubapertureResult; Q],
    rx: [u8; MAX_FRAME_LEN],
    tx: [u8; MAX_FRAME_LEN],
    pixels: [u16; PIXEL_BATCH],
}

impl<
        const S: usize,
        const P: usize,
        const OPEN: usize,
        const ENTRIES: usize,
        const HISTORY: usize,
        const SCRATCH: usize,
        const Q: usize,
    > DeviceStorage<S, P, OPEN, ENTRIES, HISTORY, SCRATCH, Q>
{
    pub const fn new() -> Self {
        DeviceStorage {
            slots: [SlotStorage::new(), SlotStorage::new()],
            engine: StaticEngineMemory::new(),
            order: [0; S],
            scratch: [0; S],
            results: [NO_RESULT; Q],
            rx: [0; MAX_FRAME_LEN],
            tx: [0; MAX_FRAME_LEN],
            pixels: [0; PIXEL_BATCH],
        }
    }

    pub fn borrow(&mut self) -> DeviceBuffers<'_> {
        let [a, b] = &mut self.slots;
        DeviceBuffers {
            slots: [a.borrow(), b.borrow()],
            engine: self.engine.borrow(),
            order: &mut self.order,
            scratch: &mut self.scratch,
            results: &mut self.results,
            rx: &mut self.rx,
            tx: &mut self.tx,
            pixels: &mut self.pixels,
        }
    }
}

impl<
        const S: usize,
        const P: usize,
        const OPEN: usize,
        const ENTRIES: usize,
        const HISTORY: usize,
        const SCRATCH: usize,
        const Q: usize,
    > Default for DeviceStorage<S, P, OPEN, ENTRIES, HISTORY, SCRATCH, Q>
{
    fn default() -> Self {
        Self::new()
    }
}
