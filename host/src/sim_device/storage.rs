//! A device's storage on the heap ([`HeapDeviceStorage`]): what a board
//! keeps in statics, sized by [`SimSizes`] (the QEMU board's limits by
//! default).

use brightpix_firmware::device::{ConfigSlot, DeviceBuffers};
use brightpix_firmware::engine::{MemorySize, SubapertureResult};
use brightpix_protocol::wire::{MAX_FRAME_LEN, MAX_PIXEL_BYTES};
use brightpix_protocol::SubapertureWindow;

use crate::engine_runner::EngineBuffers;

/// The in-process device's buffers (the QEMU board's limits by default).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SimSizes {
    pub subapertures: usize,
    /// Camera pixels of background and gain maps.
    pub map_pixels: usize,
    pub open_windows: usize,
    pub pool_entries: usize,
    /// Camera pixels of the engine's row history.
    pub history_pixels: usize,
    /// The engine's scratch entries (pixels of the largest selecting window).
    pub scratch_entries: usize,
    pub results_per_row: usize,
}

impl Default for SimSizes {
    fn default() -> Self {
        SimSizes {
            subapertures: 6400,
            map_pixels: 256 * 256,
            open_windows: 256,
            pool_entries: 256 * 271,
            history_pixels: 64 * 4096,
            scratch_entries: 64 * 64,
            results_per_row: 1024,
        }
    }
}

struct SlotVecs {
    windows: Vec<SubapertureWindow>,
    counts: Vec<u16>,
    references: Vec<[i32; 2]>,
    background: Vec<i32>,
    gain: Vec<u16>,
}

/// A device's storage on the heap: what a board keeps in statics, for the
/// in-process device and for tests of the device loop.
pub struct HeapDeviceStorage {
    slots: [SlotVecs; 2],
    engine: EngineBuffers,
    vet_order: Vec<u16>,
    vet_scratch: Vec<u16>,
    results: Vec<SubapertureResult>,
    rx: Vec<u8>,
    tx: Vec<u8>,
    pixels: Vec<u16>,
}

impl HeapDeviceStorage {
    pub fn new(z: SimSizes) -> Self {
        let slot = || SlotVecs {
            windows: vec![
                SubapertureWindow {
                    x: 0,
                    y: 0,
                    width: 0,
                    height: 0
                };
                z.subapertures
            ],
            counts: vec![0; z.subapertures],
            references: vec![[0; 2]; z.subapertures],
            background: vec![0; z.map_pixels],
            gain: vec![0; z.map_pixels],
        };
        let none = SubapertureResult {
            index: 0,
            slope_x: 0,
            slope_y: 0,
            flux: 0,
            valid: false,
        };
        HeapDeviceStorage {
            slots: [slot(), slot()],
            engine: EngineBuffers::with_capacity(MemorySize {
                subapertures: z.subapertures,
                open_windows: z.open_windows,
                pool_entries: z.pool_entries,
                history_pixels: z.history_pixels,
                scratch_entries: z.scratch_entries,
            }),
            vet_order: vec![0; z.subapertures],
            vet_scratch: vec![0; z.subapertures],
            results: vec![none; z.results_per_row],
            rx: vec![0; MAX_FRAME_LEN],
            tx: vec![0; MAX_FRAME_LEN],
            pixels: vec![0; MAX_PIXEL_BYTES / 2],
        }
    }

    /// The buffers for `Device::new`.
    pub fn buffers(&mut self) -> DeviceBuffers<'_> {
        fn slot(s: &mut SlotVecs) -> ConfigSlot<'_> {
            ConfigSlot::new(
                &mut s.windows,
                &mut s.counts,
                &mut s.references,
                &mut s.background,
                &mut s.gain,
            )
        }
        let [a, b] = &mut self.slots;
        DeviceBuffers {
            slots: [slot(a), slot(b)],
            engine: self.engine.memory(),
            order: &mut self.vet_order,
            scratch: &mut self.vet_scratch,
            results: &mut self.results,
            rx: &mut self.rx,
            tx: &mut self.tx,
            pixels: &mut self.pixels,
        }
    }
}
