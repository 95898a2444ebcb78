//! The floors the engine is measured against: the work no selection can
//! avoid, done the tightest way we can write it, on the pixels as the
//! engine gets them (camera rows pushed one at a time).
//!
//! - [`read_every_pixel`]: the memory floor, every pixel read once.
//! - [`Floor`] with [`FloorMode::Skip`]: **the floor**. A streaming centre of
//!   gravity above a *known* level per window (the `v(N+1)` the engine has to
//!   find, handed to it): background map in 1/16 count, weights `p - L` above
//!   `L`, the three sums, and the same pre-filter as the engine (a row
//!   segment whose raw pixels cannot reach `L` is skipped uncalibrated,
//!   `UQSUB16` on Cortex-M), in one routine per camera row (`floor_row`,
//!   written as tight as the engine's row kernel). Its slopes are the engine's
//!   subtract-next slopes, bit for bit, which the benchmark checks: it does
//!   the same work, less finding `L`.
//! - [`FloorMode::CalibrateAll`]: the same kernel without the pre-filter
//!   (every pixel calibrated), the floor as first defined in the speed
//!   issue: what the pre-filter saves.
//! - [`FloorMode::AllPixels`]: every pixel weighs its value (the engine's
//!   `N >= n`).

use brightpix_firmware::engine::calibrate::{raw_floor, WindowBounds, With, FLOOR_NONE};
use brightpix_firmware::engine::centroid::{Centroider, Moments};
use brightpix_firmware::engine::SubapertureResult;
use brightpix_protocol::Calibration;

use crate::floor_row::{floor_row, FloorRow, FloorWindow};
use crate::frames::Grid;

/// The memory floor: the sum of a row's pixels, reading each once. On
/// Cortex-M, eight at a time with `LDM` and `UXTAH` (the loop the issue
/// measured); the portable sum is its twin.
#[inline(never)]
pub fn read_every_pixel(row: &[u16]) -> u32 {
    #[cfg(target_arch = "arm")]
    {
        // SAFETY: align_to only splits at aligned words; any bits are a u32.
        let (head, words, tail) = unsafe { row.align_to::<u32>() };
        let mut sum: u32 = head.iter().chain(tail).map(|&p| p as u32).sum();
        let quads = words.len() / 4;
        if quads > 0 {
            // SAFETY: reads exactly `quads * 4` words from `words`, which
            // holds at least that many; r2-r5 are declared clobbered.
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldm {p}!, {{r2, r3, r4, r5}}",
                    "uxtah {s}, {s}, r2",
                    "uxtah {s}, {s}, r2, ror #16",
                    "uxtah {s}, {s}, r3",
                    "uxtah {s}, {s}, r3, ror #16",
                    "uxtah {s}, {s}, r4",
                    "uxtah {s}, {s}, r4, ror #16",
                    "uxtah {s}, {s}, r5",
                    "uxtah {s}, {s}, r5, ror #16",
                    "subs {n}, {n}, #1",
                    "bne 2b",
                    p = inout(reg) words.as_ptr() => _,
                    n = inout(reg) quads => _,
                    s = inout(reg) sum,
                    out("r2") _, out("r3") _, out("r4") _, out("r5") _,
                    options(readonly, nostack),
                );
            }
        }
        for &w in &words[quads * 4..] {
            sum = sum.wrapping_add(w & 0xffff).wrapping_add(w >> 16);
        }
        sum
    }
    #[cfg(not(target_arch = "arm"))]
    {
        read_every_pixel_portable(row)
    }
}

/// The twin of [`read_every_pixel`].
pub fn read_every_pixel_portable(row: &[u16]) -> u32 {
    row.iter().fold(0u32, |s, &p| s.wrapping_add(p as u32))
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FloorMode {
    Skip,
    CalibrateAll,
    AllPixels,
}

/// Windows of one grid row the QEMU bench's floor holds (the ELT-like
/// grid's 80); a board's bench mode chooses fewer (`Floor`'s `A`), as its
/// stack is small.
pub const MAX_ACROSS: usize = 128;

/// The widest window side the floor handles (the bench's grids: 8 to 32).
const MAX_SIDE: usize = 64;

/// The background of a run without a map.
static NO_BACKGROUND: [i32; 4096] = [0; 4096];

/// A streaming centre of gravity over a regular grid with known levels, for
/// grids of at most `A` windows across.
pub struct Floor<'a, const A: usize = MAX_ACROSS> {
    grid: Grid,
    calibration: Calibration<'a>,
    centroider: Centroider<'a>,
    mode: FloorMode,
    /// Per window (row-major grid order): the level `L`, weights `p - L`
    /// above it.
    levels: &'a [i32],
    /// Per window: the map bounds, as the engine keeps them.
    bounds: &'a [WindowBounds],
    /// Per window of the current grid row: its sums, raw floor and level
    /// (the other modes).
    sums: [Moments; A],
    floors: [u32; A],
    row_levels: [i32; A],
    /// Per window of the current grid row, as the row kernel keeps them
    /// ([`FloorMode::Skip`]).
    kernel: [FloorWindow; A],
    /// Some window of the current grid row has raw floor 0 (every pixel
    /// can pass, which the kernel's lanes cannot say): it is summed
    /// pixel by pixel after the kernel, which skips it.
    any_floor_zero: bool,
    /// [`FloorMode::Skip`]: the kernel's arguments, kept from row to row;
    /// the row in its windows, the grid row, and the address of the row's
    /// first background value (0 without a map).
    args: FloorRow,
    j: usize,
    gy: usize,
    bg_row: usize,
}

impl<'a, const A: usize> Floor<'a, A> {
    pub fn new(
        grid: Grid,
        calibration: Calibration<'a>,
        centroider: Centroider<'a>,
        mode: FloorMode,
        levels: &'a [i32],
        bounds: &'a [WindowBounds],
    ) -> Self {
        assert!(grid.across <= A && grid.side <= MAX_SIDE);
        assert!(mode != FloorMode::Skip || grid.side.is_multiple_of(2));
        assert!(grid.width() <= NO_BACKGROUND.len());
        Floor {
            grid,
            calibration,
            centroider,
            mode,
            levels,
            bounds,
            sums: [Moments::ZERO; A],
            floors: [0; A],
            row_levels: [0; A],
            kernel: [FloorWindow::default(); A],
            any_floor_zero: false,
            args: FloorRow {
                row: core::ptr::null(),
                windows: core::ptr::null_mut(),
                windows_end: core::ptr::null_mut(),
                segment_bytes: 2 * grid.side as u32,
                bg_delta: 0,
                bg_row: 0,
                j: 0,
            },
            j: 0,
            gy: 0,
            bg_row: calibration.background.map_or(0, |b| b.as_ptr() as usize),
        }
    }

    /// Camera row `y`; emits each window's result after its last row.
    ///
    /// [`FloorMode::Skip`] runs the row kernel (`floor_row`: on Cortex-M
    /// one assembly routine for the whole row, everything in registers, a
    /// pair of words in seven instructions when no pixel passes); the other
    /// modes, which only put the pre-filter's gain in figures, are plain
    /// loops.
    #[inline(never)]
    pub fn push_row(&mut self, y: usize, row: &[u16], out: &mut impl FnMut(SubapertureResult)) {
        if self.mode != FloorMode::AllPixels {
            return self.skip_push(y, row, out);
        }
        let (across, side, width) = (self.grid.across, self.grid.side, self.grid.width());
        let (gy, j) = (y / side, y % side);
        let first = gy * across;
        if j == 0 {
            for sx in 0..across {
                self.sums[sx] = Moments::ZERO;
                let level = self.levels[first + sx];
                self.row_levels[sx] = level;
                // Strictly above L: the raw floor of L + 1.
                self.floors[sx] = raw_floor(
                    &self.calibration,
                    self.bounds[first + sx],
                    level.saturating_add(1),
                );
                let floor = self.floors[sx];
                self.kernel[sx] = FloorWindow {
                    lanes: if floor == 0 || floor >= FLOOR_NONE {
                        u32::MAX
                    } else {
                        (floor - 1) * 0x0001_0001
                    },
                    level,
                    ..FloorWindow::default()
                };
            }
            self.any_floor_zero = self.floors[..across].contains(&0);
        }
        let row = &row[..width];
        let background = match self.calibration.background {
            Some(b) => &b[y * width..][..width],
            None => &NO_BACKGROUND[..width],
        };
        let windows = row
            .chunks_exact(side)
            .zip(background.chunks_exact(side))
            .zip(self.sums[..across].iter_mut())
            .zip(self.floors[..across].iter().zip(&self.row_levels[..across]));
        match self.mode {
            FloorMode::Skip | FloorMode::CalibrateAll => unreachable!("push_row takes skip_push"),
            FloorMode::AllPixels => {
                // The engine's own pass (there is nothing to select: the
                // floor's work is the engine's).
                for (((segment, bg), sums), _) in windows {
                    sums.add_raw_row::<With<true, false, false>>(
                        segment,
                        bg,
                        &[],
                        i32::MIN,
                        0,
                        j as u16,
                    );
                }
            }
        }
        if j == side - 1 {
            for sx in 0..across {
                let moments = if self.mode == FloorMode::Skip {
                    let k = &self.kernel[sx];
                    Moments {
                        sum_w: k.sum_w as i64,
                        sum_wi: k.sum_wcol.wrapping_sub((sx * side) as u64 * k.sum_w) as i64,
                        sum_wj: k.sum_wj as i64,
                    }
                } else {
                    self.sums[sx]
                };
                out(self
                    .centroider
                    .result((first + sx) as u16, moments, side as u16, side as u16));
            }
        }
    }

    /// One camera row of [`FloorMode::Skip`] (rows come in order from
    /// the frame's first): the kernel, then the windows it skipped for a
    /// raw floor of 0; after a grid row's last camera row, its results.
    #[inline(always)]
    fn skip_push(&mut self, y: usize, row: &[u16], out: &mut impl FnMut(SubapertureResult)) {
        debug_assert_eq!(y, self.gy * self.grid.side + self.j);
        if self.j == 0 {
            self.start_band();
        }
        let row_address = row.as_ptr() as usize;
        assert!(row_address & 3 == 0 && row.len() >= self.grid.width());
        self.args.row = row.as_ptr();
        self.args.bg_delta = self.bg_row.wrapping_sub(2 * row_address).wrapping_sub(16);
        self.args.bg_row = self.bg_row;
        self.args.j = self.j as u32;
        // SAFETY: the arguments point at this row (a whole, word-aligned
        // camera row of the grid: asserted above), its background
        // row and the grid row's windows.
        unsafe {
            if self.bg_row != 0 {
                floor_row::<true>(&self.args)
            } else {
                floor_row::<false>(&self.args)
            }
        }
        if self.any_floor_zero {
            self.floor_zero_row(row);
        }
        let (side, width) = (self.grid.side, self.grid.width());
        if self.bg_row != 0 {
            self.bg_row += 4 * width;
        }
        self.j += 1;
        if self.j == side {
            let first = self.gy * self.grid.across;
            for (sx, k) in self.kernel[..self.grid.across].iter().enumerate() {
                let moments = Moments {
                    sum_w: k.sum_w as i64,
                    sum_wi: k.sum_wcol.wrapping_sub((sx * side) as u64 * k.sum_w) as i64,
                    sum_wj: k.sum_wj as i64,
                };
                out(self
                    .centroider
                    .result((first + sx) as u16, moments, side as u16, side as u16));
            }
            self.j = 0;
            self.gy += 1;
        }
    }

    /// A grid row's windows: levels, lanes, sums cleared.
    #[cold]
    fn start_band(&mut self) {
        let across = self.grid.across;
        let first = self.gy * across;
        for sx in 0..across {
            let level = self.levels[first + sx];
            // Strictly above L: the raw floor of L + 1.
            let floor = raw_floor(
                &self.calibration,
                self.bounds[first + sx],
                level.saturating_add(1),
            );
            self.floors[sx] = floor;
            self.kernel[sx] = FloorWindow {
                lanes: if self.mode == FloorMode::CalibrateAll {
                    // No pre-filter: every pixel but a raw 0 passes (a
                    // figure of the work only: its results are not used).
                    0
                } else if floor == 0 || floor >= FLOOR_NONE {
                    u32::MAX
                } else {
                    (floor - 1) * 0x0001_0001
                },
                level,
                ..FloorWindow::default()
            };
        }
        self.any_floor_zero = self.mode == FloorMode::Skip && self.floors[..across].contains(&0);
        let range = self.kernel[..across].as_mut_ptr_range();
        self.args.windows = range.start;
        self.args.windows_end = range.end;
    }

    /// The windows of a raw floor of 0, pixel by pixel.
    #[cold]
    fn floor_zero_row(&mut self, row: &[u16]) {
        let (side, width, j) = (self.grid.side, self.grid.width(), self.j);
        let background = (self.bg_row != 0).then(|| {
            // SAFETY: `bg_row` is the address of the current row of the map.
            unsafe { core::slice::from_raw_parts(self.bg_row as *const i32, width) }
        });
        for (sx, window) in self.kernel[..self.grid.across].iter_mut().enumerate() {
            if self.floors[sx] != 0 {
                continue;
            }
            for i in 0..side {
                let column = sx * side + i;
                let b = background.map_or(0, |b| b[column]);
                let w = ((row[column] as i32) << 4) - b - window.level;
                if w > 0 {
                    window.sum_w += w as u64;
                    window.sum_wcol += w as u64 * column as u64;
                    window.sum_wj += w as u64 * j as u64;
                }
            }
        }
    }
}
