//! Writing results safely: every output is either whole or absent.
//!
//! - [`check_outputs`]: before any work, refuse an output that is the same
//!   file as an input (or as another output), has an unknown extension, or
//!   lies in a directory that does not exist.
//! - [`Staged`]: an array written to a temporary sibling file
//!   (`.tmp-PID.NAME`), renamed over the target only by
//!   [`Staged::commit`]; dropped uncommitted, it is removed. A command with
//!   several outputs stages them all and commits them only when every one
//!   was written, so a failure leaves none of them behind.
//! - [`Appender`]: an array that grows along its first axis as results
//!   arrive (`stream --out`), kept a valid `.npy` / FITS file after every
//!   append, so a process killed even by SIGKILL leaves every whole frame
//!   it had written.

use std::fs::{File, OpenOptions};
use std::io::{Seek, SeekFrom, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use super::fits::BLOCK;
use super::{FileFormat, IoError};

/// Checks, before any work, that each output can be written without harm:
/// its extension is `.npy` or FITS, its directory exists, and it is not the
/// same file as any input or any other output (compared by device and inode
/// when the file exists, and by canonical path otherwise).
pub fn check_outputs(inputs: &[&Path], outputs: &[&Path]) -> Result<(), IoError> {
    check_paths(inputs, outputs)?;
    outputs
        .iter()
        .try_for_each(|out| FileFormat::from_path(out).map(drop))
}

/// [`check_outputs`] without the extension check.
pub(crate) fn check_paths(inputs: &[&Path], outputs: &[&Path]) -> Result<(), IoError> {
    let identities: Vec<(PathBuf, Option<(u64, u64)>)> =
        inputs.iter().map(|p| identity(p)).collect();
    let mut seen: Vec<(PathBuf, Option<(u64, u64)>)> = Vec::new();
    for &out in outputs {
        let dir = parent(out);
        if !dir.is_dir() {
            return Err(IoError::io(
                out,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!("the directory {} does not exist", dir.display()),
                ),
            ));
        }
        let id = identity(out);
        for (k, input) in identities.iter().enumerate() {
            if same(&id, input) {
                return Err(IoError::unexpected(
                    out,
                    format!("the same file as the input {}", inputs[k].display()),
                    "an output path that is not an input (it would be overwritten)",
                ));
            }
        }
        if seen.iter().any(|s| same(&id, s)) {
            return Err(IoError::unexpected(
                out,
                "named twice as an output",
                "a different path for each output",
            ));
        }
        seen.push(id);
    }
    Ok(())
}

fn parent(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// A path's canonical form (its directory canonicalised when the file does
/// not exist yet) and, if it exists, its device and inode.
fn identity(path: &Path) -> (PathBuf, Option<(u64, u64)>) {
    let inode = std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()));
    let canonical = std::fs::canonicalize(path).unwrap_or_else(|_| {
        let dir = std::fs::canonicalize(parent(path)).unwrap_or_else(|_| parent(path));
        match path.file_name() {
            Some(name) => dir.join(name),
            None => dir,
        }
    });
    (canonical, inode)
}

fn same(a: &(PathBuf, Option<(u64, u64)>), b: &(PathBuf, Option<(u64, u64)>)) -> bool {
    match (a.1, b.1) {
        (Some(x), Some(y)) => x == y,
        _ => a.0 == b.0,
    }
}

/// The temporary sibling of `path` that a staged write goes to.
fn temp_sibling(path: &Path, tag: &str) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "output".into());
    // The extension stays last: writers choose the format by it.
    parent(path).join(format!(".{tag}-{}.{name}", std::process::id()))
}

/// An output written to a temporary file, waiting for [`Staged::commit`].
#[derive(Debug)]
pub struct Staged {
    temp: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl Staged {
    /// Writes `data` with `write` into a temporary sibling of `target`.
    pub fn write(
        target: &Path,
        write: impl FnOnce(&Path) -> Result<(), IoError>,
    ) -> Result<Staged, IoError> {
        let staged = Staged {
            temp: temp_sibling(target, "tmp"),
            target: target.to_path_buf(),
            committed: false,
        };
        write(&staged.temp).map_err(|e| match e {
            // Name the file the user asked for, not the temporary one.
            IoError::Io { error, .. } => IoError::io(target, error),
            other => other,
        })?;
        Ok(staged)
    }

    /// The file the output will have.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Moves the written file into place (an atomic rename).
    pub fn commit(mut self) -> Result<(), IoError> {
        std::fs::rename(&self.temp, &self.target).map_err(|e| IoError::io(&self.target, e))?;
        self.committed = true;
        Ok(())
    }

    /// Commits every staged output, in order.
    pub fn commit_all(all: Vec<Staged>) -> Result<(), IoError> {
        all.into_iter().try_for_each(Staged::commit)
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

/// A float64 array written as it grows along its first axis: after every
/// [`Appender::append`] the file is a valid `.npy` or FITS image holding
/// exactly the rows appended so far (the data first, then the header's
/// length), so it is whole at any moment the process dies.
#[derive(Debug)]
pub struct Appender {
    file: File,
    path: PathBuf,
    format: FileFormat,
    /// Shape of one row (the axes after the first).
    row_shape: Vec<usize>,
    row_len: usize,
    rows: usize,
    data_offset: u64,
    /// Where the first axis' length is written in the header, and its width.
    count_at: u64,
    count_width: usize,
    bytes: Vec<u8>,
}

/// Digits reserved for the first axis' length.
const COUNT_WIDTH: usize = 20;

impl Appender {
    /// Creates (truncates) `path` as an empty array of rows of `row_shape`.
    pub fn create(path: &Path, row_shape: &[usize]) -> Result<Appender, IoError> {
        let format = FileFormat::from_path(path)?;
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
            .map_err(|e| IoError::io(path, e))?;
        let mut appender = Appender {
            file,
            path: path.to_path_buf(),
            format,
            row_shape: row_shape.to_vec(),
            row_len: row_shape.iter().product(),
            rows: 0,
            data_offset: 0,
            count_at: 0,
            count_width: COUNT_WIDTH,
            bytes: Vec::new(),
        };
        let header = appender.header();
        appender.data_offset = header.len() as u64;
        appender
            .file
            .write_all(&header)
            .map_err(|e| IoError::io(path, e))?;
        Ok(appender)
    }

    /// The header with the first axis' length in a fixed-width field.
    fn header(&mut self) -> Vec<u8> {
        let count = format!("{:>width$}", self.rows, width = self.count_width);
        match self.format {
            FileFormat::Npy => {
                let rest: String = self.row_shape.iter().map(|d| format!("{d}, ")).collect();
                let prefix = "{'descr': '<f8', 'fortran_order': False, 'shape': (";
                let mut dict = format!("{prefix}{count}, {}), }}", rest.trim_end_matches(", "));
                // A trailing comma keeps a 1-D shape a tuple.
                if self.row_shape.is_empty() {
                    dict = format!("{prefix}{count},), }}");
                }
                while (10 + dict.len() + 1) % 64 != 0 {
                    dict.push(' ');
                }
                dict.push('\n');
                self.count_at = 10 + prefix.len() as u64;
                let mut out = b"\x93NUMPY\x01\x00".to_vec();
                out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
                out.extend_from_slice(dict.as_bytes());
                out
            }
            FileFormat::Fits => {
                let card = |key: &str, value: &str| format!("{key:<8}= {value:>20}{:<50}", "");
                let mut cards = vec![
                    card("SIMPLE", "T"),
                    card("BITPIX", "-64"),
                    card("NAXIS", &(self.row_shape.len() + 1).to_string()),
                ];
                for (k, d) in self.row_shape.iter().rev().enumerate() {
                    cards.push(card(&format!("NAXIS{}", k + 1), &d.to_string()));
                }
                let first_axis = self.row_shape.len() + 1;
                self.count_at = (cards.len() * 80 + 10) as u64;
                cards.push(card(&format!("NAXIS{first_axis}"), &count));
                cards.push(format!("{:<80}", "END"));
                let mut out = cards.concat().into_bytes();
                out.resize(out.len().div_ceil(BLOCK) * BLOCK, b' ');
                out
            }
        }
    }

    /// Appends one row (`row_shape` values, row-major) and makes the file
    /// say so.
    pub fn append(&mut self, row: &[f64]) -> Result<(), IoError> {
        if row.len() != self.row_len {
            return Err(IoError::unexpected(
                &self.path,
                format!("a row of {} values", row.len()),
                format!("{} values per row", self.row_len),
            ));
        }
        self.bytes.clear();
        for &v in row {
            match self.format {
                FileFormat::Npy => self.bytes.extend_from_slice(&v.to_le_bytes()),
                FileFormat::Fits => self.bytes.extend_from_slice(&v.to_be_bytes()),
            }
        }
        let at = self.data_offset + (self.rows * self.row_len * 8) as u64;
        let path = self.path.clone();
        let io = |e| IoError::io(&path, e);
        self.file.seek(SeekFrom::Start(at)).map_err(io)?;
        self.file.write_all(&self.bytes).map_err(io)?;
        self.rows += 1;
        if self.format == FileFormat::Fits {
            // Whole blocks at every moment, as FITS readers (cfitsio) require.
            let end = at + self.bytes.len() as u64;
            self.file
                .set_len(end.div_ceil(BLOCK as u64) * BLOCK as u64)
                .map_err(io)?;
        }
        let count = format!("{:>width$}", self.rows, width = self.count_width);
        self.file.seek(SeekFrom::Start(self.count_at)).map_err(io)?;
        self.file.write_all(count.as_bytes()).map_err(io)
    }

    /// Rows written so far.
    pub fn rows(&self) -> usize {
        self.rows
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Completes the file (FITS: pads the data to whole blocks); returns the
    /// rows written.
    pub fn finish(self) -> Result<usize, IoError> {
        let end = self.data_offset + (self.rows * self.row_len * 8) as u64;
        let len = match self.format {
            FileFormat::Npy => end,
            FileFormat::Fits => end.div_ceil(BLOCK as u64) * BLOCK as u64,
        };
        self.file
            .set_len(len)
            .and_then(|_| self.file.sync_data())
            .map_err(|e| IoError::io(&self.path, e))?;
        Ok(self.rows)
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::temp_dir;
    use super::super::{read_array, write_array};
    use super::*;

    #[test]
    fn an_output_equal_to_an_input_is_refused() {
        let dir = temp_dir("sameout");
        let frames = dir.join("frames.npy");
        write_array(&frames, &[1, 2, 2], &[1u16, 2, 3, 4]).unwrap();
        // The same path, another spelling of it, and a hard link.
        let other = dir.join(".").join("frames.npy");
        std::fs::hard_link(&frames, dir.join("link.npy")).unwrap();
        for out in [frames.clone(), other, dir.join("link.npy")] {
            let err = check_outputs(&[&frames], &[&out]).unwrap_err();
            assert!(
                err.to_string().contains("the same file as the input"),
                "{err}"
            );
        }
        // Two outputs on one path.
        let a = dir.join("a.npy");
        let err = check_outputs(&[&frames], &[&a, &a]).unwrap_err();
        assert!(err.to_string().contains("named twice"), "{err}");
        // A missing directory, an unknown extension.
        let err = check_outputs(&[], &[&dir.join("no/such/dir/x.npy")]).unwrap_err();
        assert!(err.to_string().contains("does not exist"), "{err}");
        assert!(check_outputs(&[], &[&dir.join("x.txt")]).is_err());
        check_outputs(&[&frames], &[&a, &dir.join("b.fits")]).unwrap();
    }

    #[test]
    fn staged_outputs_appear_only_when_committed() {
        let dir = temp_dir("staged");
        let target = dir.join("out.npy");
        let staged = Staged::write(&target, |p| write_array(p, &[2], &[1.0f64, 2.0])).unwrap();
        assert!(!target.exists());
        drop(staged);
        assert!(!target.exists());
        assert_eq!(
            std::fs::read_dir(&dir).unwrap().count(),
            0,
            "temporary file left"
        );
        let staged = Staged::write(&target, |p| write_array(p, &[2], &[1.0f64, 2.0])).unwrap();
        staged.commit().unwrap();
        assert_eq!(read_array(&target).unwrap().data, [1.0, 2.0]);
    }

    #[test]
    fn an_appended_file_is_valid_after_every_row() {
        for ext in ["npy", "fits"] {
            let dir = temp_dir("append");
            let path = dir.join(format!("slopes.{ext}"));
            let mut out = Appender::create(&path, &[3, 2]).unwrap();
            let empty = read_array(&path).unwrap();
            assert_eq!(empty.shape, [0, 3, 2], "{ext}");
            let mut all = Vec::new();
            for k in 0..12 {
                let row: Vec<f64> = (0..6).map(|i| (k * 6 + i) as f64 * 0.5).collect();
                out.append(&row).unwrap();
                all.extend_from_slice(&row);
                // As a killed process would leave it.
                {
                    let back = read_array(&path).unwrap();
                    assert_eq!(back.shape, [k + 1, 3, 2], "{ext}");
                    assert_eq!(back.data, all, "{ext}");
                }
            }
            assert_eq!(out.finish().unwrap(), 12);
            let back = read_array(&path).unwrap();
            assert_eq!(back.shape, [12, 3, 2]);
            assert_eq!(back.data, all);
        }
    }
}
