//! The firmware's bench in QEMU (exact instruction counts with `-icount`),
//! through its script:
//!
//! ```text
//! firmware/boards/qemu/scripts/run-bench CORE [--config PATH --frames PATH]
//! ```
//!
//! `CORE` is `m4` (mps2-an386) or `m7` (mps2-an500). The script builds the
//! bench if needed, runs it and prints, besides its own table, one line per
//! measurement: `BENCH {json}` with at least `workload`, `core`,
//! `instr_per_px`, `floor_instr_per_px`, `last_row_instructions`, `pixels`
//! and `frames`. With `--config` (the bytes a host sends to configure a
//! device: the COBS frames of the upload's messages, concatenated) and
//! `--frames` (raw little-endian `u16`, frames x height x width) it measures
//! that configuration on those frames, as workload `user`.

use serde::{Deserialize, Serialize};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;

use brightpix_protocol::wire::{encode, UploadPlan, MAX_CHUNK_BYTES, MAX_FRAME_LEN};
use brightpix_protocol::Config;

/// A QEMU core of the bench.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QemuCore {
    M4,
    M7,
}

impl QemuCore {
    pub const ALL: [QemuCore; 2] = [QemuCore::M4, QemuCore::M7];

    /// The script's argument.
    pub fn arg(self) -> &'static str {
        match self {
            QemuCore::M4 => "m4",
            QemuCore::M7 => "m7",
        }
    }

    /// The name in the bench's lines and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            QemuCore::M4 => "cortex-m4",
            QemuCore::M7 => "cortex-m7",
        }
    }
}

/// One measurement of the QEMU bench (a `BENCH` line).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QemuRow {
    pub workload: String,
    /// `cortex-m4` or `cortex-m7`.
    pub core: String,
    pub instr_per_px: f64,
    /// The honest floor's, for the built-in workloads; `null` (`None`) for
    /// a user's configuration, whose windows need not be a grid the floor
    /// handles.
    pub floor_instr_per_px: Option<f64>,
    /// Instructions from the last row's arrival to the frame's last result.
    pub last_row_instructions: f64,
    #[serde(default)]
    pub pixels: u64,
    #[serde(default)]
    pub frames: u64,
    /// Whatever else the bench reports.
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

impl QemuRow {
    /// The engine's instructions over the floor's, if there is one.
    pub fn x_floor(&self) -> Option<f64> {
        self.floor_instr_per_px
            .map(|floor| self.instr_per_px / floor)
    }
}

/// The script, relative to the repository root.
pub const SCRIPT: &str = "firmware/boards/qemu/scripts/run-bench";

/// The repository root: the first of the current directory and its parents
/// that holds the firmware, else the one this binary was built from.
pub fn repository_root() -> Option<PathBuf> {
    let has_firmware = |dir: &Path| dir.join("firmware/boards/qemu").is_dir();
    if let Ok(cwd) = std::env::current_dir() {
        if let Some(dir) = cwd.ancestors().find(|d| has_firmware(d)) {
            return Some(dir.to_path_buf());
        }
    }
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).parent()?;
    has_firmware(built).then(|| built.to_path_buf())
}

/// What is missing to run the QEMU bench, in words, or `None`.
pub fn missing(repo: Option<&Path>) -> Option<String> {
    let Some(repo) = repo else {
        return Some(
            "the brightpix source tree (firmware/boards/qemu) is not here: run from a clone of the repository"
                .into(),
        );
    };
    let mut missing = Vec::new();
    if !repo.join(SCRIPT).is_file() {
        missing.push(format!("the QEMU bench script {SCRIPT}"));
    }
    if !on_path("qemu-system-arm") {
        missing.push(
            "qemu-system-arm (Debian/Ubuntu: apt-get install qemu-system-arm; or run scripts/setup)"
                .into(),
        );
    }
    if !thumb_target_installed() {
        missing.push(
            "the Rust target thumbv7em-none-eabihf (rustup target add thumbv7em-none-eabihf; or run scripts/setup)"
                .into(),
        );
    }
    (!missing.is_empty()).then(|| format!("missing {}", missing.join("; ")))
}

fn on_path(program: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|paths| std::env::split_paths(&paths).any(|dir| dir.join(program).is_file()))
}

fn thumb_target_installed() -> bool {
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    Command::new(rustc)
        .args(["--print", "sysroot"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| {
            PathBuf::from(String::from_utf8_lossy(&o.stdout).trim())
                .join("lib/rustlib/thumbv7em-none-eabihf")
                .is_dir()
        })
        .unwrap_or(false)
}

/// A run of the script: its rows and everything it printed.
pub struct QemuRun {
    pub rows: Vec<QemuRow>,
    pub output: String,
}

/// Runs the script for `core` with `args`; an error says what failed, with
/// the end of the script's output.
pub fn run(repo: &Path, core: QemuCore, args: &[OsString]) -> Result<QemuRun, String> {
    let output = Command::new(repo.join(SCRIPT))
        .arg(core.arg())
        .args(args)
        .current_dir(repo)
        .output()
        .map_err(|e| format!("cannot run {SCRIPT}: {e}"))?;
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    let tail = |text: &str| {
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(15)..].join("\n")
    };
    if !output.status.success() {
        return Err(format!(
            "{SCRIPT} {} failed ({}):\n{}\n{}",
            core.arg(),
            output.status,
            tail(&stderr),
            tail(&stdout)
        ));
    }
    let rows = parse_bench_lines(&stdout)?;
    if rows.is_empty() {
        return Err(format!(
            "{SCRIPT} {} printed no BENCH lines:\n{}",
            core.arg(),
            tail(&stdout)
        ));
    }
    Ok(QemuRun {
        rows,
        output: stdout + &stderr,
    })
}

/// The `BENCH {json}` lines of the script's output.
pub fn parse_bench_lines(text: &str) -> Result<Vec<QemuRow>, String> {
    text.lines()
        .filter_map(|line| line.trim_start().strip_prefix("BENCH "))
        .map(|json| {
            serde_json::from_str::<QemuRow>(json)
                .map_err(|e| format!("a BENCH line the host cannot read ({e}): {json}"))
        })
        .collect()
}

/// The bytes a host sends to configure a device with `config`: the COBS
/// frames of its upload's messages (`ConfigBegin`, the table chunks,
/// `ConfigCommit`), concatenated, as `brightpix configure` sends them.
pub fn config_upload_bytes(config: &Config<'_>) -> Vec<u8> {
    let mut plan = UploadPlan::new(*config, 1, MAX_CHUNK_BYTES);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    let mut frame = vec![0u8; MAX_FRAME_LEN];
    let mut out = Vec::new();
    while let Some(message) = plan.next(&mut scratch) {
        let encoded = encode(&message, &mut frame).expect("upload messages fit a frame");
        out.extend_from_slice(encoded);
    }
    out
}

/// Writes `config.bin` (the upload's bytes) and `frames.u16le` (raw
/// little-endian pixels) into `dir`, for `run-bench --config --frames`.
pub fn write_user_inputs(
    dir: &Path,
    config: &Config<'_>,
    pixels: &[u16],
) -> std::io::Result<(PathBuf, PathBuf)> {
    let config_path = dir.join("config.bin");
    let frames_path = dir.join("frames.u16le");
    std::fs::write(&config_path, config_upload_bytes(config))?;
    let bytes: Vec<u8> = pixels.iter().flat_map(|p| p.to_le_bytes()).collect();
    std::fs::write(&frames_path, bytes)?;
    Ok((config_path, frames_path))
}

#[cfg(test)]
mod tests {
    use super::*;
    use brightpix_protocol::wire::{decode, HostMessage};

    #[test]
    fn bench_lines_are_read_and_others_ignored() {
        let text = "a human table\n\
            BENCH {\"workload\":\"canary-subtract-next-n20\",\"core\":\"cortex-m4\",\"instr_per_px\":19.5,\"floor_instr_per_px\":8.0,\"last_row_instructions\":1900,\"pixels\":12544,\"frames\":4,\"note\":\"x\"}\n\
            more text\n";
        let rows = parse_bench_lines(text).unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].core, "cortex-m4");
        assert_eq!(rows[0].x_floor(), Some(19.5 / 8.0));
        assert_eq!(rows[0].extra["note"], "x");
        assert!(parse_bench_lines("BENCH {\"workload\": 1}").is_err());
    }

    #[test]
    fn a_tree_without_the_script_says_so() {
        let dir =
            std::env::temp_dir().join(format!("brightpix-qemu-missing-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("firmware/boards/qemu")).unwrap();
        let message = missing(Some(&dir)).unwrap();
        assert!(message.contains("run-bench"), "{message}");
        assert!(missing(None).unwrap().contains("source tree"));
    }

    #[test]
    fn the_config_file_is_the_upload_a_device_receives() {
        let config = crate::sil::canary_config();
        let bytes = config_upload_bytes(&config.view());
        let mut frames: Vec<Vec<u8>> = bytes
            .split(|&b| b == 0)
            .filter(|f| !f.is_empty())
            .map(<[u8]>::to_vec)
            .collect();
        let count = frames.len();
        assert!(count >= 3);
        let first: HostMessage<'_> = decode(&mut frames[0]).unwrap();
        assert!(matches!(
            first,
            HostMessage::ConfigBegin { upload_id: 1, .. }
        ));
        let last: HostMessage<'_> = decode(&mut frames[count - 1]).unwrap();
        assert!(matches!(
            last,
            HostMessage::ConfigCommit { upload_id: 1, .. }
        ));
    }
}
