//! The boards a rig can use: their crop rules, clocks and links, and the
//! cost model that predicts a board's load from the bench.

use brightpix_firmware::camera::crop::{frame_check, DCMI_WIDTH_MULTIPLE};
use brightpix_firmware::camera::{dcmi_check, DataWidth};
use brightpix_protocol::{Camera, Crop};

use super::link::{self, Link};
use super::part::Rectangle;

/// The DCMI samples PIXCLK with HCLK and needs its period above 2.5 HCLK
/// periods: at the H743's 240 MHz HCLK, 96 MHz; ST's datasheet gives 80 MHz
/// for the 8-bit bus. A board on a fanned-out bus sees every pixel clock of
/// the camera, whatever it crops.
pub const DCMI_MAX_PIXEL_CLOCK_HZ: f64 = 80.0e6;

/// Predicted Cortex-M instructions for a board's frame: `per_pixel` for
/// each pixel it captures plus `per_window` for each window it computes
/// (opening, attention stops and end), and `last_row_per_window` after the
/// frame's last pixel for each window of the last window row.
///
/// Fitted to the bench (docs/bench/cortex-m*.txt, QEMU -icount, exact):
/// the CANARY row (112x112, 49 windows of 16x16, N = 20) and the 8x8-window
/// row (196 windows on the same camera) give two equations in the two
/// unknowns; the last row is the CANARY row's over its 7 windows. A
/// configuration unlike these (another N, 32x32 windows, heavy noise) costs
/// up to ~20% more or less: `brightpix bench --config` measures it, and
/// `rig plan --instr-per-px` takes that figure instead.
///
/// A board whose camera interface hands the engine something other than
/// whole 16-bit rows pays for it: the STM32H743's DCMI writes 12-bit
/// pixels into a DMA ring, which its camera source copies out in runs (at
/// most 512 words, 1,024 pixels, cut at row ends) and the engine takes run
/// by run, checking each pixel against the bit depth
/// ([`CostModel::STM32H743`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostModel {
    pub per_pixel: f64,
    pub per_window: f64,
    pub last_row_per_window: f64,
    /// Per captured pixel, the board's camera interface beyond whole
    /// 16-bit rows (its camera source and runs); 0 for pixels in rows.
    pub camera_per_pixel: f64,
    /// After the frame's last pixel, whatever the windows: the camera
    /// interface's last piece (a board's last DMA run).
    pub last_row_per_frame: f64,
    /// The link that carries the board's results to the host; `None` for
    /// an emulated board (a pseudo-terminal, no rate of its own).
    pub link: Option<Link>,
}

impl CostModel {
    /// Cortex-M4: CANARY 11.63 instr/px, 8x8 windows 28.83, last row 2,680.
    pub const CORTEX_M4: CostModel = CostModel::fit(11.63, 28.83, 2680.0);
    /// Cortex-M7: CANARY 11.59 instr/px, 8x8 windows 28.81, last row 2,616.
    pub const CORTEX_M7: CostModel = CostModel::fit(11.59, 28.81, 2616.0);
    /// The STM32H743 (Cortex-M7) through its camera path: the bench's
    /// `canary-12bit-dcmi` row (12.20 instr/px, last row 3,915: the
    /// board's `DcmiSource` over a DMA ring, its runs, the 12-bit check)
    /// against its whole-row CANARY (11.59, 2,616) adds 0.61 instructions
    /// a pixel and 1,299 after the last pixel to the Cortex-M7's model.
    /// Its results leave on USB full speed ([`link::USB_FULL_SPEED`]).
    pub const STM32H743: CostModel = CostModel::CORTEX_M7
        .with_camera_runs(11.59, 2616.0, 12.20, 3915.0)
        .with_link(link::USB_FULL_SPEED);

    /// The model through the bench's two rows (see the type's documentation).
    pub const fn fit(canary: f64, windows_8x8: f64, canary_last_row: f64) -> CostModel {
        let pixels = 112.0 * 112.0;
        let per_window = (windows_8x8 - canary) * pixels / (196.0 - 49.0);
        CostModel {
            per_pixel: (canary * pixels - 49.0 * per_window) / pixels,
            per_window,
            last_row_per_window: canary_last_row / 7.0,
            camera_per_pixel: 0.0,
            last_row_per_frame: 0.0,
            link: None,
        }
    }

    /// This model with its results on `link`.
    pub const fn with_link(self, link: Link) -> CostModel {
        CostModel {
            link: Some(link),
            ..self
        }
    }

    /// This model with a link measured at `bytes_per_s` (`brightpix bench
    /// --port PORT --link`) instead of its own.
    pub fn with_measured_link(self, bytes_per_s: f64) -> CostModel {
        self.with_link(Link {
            name: "measured",
            bytes_per_s,
        })
    }

    /// [`with_measured_link`](Self::with_measured_link) of a rate given in
    /// MB/s, as `bench --port --link` prints it and `rig plan --link-rate`
    /// and rig.toml's `link_mb_per_s` take it; not a positive number: the
    /// error says so (its caller names the figure).
    pub fn with_link_rate(self, mb_per_s: f64) -> Result<CostModel, String> {
        if !(mb_per_s.is_finite() && mb_per_s > 0.0) {
            return Err("must be a positive number of MB/s".into());
        }
        Ok(self.with_measured_link(mb_per_s * 1e6))
    }

    /// This model for a board whose camera interface costs what the
    /// bench's camera-run row shows against its whole-row CANARY row (same
    /// core, same run): the difference per pixel, and after the last pixel.
    pub const fn with_camera_runs(
        self,
        canary: f64,
        canary_last_row: f64,
        runs: f64,
        runs_last_row: f64,
    ) -> CostModel {
        CostModel {
            camera_per_pixel: self.camera_per_pixel + (runs - canary),
            last_row_per_frame: self.last_row_per_frame + (runs_last_row - canary_last_row),
            ..self
        }
    }

    /// A flat `instr_per_px` for every captured pixel (a figure
    /// `brightpix bench --config` measured for the configuration itself,
    /// on whole rows), with `model`'s camera interface and last row.
    pub fn flat(instr_per_px: f64, model: &CostModel) -> CostModel {
        CostModel {
            per_pixel: instr_per_px,
            per_window: 0.0,
            ..*model
        }
    }

    /// Instructions after a frame's last pixel on a board with
    /// `windows_in_last_row` windows ending in its last row.
    pub fn last_row_instructions(&self, windows_in_last_row: usize) -> f64 {
        self.last_row_per_window * windows_in_last_row as f64 + self.last_row_per_frame
    }

    /// Instructions per frame of a board capturing `pixels` and computing
    /// `windows` windows.
    pub fn frame_instructions(&self, pixels: usize, windows: usize) -> f64 {
        (self.per_pixel + self.camera_per_pixel) * pixels as f64 + self.per_window * windows as f64
    }
}

/// The boards a rig can use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoardKind {
    /// The production board: Cortex-M7 at 480 MHz, DCMI crop.
    Stm32h743,
    /// The firmware in QEMU (mps2-an386, Cortex-M4): pixels from the host.
    QemuM4,
    /// The firmware in QEMU (mps2-an500, Cortex-M7): pixels from the host.
    QemuM7,
}

impl BoardKind {
    pub const ALL: [BoardKind; 3] = [BoardKind::Stm32h743, BoardKind::QemuM4, BoardKind::QemuM7];

    pub fn name(self) -> &'static str {
        match self {
            BoardKind::Stm32h743 => "stm32h743",
            BoardKind::QemuM4 => "qemu-m4",
            BoardKind::QemuM7 => "qemu-m7",
        }
    }

    pub fn parse(text: &str) -> Result<BoardKind, String> {
        BoardKind::ALL
            .into_iter()
            .find(|k| k.name() == text)
            .ok_or_else(|| {
                format!("unknown board {text:?}; expected stm32h743, qemu-m4 or qemu-m7")
            })
    }

    /// The core's clock, MHz; `None` for an emulated board (no real time).
    pub fn clock_mhz(self) -> Option<f64> {
        match self {
            BoardKind::Stm32h743 => Some(480.0),
            BoardKind::QemuM4 | BoardKind::QemuM7 => None,
        }
    }

    pub fn cost_model(self) -> CostModel {
        match self {
            BoardKind::Stm32h743 => CostModel::STM32H743,
            BoardKind::QemuM4 => CostModel::CORTEX_M4,
            BoardKind::QemuM7 => CostModel::CORTEX_M7,
        }
    }

    /// Pixels the crop's width must be a multiple of: the DCMI's (4 at
    /// every bit depth, `brightpix_firmware::camera::crop`). The QEMU
    /// boards' simulated camera crops any width.
    pub fn width_multiple(self) -> u16 {
        match self {
            BoardKind::Stm32h743 => DCMI_WIDTH_MULTIPLE,
            BoardKind::QemuM4 | BoardKind::QemuM7 => 1,
        }
    }

    /// Why this board's camera interface cannot crop `rect` of `camera`,
    /// if it cannot: the firmware's own rules, which the board applies
    /// again when it is configured (`Error(Crop)` at `ConfigBegin`). The
    /// STM32H743's DCMI with the narrowest mode that holds the bit depth;
    /// the QEMU boards' simulated camera with its 16-bit bus.
    pub fn check_crop(self, rect: &Rectangle, camera: &Camera) -> Result<(), String> {
        let part = Camera {
            width: rect.width,
            height: rect.height,
            bit_depth: camera.bit_depth,
        };
        let crop = Crop {
            x: rect.x,
            y: rect.y,
            sensor_width: camera.width,
            sensor_height: camera.height,
        };
        let verdict = match self {
            BoardKind::Stm32h743 => dcmi_check(DataWidth::holding(camera.bit_depth), part, crop),
            BoardKind::QemuM4 | BoardKind::QemuM7 => {
                frame_check(part, DataWidth::Bits16.pixels_per_word())
            }
        };
        verdict.map_err(|e| format!("the {}'s camera interface cannot crop it: {e}", self.name()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The model's constants are the bench tables' figures: regenerating
    /// the tables with other figures fails here until they are updated;
    /// and each model reproduces the rows it was fitted to.
    #[test]
    fn cost_model_is_the_bench_tables() {
        for (file, model) in [
            ("cortex-m4.txt", CostModel::CORTEX_M4),
            ("cortex-m7.txt", CostModel::CORTEX_M7),
        ] {
            let path = format!("{}/../docs/bench/{file}", env!("CARGO_MANIFEST_DIR"));
            let text = std::fs::read_to_string(&path).unwrap();
            let row = |name: &str| -> (f64, f64) {
                let line = text
                    .lines()
                    .find(|l| l.split_whitespace().next() == Some(name))
                    .unwrap_or_else(|| panic!("{path}: no row {name}"));
                let cols: Vec<&str> = line.split_whitespace().collect();
                (cols[1].parse().unwrap(), cols[4].parse().unwrap())
            };
            let (canary, last_row) = row("canary-subtract-next-n20");
            let (small, _) = row("windows-8x8-n20");
            assert_eq!(model, CostModel::fit(canary, small, last_row), "{file}");
            // The fit reproduces both rows.
            assert!((model.frame_instructions(12544, 49) / 12544.0 - canary).abs() < 1e-9);
            assert!((model.frame_instructions(12544, 196) / 12544.0 - small).abs() < 1e-9);
            if file == "cortex-m7.txt" {
                let (runs, runs_last_row) = row("canary-12bit-dcmi");
                let h = CostModel::STM32H743;
                assert_eq!(
                    h,
                    model
                        .with_camera_runs(canary, last_row, runs, runs_last_row)
                        .with_link(link::USB_FULL_SPEED)
                );
                // The board's model reproduces its own row.
                assert!((h.frame_instructions(12544, 49) / 12544.0 - runs).abs() < 1e-9);
                assert!((h.last_row_instructions(7) - runs_last_row).abs() < 1e-6);
            }
        }
        assert_eq!(BoardKind::Stm32h743.cost_model(), CostModel::STM32H743);
        assert_eq!(BoardKind::QemuM7.cost_model(), CostModel::CORTEX_M7);
    }
}
