//! Splitting one camera's sub-apertures over several boards: the boards
//! a rig can use (their crop rules and clocks), the cost model that
//! predicts a board's load from the bench, and the plan itself.
//!
//! The plan cuts the sensor into bands of rows between which no window
//! crosses (columns when rows alone cannot give the boards an even share),
//! balancing the predicted instructions per frame; each board captures the
//! bounding rectangle of its windows, widened as its crop hardware needs.

use brightpix_firmware::camera::crop::{frame_check, DCMI_WIDTH_MULTIPLE};
use brightpix_firmware::camera::{dcmi_check, DataWidth};
use brightpix_protocol::{Camera, Crop, SubapertureWindow};

use super::link::{self, Link, ResultBounds};
use super::part::Rectangle;
use crate::config_file::ProcessingConfig;

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

/// One board's share in a plan.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardShare {
    pub rectangle: Rectangle,
    /// Whole-camera window indices, ascending (the board's output order).
    pub windows: Vec<usize>,
}

/// What a board of a plan is predicted to do.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardLoad {
    pub instructions_per_frame: f64,
    /// Instructions after the frame's last pixel (its last window row).
    pub last_row_instructions: f64,
    /// Fraction of the core's cycles at the camera rate (one instruction a
    /// cycle), when both are known.
    pub load: Option<f64>,
    /// Results on the link, bytes a frame: each result at the largest
    /// slopes and flux its configuration allows ([`link::frame_bytes`]).
    pub result_bytes_per_frame: usize,
    /// The same a second at the camera rate.
    pub result_bytes_per_s: Option<f64>,
    /// Fraction of the board's link those take, when both are known.
    pub link_load: Option<f64>,
}

impl BoardLoad {
    /// Whether the board keeps up: its core and its link, where known.
    pub fn keeps_up(&self) -> bool {
        self.load.is_none_or(|l| l <= 1.0) && self.link_load.is_none_or(|l| l <= 1.0)
    }
}

/// How the plan cut the sensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cut {
    Rows,
    Columns,
}

/// Boards' shares of one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub cut: Cut,
    pub shares: Vec<BoardShare>,
}

/// Why a camera cannot be split.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PlanError {
    #[error("{0}")]
    Split(String),
    #[error("{0}")]
    TooSlow(String),
}

/// Window indices grouped into bands along one axis: windows whose spans
/// overlap share a band, so a cut between bands crosses no window.
fn bands(windows: &[SubapertureWindow], axis: Cut) -> Vec<Vec<usize>> {
    let span = |w: &SubapertureWindow| match axis {
        Cut::Rows => (w.y as u32, w.y as u32 + w.height as u32),
        Cut::Columns => (w.x as u32, w.x as u32 + w.width as u32),
    };
    let mut order: Vec<usize> = (0..windows.len()).collect();
    order.sort_by_key(|&k| span(&windows[k]));
    let mut out: Vec<Vec<usize>> = Vec::new();
    let mut end = 0;
    for k in order {
        let (start, stop) = span(&windows[k]);
        match out.last_mut() {
            Some(band) if start < end => band.push(k),
            _ => out.push(vec![k]),
        }
        end = end.max(stop);
    }
    out
}

/// The rectangle a board needs for `windows`: their bounding box, widened
/// to the board's width multiple (to the right, else to the left).
fn rectangle_for(
    windows: &[SubapertureWindow],
    members: &[usize],
    camera: &Camera,
    board: BoardKind,
) -> Result<Rectangle, String> {
    let x0 = members.iter().map(|&k| windows[k].x).min().unwrap_or(0);
    let y0 = members.iter().map(|&k| windows[k].y).min().unwrap_or(0);
    let x1 = members
        .iter()
        .map(|&k| windows[k].x + windows[k].width)
        .max()
        .unwrap_or(0);
    let y1 = members
        .iter()
        .map(|&k| windows[k].y + windows[k].height)
        .max()
        .unwrap_or(0);
    let multiple = board.width_multiple();
    let width = (x1 - x0).div_ceil(multiple) * multiple;
    if width > camera.width {
        return Err(format!(
            "the {} needs a width that is a multiple of {multiple} pixels, and the {}-pixel-wide camera holds no such rectangle around windows {}..{} of columns {x0}..{x1}",
            board.name(),
            camera.width,
            members.first().unwrap_or(&0),
            members.last().unwrap_or(&0)
        ));
    }
    // The narrowest rectangle the board can crop: wider by a multiple at a
    // time when its frame is not whole words or bursts (an odd height).
    let mut last = String::new();
    for width in (width..=camera.width).step_by(multiple as usize).take(4) {
        let rect = Rectangle {
            x: x0.min(camera.width - width),
            y: y0,
            width,
            height: y1 - y0,
        };
        match board.check_crop(&rect, camera) {
            Ok(()) => return Ok(rect),
            Err(e) => last = format!("rectangle {}: {e}", rect.describe()),
        }
    }
    Err(last)
}

/// The shares of `boards` contiguous groups of `bands` that minimise the
/// largest predicted cost (dynamic programming over the cut points).
fn balance(
    config: &ProcessingConfig,
    bands: &[Vec<usize>],
    boards: usize,
    kind: BoardKind,
    model: &CostModel,
) -> Result<Vec<BoardShare>, String> {
    let n = bands.len();
    // share(i, j): bands i..j on one board.
    let share = |i: usize, j: usize| -> Result<(BoardShare, f64), String> {
        let mut members: Vec<usize> = bands[i..j].iter().flatten().copied().collect();
        members.sort_unstable();
        let rectangle = rectangle_for(&config.windows, &members, &config.camera, kind)?;
        let cost = model.frame_instructions(rectangle.pixels(), members.len());
        Ok((
            BoardShare {
                rectangle,
                windows: members,
            },
            cost,
        ))
    };
    let mut cost = vec![vec![0.0f64; n + 1]; n + 1];
    for (i, row) in cost.iter_mut().enumerate() {
        for (j, c) in row.iter_mut().enumerate().skip(i + 1) {
            *c = share(i, j)?.1;
        }
    }
    // best[b][j]: the least largest cost of bands 0..j on b boards.
    let mut best = vec![vec![f64::INFINITY; n + 1]; boards + 1];
    let mut from = vec![vec![0usize; n + 1]; boards + 1];
    best[0][0] = 0.0;
    for b in 1..=boards {
        for j in b..=n {
            for i in b - 1..j {
                let c = best[b - 1][i].max(cost[i][j]);
                if c < best[b][j] {
                    best[b][j] = c;
                    from[b][j] = i;
                }
            }
        }
    }
    let mut cuts = vec![n];
    let mut j = n;
    for b in (1..=boards).rev() {
        j = from[b][j];
        cuts.push(j);
    }
    cuts.reverse();
    cuts.windows(2).map(|c| Ok(share(c[0], c[1])?.0)).collect()
}

/// Splits `config`'s windows over `boards` boards of `kind`: row bands
/// when the windows fall into at least `boards` of them and they balance
/// as well as column strips, else column strips.
pub fn plan(
    config: &ProcessingConfig,
    boards: usize,
    kind: BoardKind,
    model: &CostModel,
) -> Result<Plan, PlanError> {
    if boards == 0 {
        return Err(PlanError::Split("a rig needs at least one board".into()));
    }
    let largest = |shares: &[BoardShare]| {
        shares
            .iter()
            .map(|s| model.frame_instructions(s.rectangle.pixels(), s.windows.len()))
            .fold(0.0, f64::max)
    };
    let mut candidates = Vec::new();
    let mut why = Vec::new();
    for cut in [Cut::Rows, Cut::Columns] {
        let bands = bands(&config.windows, cut);
        if bands.len() < boards {
            why.push(format!(
                "the windows fall into {} {} that no cut crosses",
                bands.len(),
                match cut {
                    Cut::Rows => "row bands",
                    Cut::Columns => "column strips",
                }
            ));
            continue;
        }
        match balance(config, &bands, boards, kind, model) {
            Ok(shares) => candidates.push((largest(&shares), cut, shares)),
            Err(e) => why.push(e),
        }
    }
    // Rows unless columns are clearly better (10%): row bands keep whole
    // camera rows together, as the DCMI delivers them.
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let pick = match candidates.as_slice() {
        [] => None,
        [only] => Some(only),
        [first, second] => {
            let rows = if first.1 == Cut::Rows { first } else { second };
            let columns = if first.1 == Cut::Rows { second } else { first };
            Some(if columns.0 * 1.1 < rows.0 {
                columns
            } else {
                rows
            })
        }
        _ => unreachable!("two ways to cut"),
    };
    match pick {
        Some((_, cut, shares)) => Ok(Plan {
            cut: *cut,
            shares: shares.clone(),
        }),
        None => Err(PlanError::Split(format!(
            "cannot give {boards} boards a share of {} windows each without cutting a window: {}; use fewer boards",
            config.windows.len(),
            why.join("; ")
        ))),
    }
}

/// What each board of `shares` is predicted to do at `camera_rate` Hz;
/// `edge_rows`: the boards share rows and send their checksums every frame.
pub fn loads(
    config: &ProcessingConfig,
    shares: &[BoardShare],
    kind: BoardKind,
    model: &CostModel,
    camera_rate: Option<f64>,
    edge_rows: bool,
) -> Vec<BoardLoad> {
    let bounds = ResultBounds::of(config);
    loads_with(config, &bounds, shares, kind, model, camera_rate, edge_rows)
}

/// [`loads`] with the results' bounds computed once.
fn loads_with(
    config: &ProcessingConfig,
    bounds: &ResultBounds,
    shares: &[BoardShare],
    kind: BoardKind,
    model: &CostModel,
    camera_rate: Option<f64>,
    edge_rows: bool,
) -> Vec<BoardLoad> {
    shares
        .iter()
        .map(|s| {
            let windows: Vec<&SubapertureWindow> =
                s.windows.iter().map(|&k| &config.windows[k]).collect();
            let last = windows.iter().map(|w| w.last_row()).max().unwrap_or(0);
            let in_last_row = windows.iter().filter(|w| w.last_row() == last).count();
            let instructions = model.frame_instructions(s.rectangle.pixels(), s.windows.len());
            let result_bytes_per_frame = link::frame_bytes(config, bounds, &s.windows, edge_rows);
            let result_bytes_per_s = camera_rate.map(|rate| result_bytes_per_frame as f64 * rate);
            BoardLoad {
                instructions_per_frame: instructions,
                last_row_instructions: model.last_row_instructions(in_last_row),
                load: camera_rate
                    .zip(kind.clock_mhz())
                    .map(|(rate, mhz)| instructions * rate / (mhz * 1e6)),
                result_bytes_per_frame,
                result_bytes_per_s,
                link_load: result_bytes_per_s
                    .zip(model.link)
                    .map(|(bytes, link)| bytes / link.bytes_per_s),
            }
        })
        .collect()
}

/// Plans with the fewest boards (from `boards` up) whose every board keeps
/// up with `camera_rate`, its core and its link ([`BoardLoad::keeps_up`]);
/// `boards` itself when the rate is unknown. The error names the fix.
pub fn plan_keeping_up(
    config: &ProcessingConfig,
    boards: usize,
    kind: BoardKind,
    model: &CostModel,
    camera_rate: Option<f64>,
) -> Result<(Plan, Vec<BoardLoad>), PlanError> {
    let bounds = ResultBounds::of(config);
    let plan_k = |k: usize| -> Result<(Plan, Vec<BoardLoad>), PlanError> {
        let p = plan(config, k, kind, model)?;
        let l = loads_with(config, &bounds, &p.shares, kind, model, camera_rate, false);
        Ok((p, l))
    };
    let (p, l) = plan_k(boards)?;
    if l.iter().all(BoardLoad::keeps_up) {
        return Ok((p, l));
    }
    let enough = (boards + 1..=boards.max(1) * 256)
        .take_while(|&k| k <= config.windows.len())
        .find(|&k| plan_k(k).is_ok_and(|(_, l)| l.iter().all(BoardLoad::keeps_up)));
    Err(PlanError::TooSlow(format!(
        "{boards} {} boards cannot keep up with this camera at {} Hz: {}; {}",
        kind.name(),
        camera_rate.unwrap_or(0.0),
        busiest(&l, kind, model),
        match enough {
            Some(k) => format!("{k} boards keep up (--boards {k}), or a lower camera rate"),
            None => "no split of these windows keeps up: lower the camera rate".to_string(),
        }
    )))
}

/// What the busiest boards of `loads` would need of their core and link
/// (`model`'s).
pub fn busiest(loads: &[BoardLoad], kind: BoardKind, model: &CostModel) -> String {
    let most = |f: fn(&BoardLoad) -> Option<f64>| loads.iter().filter_map(f).reduce(f64::max);
    let mut parts = Vec::new();
    if let (Some(core), Some(mhz)) = (most(|l| l.load), kind.clock_mhz()) {
        parts.push(format!(
            "the busiest would need {:.0}% of its {mhz} MHz core",
            core * 100.0
        ));
    }
    if let (Some(link), Some(bytes), Some(spec)) = (
        most(|l| l.link_load),
        most(|l| l.result_bytes_per_s),
        model.link,
    ) {
        parts.push(format!(
            "the one with most results sends up to {:.2} MB/s, {:.0}% of its {} link (about {:.2} MB/s)",
            bytes / 1e6,
            link * 100.0,
            spec.name,
            spec.bytes_per_s / 1e6
        ));
    }
    parts.join(", and ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use brightpix_protocol::RegularGrid;

    fn canary() -> ProcessingConfig {
        crate::sil::canary_config()
    }

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

    #[test]
    fn canary_in_three_row_bands() {
        let config = canary();
        let plan = plan(&config, 3, BoardKind::Stm32h743, &CostModel::CORTEX_M7).unwrap();
        assert_eq!(plan.cut, Cut::Rows);
        let counts: Vec<usize> = plan.shares.iter().map(|s| s.windows.len()).collect();
        // 7 rows of 7 windows: 2 + 2 + 3 rows (or a permutation).
        let mut sorted = counts.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, [14, 14, 21], "{counts:?}");
        let mut all: Vec<usize> = plan.shares.iter().flat_map(|s| s.windows.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..49).collect::<Vec<_>>());
        for s in &plan.shares {
            assert_eq!(s.rectangle.width, 112);
            for &k in &s.windows {
                assert!(s.rectangle.holds(&config.windows[k]));
            }
        }
    }

    #[test]
    fn one_row_of_windows_splits_into_columns() {
        let camera = Camera {
            width: 128,
            height: 16,
            bit_depth: 12,
        };
        let grid = RegularGrid {
            x: 0,
            y: 0,
            columns: 8,
            rows: 1,
            width: 16,
            height: 16,
            pitch_x: 16,
            pitch_y: 16,
        };
        let config = ProcessingConfig::from_grid(camera, grid, &[]);
        let plan = plan(&config, 2, BoardKind::Stm32h743, &CostModel::CORTEX_M7).unwrap();
        assert_eq!(plan.cut, Cut::Columns);
        assert_eq!(plan.shares[0].windows, [0, 1, 2, 3]);
        assert_eq!(plan.shares[1].rectangle.x, 64);
        let err = super::plan(&config, 9, BoardKind::Stm32h743, &CostModel::CORTEX_M7).unwrap_err();
        assert!(err.to_string().contains("cannot give 9 boards"), "{err}");
    }

    #[test]
    fn crop_widths_follow_the_dcmi() {
        // 8-bit camera, windows 6 wide: the rectangle widens to 8 (a word).
        let camera = Camera {
            width: 30,
            height: 12,
            bit_depth: 8,
        };
        let windows = vec![
            SubapertureWindow {
                x: 1,
                y: 0,
                width: 6,
                height: 6,
            },
            SubapertureWindow {
                x: 1,
                y: 6,
                width: 6,
                height: 6,
            },
        ];
        let config = ProcessingConfig::new(camera, windows);
        let p = plan(&config, 2, BoardKind::Stm32h743, &CostModel::CORTEX_M7).unwrap();
        assert_eq!(
            p.shares[0].rectangle,
            Rectangle {
                x: 1,
                y: 0,
                width: 8,
                height: 6
            }
        );
        let q = plan(&config, 2, BoardKind::QemuM4, &CostModel::CORTEX_M4).unwrap();
        assert_eq!(q.shares[0].rectangle.width, 6);
        let odd = Rectangle {
            x: 0,
            y: 0,
            width: 6,
            height: 4,
        };
        let camera = |bit_depth| Camera {
            width: 40,
            height: 30,
            bit_depth,
        };
        for bit_depth in [8, 12] {
            let e = BoardKind::Stm32h743
                .check_crop(&odd, &camera(bit_depth))
                .unwrap_err();
            assert!(e.contains("multiple of 4"), "{e}");
        }
        let square = Rectangle { width: 8, ..odd };
        assert!(BoardKind::Stm32h743
            .check_crop(&square, &camera(12))
            .is_ok());
        // 32 pixels: two bursts of the 8-bit bus (16 pixels each); 24 are not.
        assert!(BoardKind::Stm32h743.check_crop(&square, &camera(8)).is_ok());
        let short = Rectangle {
            height: 3,
            ..square
        };
        let e = BoardKind::Stm32h743
            .check_crop(&short, &camera(8))
            .unwrap_err();
        assert!(e.contains("24 pixels") && e.contains("16"), "{e}");
        assert!(BoardKind::QemuM4.check_crop(&short, &camera(8)).is_ok());
    }

    /// The K of "(--boards K)" in a plan's error.
    fn boards_named(text: &str) -> usize {
        text.split("(--boards ")
            .nth(1)
            .and_then(|t| t.split(|c: char| !c.is_ascii_digit()).next())
            .unwrap()
            .parse()
            .unwrap()
    }

    #[test]
    fn too_slow_names_the_boards_needed() {
        // 240x240 of 16x16 windows (the bench's OCAM2K-class workload) at 2 kHz: 115 Mpx/s.
        let config = crate::bench::workloads::ocam240_config();
        let model = CostModel::CORTEX_M7;
        let e =
            plan_keeping_up(&config, 2, BoardKind::Stm32h743, &model, Some(2000.0)).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("cannot keep up") && text.contains("boards keep up (--boards"),
            "{text}"
        );
        let k = boards_named(&text);
        let (_, loads) =
            plan_keeping_up(&config, k, BoardKind::Stm32h743, &model, Some(2000.0)).unwrap();
        assert!(loads.iter().all(BoardLoad::keeps_up));
        assert!(
            plan_keeping_up(&config, k - 1, BoardKind::Stm32h743, &model, Some(2000.0)).is_err()
        );
    }

    /// A 240x240 12-bit camera at 1 kHz: two STM32H743 cores keep up, but
    /// not their USB links, so the plan asks for the boards the links need.
    #[test]
    fn the_link_counts_as_well_as_the_core() {
        let mut config = crate::bench::workloads::ocam240_config();
        config.camera.bit_depth = 12;
        let (kind, model) = (BoardKind::Stm32h743, CostModel::STM32H743);
        let two = plan(&config, 2, kind, &model).unwrap();
        let loads = loads(&config, &two.shares, kind, &model, Some(1000.0), false);
        assert!(loads.iter().all(|l| l.load.unwrap() <= 1.0));
        assert!(loads.iter().any(|l| l.link_load.unwrap() > 1.0));
        let text = plan_keeping_up(&config, 2, kind, &model, Some(1000.0))
            .unwrap_err()
            .to_string();
        assert!(text.contains("of its USB full speed link"), "{text}");
        let k = boards_named(&text);
        let (_, loads) = plan_keeping_up(&config, k, kind, &model, Some(1000.0)).unwrap();
        assert!(loads.iter().all(|l| l.link_load.unwrap() <= 1.0));
        // A link measured at twice USB full speed: two boards keep up; at
        // half of it, more boards than at USB full speed.
        let fast = model.with_measured_link(2.0e6);
        let (p, _) = plan_keeping_up(&config, 2, kind, &fast, Some(1000.0)).unwrap();
        assert_eq!(p.shares.len(), 2);
        let slow = model.with_measured_link(0.5e6);
        let text = plan_keeping_up(&config, k, kind, &slow, Some(1000.0))
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("of its measured link (about 0.50 MB/s)"),
            "{text}"
        );
        assert!(boards_named(&text) > k, "{text}");
        // The emulated boards have no link rate of their own.
        let qemu = loads_with(
            &config,
            &ResultBounds::of(&config),
            &two.shares,
            BoardKind::QemuM7,
            &CostModel::CORTEX_M7,
            Some(1000.0),
            false,
        );
        assert!(qemu.iter().all(|l| l.link_load.is_none()));
    }
}
