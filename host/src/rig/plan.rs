//! Splitting one camera's sub-apertures over several boards of one kind
//! ([`super::board`]), and what each board of a split is predicted to do.
//!
//! The plan cuts the sensor into bands of rows between which no window
//! crosses (columns when rows alone cannot give the boards an even share),
//! balancing the predicted instructions per frame; when a camera rate is
//! given and no such cut keeps up but runs of windows in raster order do
//! (a link-bound board's results follow its count of windows), those. Each
//! board captures the bounding rectangle of its windows, widened as its
//! crop hardware needs.

use brightpix_protocol::{Camera, SubapertureWindow};

use super::board::{BoardKind, CostModel};
use super::link::{self, ResultBounds};
use super::part::Rectangle;
use crate::config_file::ProcessingConfig;

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
    /// Bands of rows between which no window crosses.
    Rows,
    /// Strips of columns between which no window crosses.
    Columns,
    /// The windows in raster order (first row, then column), cut anywhere
    /// into runs whose counts differ by one at most: a board's rectangle
    /// is its run's bounding box, so neighbours' rectangles overlap where a
    /// run ends inside a row of windows (each board still computes only its
    /// own). Taken only when whole bands leave some board's link or core
    /// behind and such runs do not ([`plan_keeping_up`]): a link-bound
    /// board's results follow its count of windows, which bands can only
    /// share out a row of windows at a time.
    Raster,
}

impl Cut {
    pub fn describe(self) -> &'static str {
        match self {
            Cut::Rows => "row bands",
            Cut::Columns => "column strips",
            Cut::Raster => "runs of windows in raster order (neighbouring rectangles overlap)",
        }
    }
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
        Cut::Raster => unreachable!("raster runs are not bands"),
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

/// `config`'s windows over `boards` boards of `kind` as runs in raster
/// order ([`Cut::Raster`]): the first `n mod boards` runs one window longer,
/// so the board that ends the frame has the fewer windows to finish after
/// its last pixel.
fn raster(config: &ProcessingConfig, boards: usize, kind: BoardKind) -> Result<Plan, String> {
    let windows = &config.windows;
    let n = windows.len();
    if boards == 0 || boards > n {
        return Err(format!("{n} windows cannot make {boards} runs"));
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&k| (windows[k].y, windows[k].x, k));
    let shares = (0..boards)
        .map(|b| {
            let run = (b * n).div_ceil(boards)..((b + 1) * n).div_ceil(boards);
            let mut members = order[run].to_vec();
            members.sort_unstable();
            let rectangle = rectangle_for(windows, &members, &config.camera, kind)?;
            Ok(BoardShare {
                rectangle,
                windows: members,
            })
        })
        .collect::<Result<Vec<_>, String>>()?;
    Ok(Plan {
        cut: Cut::Raster,
        shares,
    })
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
                cut.describe()
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
/// up with `camera_rate`, its core and its link ([`BoardLoad::keeps_up`]):
/// bands ([`plan`]), else runs of windows in raster order ([`Cut::Raster`])
/// if those keep up; `boards` itself when the rate is unknown. The error
/// names the fix.
pub fn plan_keeping_up(
    config: &ProcessingConfig,
    boards: usize,
    kind: BoardKind,
    model: &CostModel,
    camera_rate: Option<f64>,
) -> Result<(Plan, Vec<BoardLoad>), PlanError> {
    let bounds = ResultBounds::of(config);
    let loads_of =
        |p: &Plan| loads_with(config, &bounds, &p.shares, kind, model, camera_rate, false);
    // Bands first; runs in raster order only where they keep up and the
    // bands do not (or cannot be cut for `k` boards).
    let plan_k = |k: usize| -> Result<(Plan, Vec<BoardLoad>), PlanError> {
        let banded = plan(config, k, kind, model).map(|p| {
            let l = loads_of(&p);
            (p, l)
        });
        if banded
            .as_ref()
            .is_ok_and(|(_, l)| l.iter().all(BoardLoad::keeps_up))
            || camera_rate.is_none()
        {
            return banded;
        }
        if let Ok(p) = raster(config, k, kind) {
            let l = loads_of(&p);
            // Runs that fall behind too are still a split of `k` boards
            // where bands are none: the caller then names the count that
            // keeps up, not "fewer boards".
            if l.iter().all(BoardLoad::keeps_up) || banded.is_err() {
                return Ok((p, l));
            }
        }
        banded
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

    /// 240x240 of 16x16 windows at 2 kHz on USB full speed: whole bands
    /// need more boards than runs of windows in raster order, which share
    /// the windows out to one (and so the link's load); every window is on
    /// exactly one board, inside its rectangle; where runs keep up, bands
    /// still come first.
    #[test]
    fn raster_runs_when_bands_leave_a_link_behind() {
        let mut config = crate::bench::workloads::ocam240_config();
        config.camera.bit_depth = 12;
        let (kind, model) = (BoardKind::Stm32h743, CostModel::STM32H743);
        let needed = |p: Result<(Plan, Vec<BoardLoad>), PlanError>| match p {
            Ok((p, _)) => p.shares.len(),
            Err(e) => boards_named(&e.to_string()),
        };
        let k = needed(plan_keeping_up(&config, 2, kind, &model, Some(2000.0)));
        let (p, loads) = plan_keeping_up(&config, k, kind, &model, Some(2000.0)).unwrap();
        assert_eq!(p.cut, Cut::Raster);
        assert!(loads.iter().all(BoardLoad::keeps_up));
        // Bands alone: one board of `k` falls behind on its link.
        let banded = plan(&config, k, kind, &model).unwrap();
        let banded_loads = super::loads(&config, &banded.shares, kind, &model, Some(2000.0), false);
        assert!(banded_loads.iter().any(|l| l.link_load.unwrap() > 1.0));
        let counts: Vec<usize> = p.shares.iter().map(|s| s.windows.len()).collect();
        let (least, most) = (counts.iter().min().unwrap(), counts.iter().max().unwrap());
        assert!(most - least <= 1, "{counts:?}");
        let mut seen = vec![0; config.windows.len()];
        for s in &p.shares {
            for &w in &s.windows {
                seen[w] += 1;
                assert!(s.rectangle.holds(&config.windows[w]));
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
        // Some neighbours overlap: a run ends inside a row of windows.
        assert!(p
            .shares
            .windows(2)
            .any(|w| w[0].rectangle.y + w[0].rectangle.height > w[1].rectangle.y));
        // At 1 kHz three boards of bands keep up: bands.
        let (p, _) = plan_keeping_up(&config, 3, kind, &model, Some(1000.0)).unwrap();
        assert_eq!(p.cut, Cut::Rows);
    }

    /// More boards than CANARY's seven bands, at a rate that eight runs
    /// cannot serve either: the error names the count that keeps up (runs),
    /// not "fewer boards"; without a rate, eight boards are refused as
    /// before (no bands to give them).
    #[test]
    fn more_boards_than_bands_names_the_count_that_keeps_up() {
        let config = canary();
        let (kind, model) = (BoardKind::Stm32h743, CostModel::STM32H743);
        let text = plan_keeping_up(&config, 8, kind, &model, Some(15000.0))
            .unwrap_err()
            .to_string();
        assert!(text.contains("cannot keep up"), "{text}");
        let k = boards_named(&text);
        assert!(k > 8, "{text}");
        let (p, _) = plan_keeping_up(&config, k, kind, &model, Some(15000.0)).unwrap();
        assert_eq!(p.cut, Cut::Raster);
        let text = plan_keeping_up(&config, 8, kind, &model, None)
            .unwrap_err()
            .to_string();
        assert!(text.contains("cannot give 8 boards"), "{text}");
    }
}
