//! A configuration on the wire: its [`ConfigHeader`] and its tables of
//! little-endian elements, and the host's side of an upload
//! ([`UploadPlan`]) and of a frame's pixels ([`PixelRowsPlan`]).

use crate::config::{Calibration, Centroid, Config, PixelCount, Selection, SubapertureWindow};

use super::{
    Background, ConfigHeader, HostMessage, PixelCountMode, Table, CRC32, MAX_CHUNK_BYTES,
    MAX_PIXEL_BYTES,
};

impl Table {
    /// Every table, in upload order.
    pub const ALL: [Table; 5] = [
        Table::Windows,
        Table::PixelCounts,
        Table::Background,
        Table::Gain,
        Table::ReferenceSlopes,
    ];

    /// Bytes per element.
    pub const fn element_size(self) -> usize {
        match self {
            Table::Windows | Table::ReferenceSlopes => 8,
            Table::Background => 4,
            Table::PixelCounts | Table::Gain => 2,
        }
    }

    /// Position in upload order.
    pub const fn position(self) -> usize {
        self as usize
    }
}

impl ConfigHeader {
    /// The header of `config` (any config; the device validates).
    pub fn of(config: &Config<'_>) -> ConfigHeader {
        ConfigHeader {
            camera: config.camera,
            windows: config.windows.len() as u32,
            rule: config.selection.rule,
            pixel_count: match config.selection.count {
                PixelCount::All(n) => PixelCountMode::All(n),
                PixelCount::PerSubaperture(_) => PixelCountMode::PerSubaperture,
            },
            level_filter: config.selection.level_filter,
            threshold: config.calibration.threshold,
            min_flux: config.centroid.min_flux,
            background: match config.calibration.background {
                None => Background::None,
                // A uniform map travels as its one value (PROTOCOL.md §7).
                Some([first, rest @ ..]) if rest.iter().all(|b| b == first) => {
                    Background::Constant(*first)
                }
                Some(_) => Background::Map,
            },
            gain: config.calibration.gain.is_some(),
            reference_slopes: config.centroid.reference_slopes.is_some(),
            crop: config.crop,
        }
    }

    /// Longest postcard encoding of a header (about 60 bytes).
    pub const MAX_ENCODED_LEN: usize = 80;

    /// The header's postcard encoding, the start of the configuration's
    /// digest (PROTOCOL.md §7).
    pub fn encode<'b>(&self, out: &'b mut [u8; Self::MAX_ENCODED_LEN]) -> &'b [u8] {
        // Cannot fail: the largest header is well under 64 bytes.
        match postcard::to_slice(self, out) {
            Ok(bytes) => bytes,
            Err(_) => &[],
        }
    }

    /// Elements of `table` in this configuration; `None` if it is not sent.
    pub fn table_elements(&self, table: Table) -> Option<usize> {
        let windows = self.windows as usize;
        let pixels = self.camera.pixel_count();
        match table {
            Table::Windows => Some(windows),
            Table::PixelCounts => {
                matches!(self.pixel_count, PixelCountMode::PerSubaperture).then_some(windows)
            }
            Table::Background => matches!(self.background, Background::Map).then_some(pixels),
            Table::Gain => self.gain.then_some(pixels),
            Table::ReferenceSlopes => self.reference_slopes.then_some(windows),
        }
    }

    /// Bytes of `table`; `None` if it is not sent.
    pub fn table_len(&self, table: Table) -> Option<usize> {
        self.table_elements(table).map(|n| n * table.element_size())
    }

    /// The first table at or after position `from` (in upload order) that
    /// is sent and not empty: where an upload goes on.
    pub fn next_table(&self, from: usize) -> Option<Table> {
        Table::ALL[from.min(Table::ALL.len())..]
            .iter()
            .copied()
            .find(|&t| self.table_len(t).is_some_and(|len| len > 0))
    }
}

/// Element `i` of `table` of `config`, little-endian, into `out`
/// (`table.element_size()` bytes). `false` if `config` has no such element.
pub fn write_element(config: &Config<'_>, table: Table, i: usize, out: &mut [u8]) -> bool {
    match table {
        Table::Windows => match config.windows.get(i) {
            Some(w) => {
                out[0..2].copy_from_slice(&w.x.to_le_bytes());
                out[2..4].copy_from_slice(&w.y.to_le_bytes());
                out[4..6].copy_from_slice(&w.width.to_le_bytes());
                out[6..8].copy_from_slice(&w.height.to_le_bytes());
                true
            }
            None => false,
        },
        Table::PixelCounts => match config.selection.count {
            PixelCount::PerSubaperture(list) => put(list.get(i).map(|n| n.to_le_bytes()), out),
            PixelCount::All(_) => false,
        },
        Table::Background => put(
            config
                .calibration
                .background
                .and_then(|m| m.get(i))
                .map(|b| b.to_le_bytes()),
            out,
        ),
        Table::Gain => put(
            config
                .calibration
                .gain
                .and_then(|m| m.get(i))
                .map(|g| g.to_le_bytes()),
            out,
        ),
        Table::ReferenceSlopes => match config.centroid.reference_slopes.and_then(|r| r.get(i)) {
            Some([x, y]) => {
                out[0..4].copy_from_slice(&x.to_le_bytes());
                out[4..8].copy_from_slice(&y.to_le_bytes());
                true
            }
            None => false,
        },
    }
}

fn put<const N: usize>(bytes: Option<[u8; N]>, out: &mut [u8]) -> bool {
    match bytes {
        Some(b) => {
            out[..N].copy_from_slice(&b);
            true
        }
        None => false,
    }
}

/// Decodes one `Windows` element.
pub fn read_window(b: &[u8]) -> SubapertureWindow {
    SubapertureWindow {
        x: u16::from_le_bytes([b[0], b[1]]),
        y: u16::from_le_bytes([b[2], b[3]]),
        width: u16::from_le_bytes([b[4], b[5]]),
        height: u16::from_le_bytes([b[6], b[7]]),
    }
}

/// Decodes one `ReferenceSlopes` element.
pub fn read_reference_slope(b: &[u8]) -> [i32; 2] {
    [
        i32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        i32::from_le_bytes([b[4], b[5], b[6], b[7]]),
    ]
}

/// Writes bytes `offset ..` of `table` of `config` into `out`, in whole
/// elements; returns how many bytes were written (0 at the end).
pub fn write_table(config: &Config<'_>, table: Table, offset: usize, out: &mut [u8]) -> usize {
    let size = table.element_size();
    let first = offset / size;
    let mut written = 0;
    for (k, chunk) in out.chunks_exact_mut(size).enumerate() {
        if !write_element(config, table, first + k, chunk) {
            break;
        }
        written += size;
    }
    written
}

/// The configuration's digest: CRC-32/ISO-HDLC of its header's postcard
/// encoding followed by all its tables in upload order. It is the value of
/// [`HostMessage::ConfigCommit`]'s `crc32` and of `Status.config_digest`.
pub fn config_digest(config: &Config<'_>) -> u32 {
    let header = ConfigHeader::of(config);
    let mut digest = CRC32.digest();
    let mut encoded = [0u8; ConfigHeader::MAX_ENCODED_LEN];
    digest.update(header.encode(&mut encoded));
    let mut element = [0u8; 8];
    for table in Table::ALL {
        let Some(n) = header.table_elements(table) else {
            continue;
        };
        let size = table.element_size();
        for i in 0..n {
            write_element(config, table, i, &mut element[..size]);
            digest.update(&element[..size]);
        }
    }
    digest.finalize()
}

/// The messages that upload a configuration, one at a time (the host sends
/// each and waits for its reply): `ConfigBegin`, the chunks, `ConfigCommit`.
pub struct UploadPlan<'c> {
    config: Config<'c>,
    header: ConfigHeader,
    upload_id: u32,
    chunk_bytes: usize,
    step: Step,
}

#[derive(Clone, Copy, Debug)]
enum Step {
    Begin,
    Chunk { table: Table, offset: usize },
    Commit,
    Done,
}

impl<'c> UploadPlan<'c> {
    /// `chunk_bytes` is capped at [`MAX_CHUNK_BYTES`] and rounded down to
    /// whole 8-byte groups (every element size divides 8).
    pub fn new(config: Config<'c>, upload_id: u32, chunk_bytes: usize) -> Self {
        UploadPlan {
            config,
            header: ConfigHeader::of(&config),
            upload_id,
            chunk_bytes: (chunk_bytes.min(MAX_CHUNK_BYTES) / 8).max(1) * 8,
            step: Step::Begin,
        }
    }

    pub fn header(&self) -> &ConfigHeader {
        &self.header
    }

    /// Total messages this plan sends.
    pub fn message_count(&self) -> usize {
        2 + Table::ALL
            .iter()
            .filter_map(|&t| self.header.table_len(t))
            .map(|len| len.div_ceil(self.chunk_bytes))
            .sum::<usize>()
    }

    /// The next message; chunk bytes are written into `scratch` (at least
    /// `chunk_bytes` long). `None` after the commit.
    pub fn next<'s>(&mut self, scratch: &'s mut [u8]) -> Option<HostMessage<'s>> {
        loop {
            match self.step {
                Step::Begin => {
                    self.step = self.first_chunk(0);
                    return Some(HostMessage::ConfigBegin {
                        upload_id: self.upload_id,
                        header: self.header,
                    });
                }
                Step::Chunk { table, offset } => {
                    let len = self.header.table_len(table).unwrap_or(0);
                    if offset >= len {
                        self.step = self.first_chunk(table.position() + 1);
                        continue;
                    }
                    let take = (len - offset).min(self.chunk_bytes).min(scratch.len());
                    let take = take / table.element_size() * table.element_size();
                    let written = write_table(&self.config, table, offset, &mut scratch[..take]);
                    if written == 0 {
                        // The config's table is shorter than its header says
                        // (an invalid config): go on, the device refuses it.
                        self.step = self.first_chunk(table.position() + 1);
                        continue;
                    }
                    self.step = Step::Chunk {
                        table,
                        offset: offset + written,
                    };
                    return Some(HostMessage::ConfigChunk {
                        upload_id: self.upload_id,
                        table,
                        offset: offset as u32,
                        bytes: &scratch[..written],
                    });
                }
                Step::Commit => {
                    self.step = Step::Done;
                    return Some(HostMessage::ConfigCommit {
                        upload_id: self.upload_id,
                        crc32: config_digest(&self.config),
                    });
                }
                Step::Done => return None,
            }
        }
    }

    fn first_chunk(&self, from: usize) -> Step {
        match self.header.next_table(from) {
            Some(table) => Step::Chunk { table, offset: 0 },
            None => Step::Commit,
        }
    }
}

/// The `PixelRows` messages of one frame.
pub struct PixelRowsPlan<'p> {
    frame: u32,
    pixels: &'p [u16],
    per_message: usize,
    next: usize,
}

impl<'p> PixelRowsPlan<'p> {
    /// `pixels_per_message` is capped at [`MAX_PIXEL_BYTES`] / 2.
    pub fn new(frame: u32, pixels: &'p [u16], pixels_per_message: usize) -> Self {
        PixelRowsPlan {
            frame,
            pixels,
            per_message: pixels_per_message.clamp(1, MAX_PIXEL_BYTES / 2),
            next: 0,
        }
    }

    /// The next message, its pixels encoded into `scratch` (at least twice
    /// `pixels_per_message` bytes). `None` at the end of the frame.
    pub fn next<'s>(&mut self, scratch: &'s mut [u8]) -> Option<HostMessage<'s>> {
        if self.next >= self.pixels.len() {
            return None;
        }
        let take = (self.pixels.len() - self.next)
            .min(self.per_message)
            .min(scratch.len() / 2);
        let first = self.next;
        let bytes = pixels_to_le(&self.pixels[first..first + take], scratch);
        self.next += take;
        Some(HostMessage::PixelRows {
            frame: self.frame,
            first_pixel: first as u32,
            pixels: &scratch[..bytes],
        })
    }
}

/// Writes `pixels` as u16 LE into `out`; returns the bytes written.
pub fn pixels_to_le(pixels: &[u16], out: &mut [u8]) -> usize {
    let n = pixels.len().min(out.len() / 2);
    for (p, o) in pixels[..n].iter().zip(out.chunks_exact_mut(2)) {
        o.copy_from_slice(&p.to_le_bytes());
    }
    2 * n
}

/// Reads u16 LE pixels from `bytes` into `out`; returns the pixels read.
pub fn pixels_from_le(bytes: &[u8], out: &mut [u16]) -> usize {
    let mut n = 0;
    for (b, o) in bytes.chunks_exact(2).zip(out.iter_mut()) {
        *o = u16::from_le_bytes([b[0], b[1]]);
        n += 1;
    }
    n
}

/// A configuration assembled from a header and decoded tables (the
/// device's side; slices must hold at least the header's element counts).
pub struct TableSlices<'a> {
    pub windows: &'a [SubapertureWindow],
    pub pixel_counts: &'a [u16],
    pub background: &'a [i32],
    pub gain: &'a [u16],
    pub reference_slopes: &'a [[i32; 2]],
}

impl ConfigHeader {
    /// The [`Config`] this header describes over `tables`, each cut to the
    /// header's length. `None` if a slice is too short.
    pub fn config<'a>(&self, tables: TableSlices<'a>) -> Option<Config<'a>> {
        let windows = self.windows as usize;
        let pixels = self.camera.pixel_count();
        let cut = |n: usize, len: usize| (n <= len).then_some(n);
        Some(Config {
            camera: self.camera,
            windows: &tables.windows[..cut(windows, tables.windows.len())?],
            calibration: Calibration {
                background: if self.background.needs_map() {
                    Some(&tables.background[..cut(pixels, tables.background.len())?])
                } else {
                    None
                },
                gain: if self.gain {
                    Some(&tables.gain[..cut(pixels, tables.gain.len())?])
                } else {
                    None
                },
                threshold: self.threshold,
            },
            selection: Selection {
                rule: self.rule,
                count: match self.pixel_count {
                    PixelCountMode::All(n) => PixelCount::All(n),
                    PixelCountMode::PerSubaperture => PixelCount::PerSubaperture(
                        &tables.pixel_counts[..cut(windows, tables.pixel_counts.len())?],
                    ),
                },
                level_filter: self.level_filter,
            },
            centroid: Centroid {
                reference_slopes: if self.reference_slopes {
                    Some(&tables.reference_slopes[..cut(windows, tables.reference_slopes.len())?])
                } else {
                    None
                },
                min_flux: self.min_flux,
            },
            crop: self.crop,
        })
    }
}
