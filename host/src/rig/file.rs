//! `rig.toml`: a rig as a file people can read and edit: the whole
//! camera's configuration, the board kind, and per board its name, port,
//! rectangle and sub-apertures. Loading it checks everything a wrong edit
//! can break (a window on no board or on two, a window outside its board's
//! rectangle, a rectangle the board cannot crop, two boards on one port)
//! before any device is touched.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::board::{BoardKind, CostModel};
use super::part::{board_config, Rectangle};
use super::plan::{BoardLoad, BoardShare, Plan};
use crate::config_file::ProcessingConfig;

/// One board of a loaded rig.
#[derive(Clone, Debug)]
pub struct RigBoard {
    pub name: String,
    /// Its serial port, when the file gives one.
    pub port: Option<String>,
    pub rectangle: Rectangle,
    /// Whole-camera window indices, in the board's output order.
    pub windows: Vec<usize>,
    /// The board's own configuration: its camera is the rectangle.
    pub config: ProcessingConfig,
}

/// A loaded, checked rig.
#[derive(Clone, Debug)]
pub struct Rig {
    /// The whole camera's configuration.
    pub whole: ProcessingConfig,
    /// Its file, as the rig names it (resolved against the rig's directory).
    pub config_file: Option<PathBuf>,
    pub kind: BoardKind,
    pub camera_rate_hz: Option<f64>,
    /// The boards' results link as measured (`brightpix bench --port PORT
    /// --link`), MB/s; `None`: the board kind's own.
    pub link_mb_per_s: Option<f64>,
    pub boards: Vec<RigBoard>,
    /// The sync line wired to every board (`[sync]`), if the rig has one.
    pub sync: Option<RigSync>,
}

/// `[sync]`: a line wired to every board (on the STM32H743 PF13,
/// firmware/boards/stm32h743 `sync.rs`), driven by one of them, so that all
/// start a capture on the same camera frame (PROTOCOL.md §9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RigSync {
    /// Index of the board that drives the line (`leader = "NAME"`).
    pub leader: usize,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RigToml {
    config: PathBuf,
    board: String,
    camera_rate_hz: Option<f64>,
    link_mb_per_s: Option<f64>,
    sync: Option<SyncToml>,
    #[serde(default)]
    boards: Vec<BoardToml>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SyncToml {
    leader: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardToml {
    name: String,
    port: Option<String>,
    rectangle: Rectangle,
    subapertures: Vec<usize>,
}

/// Why a rig file was refused; the message names the file.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", file.display())]
pub struct RigError {
    pub file: PathBuf,
    pub message: String,
}

impl Rig {
    /// Loads `path`, its whole-camera configuration (relative to the rig's
    /// directory) and checks the split.
    pub fn load(path: &Path) -> Result<Rig, RigError> {
        let fail = |message: String| RigError {
            file: path.to_path_buf(),
            message,
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| fail(format!("cannot read the rig file: {e}")))?;
        let file: RigToml =
            toml::from_str(&text).map_err(|e| fail(format!("not a rig file: {e}")))?;
        let config_path = path.parent().unwrap_or(Path::new(".")).join(&file.config);
        let whole = ProcessingConfig::load(&config_path)
            .map_err(|e| fail(format!("its configuration: {e}")))?;
        let kind = BoardKind::parse(&file.board).map_err(|e| fail(format!("board: {e}")))?;
        let boards = file
            .boards
            .into_iter()
            .map(|b| (b.name, b.port, b.rectangle, b.subapertures))
            .collect();
        let mut rig = Rig::from_parts(whole, kind, file.camera_rate_hz, boards).map_err(fail)?;
        if let Some(rate) = file.link_mb_per_s {
            kind.cost_model()
                .with_link_rate(rate)
                .map_err(|e| fail(format!("link_mb_per_s = {rate}: {e}")))?;
            rig.link_mb_per_s = Some(rate);
        }
        if let Some(sync) = file.sync {
            rig.set_sync_leader(&sync.leader).map_err(fail)?;
        }
        rig.config_file = Some(config_path);
        Ok(rig)
    }

    /// What a board of this rig costs: its kind's model, with the link as
    /// measured if the rig says.
    pub fn cost_model(&self) -> CostModel {
        let model = self.kind.cost_model();
        match self.link_mb_per_s {
            // Checked when loaded or planned.
            Some(rate) => model.with_measured_link(rate * 1e6),
            None => model,
        }
    }

    /// Each board's rectangle and windows, as the cost model takes them
    /// ([`super::loads`]).
    pub fn shares(&self) -> Vec<BoardShare> {
        self.boards
            .iter()
            .map(|b| BoardShare {
                rectangle: b.rectangle,
                windows: b.windows.clone(),
            })
            .collect()
    }

    /// Pairs of boards `(above, below)` whose rectangles share one camera
    /// row, the last of `above` and the first of `below`, over the same
    /// columns: on the same camera frame both see the same pixels there,
    /// which `rig capture` checks frame by frame (`EdgeRows`, PROTOCOL.md
    /// §9) without any wiring.
    pub fn shared_rows(&self) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        for (a, above) in self.boards.iter().enumerate() {
            for (b, below) in self.boards.iter().enumerate() {
                let (ra, rb) = (above.rectangle, below.rectangle);
                if a != b
                    && (ra.x, ra.width) == (rb.x, rb.width)
                    && u32::from(ra.y) + u32::from(ra.height) == u32::from(rb.y) + 1
                {
                    pairs.push((a, b));
                }
            }
        }
        pairs
    }

    /// The rig with each band of rows reaching one row into the band below
    /// it (same columns), so that neighbours share a camera row
    /// ([`Rig::shared_rows`]); refused if a board cannot crop its taller
    /// rectangle.
    pub fn with_shared_rows(&self) -> Result<Rig, String> {
        let starts: Vec<(u16, u16, u16)> = self
            .boards
            .iter()
            .map(|b| (b.rectangle.x, b.rectangle.width, b.rectangle.y))
            .collect();
        let boards = self
            .boards
            .iter()
            .map(|b| {
                let mut r = b.rectangle;
                let end = r.y + r.height;
                if starts.contains(&(r.x, r.width, end)) {
                    r.height += 1;
                }
                (b.name.clone(), b.port.clone(), r, b.windows.clone())
            })
            .collect();
        let mut rig = Rig::from_parts(self.whole.clone(), self.kind, self.camera_rate_hz, boards)?;
        rig.config_file = self.config_file.clone();
        rig.sync = self.sync;
        Ok(rig)
    }

    /// Declares the sync line, driven by the board named `leader`.
    pub fn set_sync_leader(&mut self, leader: &str) -> Result<(), String> {
        let index = self
            .boards
            .iter()
            .position(|b| b.name == leader)
            .ok_or_else(|| {
                let names: Vec<&str> = self.boards.iter().map(|b| b.name.as_str()).collect();
                format!(
                    "[sync] leader = {leader:?}: no board has that name (the boards: {})",
                    names.join(", ")
                )
            })?;
        self.sync = Some(RigSync { leader: index });
        Ok(())
    }

    /// The rig of `plan`'s shares of `whole`, boards named `board-K`, no ports.
    pub fn from_plan(
        whole: ProcessingConfig,
        kind: BoardKind,
        camera_rate_hz: Option<f64>,
        plan: &Plan,
    ) -> Result<Rig, String> {
        let boards = plan
            .shares
            .iter()
            .enumerate()
            .map(|(k, s)| (format!("board-{k}"), None, s.rectangle, s.windows.clone()))
            .collect();
        Rig::from_parts(whole, kind, camera_rate_hz, boards)
    }

    /// Checks a split and derives each board's configuration.
    #[allow(clippy::type_complexity)]
    pub fn from_parts(
        whole: ProcessingConfig,
        kind: BoardKind,
        camera_rate_hz: Option<f64>,
        boards: Vec<(String, Option<String>, Rectangle, Vec<usize>)>,
    ) -> Result<Rig, String> {
        if boards.is_empty() {
            return Err("no [[boards]]: a rig needs at least one".into());
        }
        if let Some(rate) = camera_rate_hz.filter(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(format!(
                "camera_rate_hz = {rate}: must be a positive number"
            ));
        }
        let count = whole.windows.len();
        let mut owner: Vec<Option<&str>> = vec![None; count];
        let mut names = BTreeSet::new();
        let mut ports = BTreeMap::new();
        for (name, port, rect, windows) in &boards {
            if !names.insert(name.as_str()) {
                return Err(format!("two boards are named {name:?}"));
            }
            if let Some(port) = port {
                if let Some(other) = ports.insert(port.as_str(), name.as_str()) {
                    return Err(format!(
                        "boards {other:?} and {name:?} are both on port {port}: each board needs its own"
                    ));
                }
            }
            if !rect.inside(&whole.camera) {
                return Err(format!(
                    "board {name:?}: rectangle {} is not inside the {}x{} camera",
                    rect.describe(),
                    whole.camera.width,
                    whole.camera.height
                ));
            }
            kind.check_crop(rect, &whole.camera)
                .map_err(|e| format!("board {name:?}: rectangle {}: {e}", rect.describe()))?;
            if windows.is_empty() {
                return Err(format!("board {name:?} has no sub-apertures"));
            }
            for &k in windows {
                let Some(slot) = owner.get_mut(k) else {
                    return Err(format!(
                        "board {name:?}: sub-aperture {k} does not exist (the configuration has {count}, 0..{})",
                        count.saturating_sub(1)
                    ));
                };
                if let Some(first) = slot {
                    return Err(if *first == name.as_str() {
                        format!("board {name:?} lists sub-aperture {k} twice")
                    } else {
                        format!("sub-aperture {k} is on two boards, {first:?} and {name:?}: give it to one")
                    });
                }
                *slot = Some(name.as_str());
                let w = whole.windows[k];
                if !rect.holds(&w) {
                    return Err(format!(
                        "board {name:?}: sub-aperture {k} ({}x{} at ({}, {})) is not inside its rectangle {}",
                        w.width,
                        w.height,
                        w.x,
                        w.y,
                        rect.describe()
                    ));
                }
            }
        }
        let orphans: Vec<usize> = (0..count).filter(|&k| owner[k].is_none()).collect();
        if !orphans.is_empty() {
            return Err(format!(
                "sub-aperture{} {} on no board: every sub-aperture must be on exactly one",
                if orphans.len() > 1 { "s" } else { "" },
                ranges(&orphans)
            ));
        }
        let boards = boards
            .into_iter()
            .map(|(name, port, rectangle, windows)| {
                let config = board_config(&whole, &rectangle, &windows);
                config
                    .validate()
                    .map_err(|e| format!("board {name:?}: its configuration: {e}"))?;
                Ok(RigBoard {
                    name,
                    port,
                    rectangle,
                    windows,
                    config,
                })
            })
            .collect::<Result<Vec<_>, String>>()?;
        Ok(Rig {
            whole,
            config_file: None,
            kind,
            camera_rate_hz,
            link_mb_per_s: None,
            boards,
            sync: None,
        })
    }

    /// One line of provenance: the boards and their sub-apertures.
    pub fn describe(&self) -> String {
        self.boards
            .iter()
            .map(|b| {
                let mut sorted = b.windows.clone();
                sorted.sort_unstable();
                format!("{} {}", b.name, ranges(&sorted))
            })
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// The rig as `rig.toml` text; `config` is how the file names the whole
    /// configuration; `loads` (one per board) go into comments.
    pub fn to_toml(&self, config: &Path, loads: Option<&[BoardLoad]>) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "# brightpix rig: one camera's sub-apertures split over {} boards.\n\
             # Edit freely: `brightpix rig` refuses a sub-aperture on no board or on two,\n\
             # one outside its board's rectangle, a rectangle the board cannot crop, and\n\
             # two boards on one port. Rectangles are in camera pixels.",
            self.boards.len()
        );
        let _ = writeln!(out, "config = {:?}", config.display().to_string());
        let _ = writeln!(out, "board = {:?}", self.kind.name());
        if let Some(rate) = self.camera_rate_hz {
            let _ = writeln!(out, "camera_rate_hz = {rate}");
        }
        if let Some(rate) = self.link_mb_per_s {
            let _ = writeln!(
                out,
                "# The boards' results link as measured (brightpix bench --port PORT --link), MB/s.\n\
                 link_mb_per_s = {rate}"
            );
        }
        match self.sync {
            Some(sync) => {
                let _ = writeln!(
                    out,
                    "\n# The sync line wired to every board; its leader drives it (rig capture starts\n\
                     # every board on the same camera frame with it).\n[sync]\nleader = {:?}",
                    self.boards[sync.leader].name
                );
            }
            None => {
                let _ = writeln!(
                    out,
                    "\n# Without a sync line, `rig capture` cannot start the boards on one camera\n\
                     # frame. Wire one GPIO to every board (STM32H743: PF13) and uncomment:\n\
                     # [sync]\n# leader = {:?}",
                    self.boards.first().map_or("board-0", |b| b.name.as_str())
                );
            }
        }
        for (k, b) in self.boards.iter().enumerate() {
            let _ = writeln!(out, "\n[[boards]]");
            if let Some(load) = loads.and_then(|l| l.get(k)) {
                let _ = writeln!(out, "# {}", describe_load(load, b));
            }
            let _ = writeln!(out, "name = {:?}", b.name);
            if let Some(port) = &b.port {
                let _ = writeln!(out, "port = {port:?}");
            }
            let r = b.rectangle;
            let _ = writeln!(
                out,
                "rectangle = {{ x = {}, y = {}, width = {}, height = {} }}",
                r.x, r.y, r.width, r.height
            );
            let list: Vec<String> = b.windows.iter().map(usize::to_string).collect();
            let _ = writeln!(out, "subapertures = [{}]", list.join(", "));
        }
        out
    }
}

/// A board's predicted load, for the plan's table and the file's comments.
pub fn describe_load(load: &BoardLoad, board: &RigBoard) -> String {
    let mut text = format!(
        "{} windows, {} pixels ({}): {:.0} instructions a frame, {:.0} after its last pixel",
        board.windows.len(),
        board.rectangle.pixels(),
        board.rectangle.describe(),
        load.instructions_per_frame,
        load.last_row_instructions
    );
    if let Some(l) = load.load {
        let _ = write!(
            text,
            "; load {:.0}% (headroom {:.0}%)",
            l * 100.0,
            (1.0 - l) * 100.0
        );
    }
    let _ = write!(
        text,
        "; results <= {} bytes a frame",
        load.result_bytes_per_frame
    );
    if let Some(b) = load.result_bytes_per_s {
        let _ = write!(text, ", {:.2} MB/s", b / 1e6);
        if let Some(l) = load.link_load {
            let _ = write!(text, " ({:.0}% of its link)", l * 100.0);
        }
    }
    text
}

/// `0-20, 24, 30-31`.
fn ranges(sorted: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut k = 0;
    while k < sorted.len() {
        let start = sorted[k];
        while k + 1 < sorted.len() && sorted[k + 1] == sorted[k] + 1 {
            k += 1;
        }
        parts.push(if sorted[k] == start {
            start.to_string()
        } else {
            format!("{start}-{}", sorted[k])
        });
        k += 1;
    }
    parts.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::board::CostModel;
    use crate::rig::plan::plan;

    fn write_rig(dir: &Path, boards: &str) -> PathBuf {
        let canary = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/canary.toml");
        std::fs::copy(canary, dir.join("canary.toml")).unwrap();
        let path = dir.join("rig.toml");
        std::fs::write(
            &path,
            format!("config = \"canary.toml\"\nboard = \"stm32h743\"\n{boards}"),
        )
        .unwrap();
        path
    }

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("brightpix-rig-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_planned_rig_round_trips_through_its_file() {
        let dir = temp("roundtrip");
        let whole = crate::sil::canary_config();
        let p = plan(&whole, 3, BoardKind::Stm32h743, &CostModel::CORTEX_M7).unwrap();
        let rig = Rig::from_plan(whole, BoardKind::Stm32h743, Some(1000.0), &p).unwrap();
        let canary = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/canary.toml");
        std::fs::copy(canary, dir.join("canary.toml")).unwrap();
        let path = dir.join("rig.toml");
        std::fs::write(&path, rig.to_toml(Path::new("canary.toml"), None)).unwrap();
        let back = Rig::load(&path).unwrap();
        assert_eq!(back.boards.len(), 3);
        for (a, b) in rig.boards.iter().zip(&back.boards) {
            assert_eq!(
                (&a.name, a.rectangle, &a.windows),
                (&b.name, b.rectangle, &b.windows)
            );
            assert_eq!(a.config, b.config);
        }
        assert_eq!(back.camera_rate_hz, Some(1000.0));
        assert_eq!(back.sync, None);
        // Bands sharing a row with the next: none planned, each after
        // with_shared_rows, which loads back the same.
        assert!(rig.shared_rows().is_empty());
        let shared = rig.with_shared_rows().unwrap();
        assert_eq!(shared.shared_rows(), [(0, 1), (1, 2)]);
        for (a, b) in rig.boards.iter().zip(&shared.boards) {
            assert_eq!(a.windows, b.windows);
        }
        std::fs::write(&path, shared.to_toml(Path::new("canary.toml"), None)).unwrap();
        assert_eq!(Rig::load(&path).unwrap().shared_rows(), [(0, 1), (1, 2)]);
        // With a sync line: its leader by name, back as the same board.
        let mut synced = rig.clone();
        synced.set_sync_leader("board-2").unwrap();
        std::fs::write(&path, synced.to_toml(Path::new("canary.toml"), None)).unwrap();
        assert_eq!(Rig::load(&path).unwrap().sync, Some(RigSync { leader: 2 }));
        let e = synced.set_sync_leader("board-9").unwrap_err();
        assert!(
            e.contains("no board has that name") && e.contains("board-0, board-1, board-2"),
            "{e}"
        );
    }

    #[test]
    fn wrong_edits_are_refused() {
        let dir = temp("edits");
        let all = |from: usize, to: usize| {
            (from..to)
                .map(|k| k.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let board = |name: &str, port: &str, y: u16, h: u16, list: String| {
            format!(
                "\n[[boards]]\nname = \"{name}\"\n{port}rectangle = {{ x = 0, y = {y}, width = 112, height = {h} }}\nsubapertures = [{list}]\n"
            )
        };
        let cases = [
            // 42-48 on no board.
            (
                board("a", "", 0, 48, all(0, 21)) + &board("b", "", 48, 48, all(21, 42)),
                "sub-apertures 42-48 on no board",
            ),
            // 20 on two.
            (
                board("a", "", 0, 48, all(0, 21)) + &board("b", "", 16, 96, all(20, 49)),
                "sub-aperture 20 is on two boards, \"a\" and \"b\"",
            ),
            // 21 (row 3) outside a's rectangle.
            (
                board("a", "", 0, 48, all(0, 22)) + &board("b", "", 48, 64, all(22, 49)),
                "sub-aperture 21 (16x16 at (0, 48)) is not inside its rectangle",
            ),
            (
                board("a", "port = \"/dev/ttyACM0\"\n", 0, 48, all(0, 21))
                    + &board("b", "port = \"/dev/ttyACM0\"\n", 48, 64, all(21, 49)),
                "both on port /dev/ttyACM0",
            ),
            (
                board("a", "", 0, 48, all(0, 21)) + &board("b", "", 48, 70, all(21, 49)),
                "is not inside the 112x112 camera",
            ),
            (String::new(), "no [[boards]]"),
            (
                board("a", "", 0, 112, all(0, 49) + ", 49"),
                "sub-aperture 49 does not exist",
            ),
            (
                "[sync]\nleader = \"c\"\n".to_string() + &board("a", "", 0, 112, all(0, 49)),
                "[sync] leader = \"c\": no board has that name (the boards: a)",
            ),
            (
                "[sync]\nleader = \"a\"\nline = 3\n".to_string()
                    + &board("a", "", 0, 112, all(0, 49)),
                "unknown field `line`",
            ),
        ];
        for (boards, expected) in cases {
            let path = write_rig(&dir, &boards);
            let e = Rig::load(&path).unwrap_err().to_string();
            assert!(
                e.contains(expected) && e.contains("rig.toml"),
                "{e}\nexpected: {expected}"
            );
        }
        // An odd width: the DCMI crops whole words of 4 pixels.
        let path = write_rig(
            &dir,
            &format!(
                "\n[[boards]]\nname = \"a\"\nrectangle = {{ x = 0, y = 0, width = 111, height = 112 }}\nsubapertures = [{}]\n",
                all(0, 42)
            ),
        );
        let e = Rig::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("cannot crop") && e.contains("multiple of 4"),
            "{e}"
        );
    }
}
