//! A user's configuration and frames (`--config PATH --frames PATH`), for
//! `brightpix bench --config`: the engine on them, in instructions per pixel
//! and after the last row.
//!
//! - `--config`: exactly the bytes a host sends to configure a device: the
//!   COBS frames of `ConfigBegin`, `ConfigChunk`s and `ConfigCommit`
//!   (`brightpix_protocol::wire::tables::UploadPlan`), concatenated;
//! - `--frames`: raw little-endian u16 pixels, frames x height x width;
//! - `--warmup K` (default 2): frames pushed before measuring, from the
//!   start of the file (the seeds of a running camera).
//!
//! Frames are read through semihosting (untimed) a block of whole rows at
//! a time (up to [`BLOCK`] pixels: any frame the tables hold, less its last
//! row). Each block's row pushes are counted together, and the frame's last
//! row alone, as the QEMU tables count theirs: a count per row would leave
//! out each push's call and return (~9-12 instructions).

use brightpix_board_qemu::hostfs::HostFile;
use brightpix_firmware::engine::{Engine, FrameError, SubapertureResult};
use brightpix_protocol::wire::tables::{read_reference_slope, read_window, TableSlices};
use brightpix_protocol::wire::{
    decode, Background, ConfigHeader, FrameReader, HostMessage, Received, Table,
};
use brightpix_protocol::SubapertureWindow;
use heapless::String;
use semihosting::println;
use static_cell::ConstStaticCell;

use crate::counter::Counter;
use crate::meter::Meter;
use crate::workloads::Buffers;

const MAX_PATH: usize = 255;
/// The configuration's tables, as the QEMU device's budget allows.
const MAX_WINDOWS: usize = 6400;
const MAX_MAP: usize = 256 * 256;
/// The widest camera row.
const MAX_ROW: usize = 4096;
/// Pixels read ahead of one count: any camera the tables above hold, whole.
const BLOCK: usize = MAX_MAP;

pub struct Request {
    config: String<MAX_PATH>,
    frames: String<MAX_PATH>,
    warmup: usize,
}

impl Request {
    /// `None` unless the command line asks for a user workload.
    pub fn from_semihosting() -> Option<Request> {
        let args = semihosting::experimental::env::args::<1024>().ok()?;
        let mut config = None;
        let mut frames = None;
        let mut warmup = 2;
        let mut args = (&args).skip(1);
        while let Some(Ok(arg)) = args.next() {
            let value = args.next().and_then(Result::ok);
            match (arg, value) {
                ("--config", Some(v)) => config = String::try_from(v).ok(),
                ("--frames", Some(v)) => frames = String::try_from(v).ok(),
                ("--warmup", Some(v)) => warmup = v.parse().unwrap_or(2),
                _ => {}
            }
        }
        Some(Request {
            config: config?,
            frames: frames?,
            warmup,
        })
    }
}

struct Tables {
    windows: [SubapertureWindow; MAX_WINDOWS],
    counts: [u16; MAX_WINDOWS],
    background: [i32; MAX_MAP],
    gain: [u16; MAX_MAP],
    references: [[i32; 2]; MAX_WINDOWS],
}

static TABLES: ConstStaticCell<Tables> = ConstStaticCell::new(Tables {
    windows: [SubapertureWindow {
        x: 0,
        y: 0,
        width: 0,
        height: 0,
    }; MAX_WINDOWS],
    counts: [0; MAX_WINDOWS],
    background: [0; MAX_MAP],
    gain: [0; MAX_MAP],
    references: [[0; 2]; MAX_WINDOWS],
});
static UPLOAD: ConstStaticCell<[u8; 16 * 1024]> = ConstStaticCell::new([0; 16 * 1024]);
static ROWS: ConstStaticCell<[u16; BLOCK]> = ConstStaticCell::new([0; BLOCK]);
static ROW_BYTES: ConstStaticCell<[u8; 2 * MAX_ROW]> = ConstStaticCell::new([0; 2 * MAX_ROW]);

fn fail(what: &str) -> ! {
    println!("FAILED: {}", what);
    brightpix_board_qemu::exit(1)
}

/// Reads the upload into `tables`; returns its header.
fn read_upload(path: &str, tables: &mut Tables) -> ConfigHeader {
    let Ok(mut file) = HostFile::open_str(path) else {
        fail("cannot open the --config file");
    };
    let mut reader = FrameReader::new(&mut UPLOAD.take()[..]);
    let mut header = None;
    loop {
        let n = match file.read(reader.space()) {
            Ok(0) => break,
            Ok(n) => n,
            Err(_) => fail("cannot read the --config file"),
        };
        reader.advance(n);
        while let Some(received) = reader.next_frame() {
            let Received::Frame(bytes) = received else {
                fail("the --config file holds a frame longer than any message");
            };
            match decode::<HostMessage>(bytes) {
                Ok(HostMessage::ConfigBegin { header: h, .. }) => header = Some(h),
                Ok(HostMessage::ConfigChunk {
                    table,
                    offset,
                    bytes,
                    ..
                }) => store(tables, table, offset as usize, bytes),
                Ok(_) => {}
                Err(_) => fail("the --config file holds a message that does not decode"),
            }
        }
    }
    header.unwrap_or_else(|| fail("the --config file has no ConfigBegin"))
}

fn store(t: &mut Tables, table: Table, offset: usize, bytes: &[u8]) {
    let size = table.element_size();
    for (k, element) in bytes.chunks_exact(size).enumerate() {
        let i = offset / size + k;
        let ok = match table {
            Table::Windows => t.windows.get_mut(i).map(|w| *w = read_window(element)),
            Table::PixelCounts => t
                .counts
                .get_mut(i)
                .map(|c| *c = u16::from_le_bytes([element[0], element[1]])),
            Table::Background => t
                .background
                .get_mut(i)
                .map(|b| *b = i32::from_le_bytes([element[0], element[1], element[2], element[3]])),
            Table::Gain => t
                .gain
                .get_mut(i)
                .map(|g| *g = u16::from_le_bytes([element[0], element[1]])),
            Table::ReferenceSlopes => t
                .references
                .get_mut(i)
                .map(|r| *r = read_reference_slope(element)),
        };
        if ok.is_none() {
            fail("the configuration is larger than the benchmark's tables (6400 windows, 65536 map pixels)");
        }
    }
}

pub fn run(
    request: &Request,
    meter: &Meter,
    core: &str,
    _buffers: &mut Buffers<'_>,
    memory: &mut crate::Memory,
) {
    let tables = TABLES.take();
    let header = read_upload(&request.config, tables);
    if let Background::Constant(value) = header.background {
        // A uniform background travels as one value; the device fills its
        // map with it (`device::Device`), and so must the benchmark.
        match tables.background.get_mut(..header.camera.pixel_count()) {
            Some(map) => map.fill(value),
            None => {
                fail("the configuration is larger than the benchmark's tables (65536 map pixels)")
            }
        }
    }
    let slices = TableSlices {
        windows: &tables.windows,
        pixel_counts: &tables.counts,
        background: &tables.background,
        gain: &tables.gain,
        reference_slopes: &tables.references,
    };
    let Some(config) = header.config(slices) else {
        fail("the configuration's tables are incomplete");
    };
    let mut engine = match Engine::new(config, memory.borrow()) {
        Ok(engine) => engine,
        Err(e) => {
            println!("the engine refused the configuration: {}", e);
            fail("configuration refused");
        }
    };
    let width = config.camera.width as usize;
    let height = config.camera.height as usize;
    if width > MAX_ROW {
        fail("the camera is wider than the benchmark's row buffer (4096)");
    }
    let frame_bytes = (2 * width * height) as u64;
    let frames = match HostFile::open_str(&request.frames).and_then(|f| f.size()) {
        Ok(len) if len >= frame_bytes && len % frame_bytes == 0 => (len / frame_bytes) as usize,
        Ok(_) => fail("the --frames file is not a whole number of frames of the configured camera"),
        Err(_) => fail("cannot open the --frames file"),
    };
    let rows = ROWS.take();
    let bytes = &mut ROW_BYTES.take()[..2 * width];
    let block_rows = (BLOCK / width).min(height);
    let warmup = request.warmup.min(frames);
    // Pushes the file's first `count` frames; returns the instructions of
    // all pushes and of the final rows.
    let mut push_frames = |count: usize| {
        let Ok(mut file) = HostFile::open_str(&request.frames) else {
            fail("cannot open the --frames file");
        };
        let (mut total, mut last_row) = (0.0, 0.0);
        for f in 0..count {
            // The rows before the last in blocks, then the last row alone.
            let mut y = 0;
            while y < height {
                let k = if y + 1 == height {
                    1
                } else {
                    block_rows.min(height - 1 - y)
                };
                let block = &mut rows[..k * width];
                for row in block.chunks_exact_mut(width) {
                    if file.read_exact(bytes).is_err() {
                        fail("cannot read the --frames file");
                    }
                    for (p, b) in row.iter_mut().zip(bytes.chunks_exact(2)) {
                        *p = u16::from_le_bytes([b[0], b[1]]);
                    }
                }
                let block = &*block;
                let (count, pushed) = meter.count(|| {
                    for row in block.chunks_exact(width) {
                        engine.push(row, &mut |_r: SubapertureResult| {})?;
                    }
                    Ok::<(), FrameError>(())
                });
                if let Err(e) = pushed {
                    println!("frame {}: {}", f, e);
                    fail("a frame was refused");
                }
                total += count;
                if y + k == height {
                    last_row += count;
                }
                y += k;
            }
        }
        (total, last_row)
    };
    push_frames(warmup);
    let (total, last_row) = push_frames(frames);
    let pass = frames;
    let pixels = (pass * width * height) as f64;
    let stats = engine.stats();
    println!(
        "user configuration: {}x{} camera, {} sub-apertures, {} frames measured after {} of warm-up",
        width,
        height,
        config.windows.len(),
        pass,
        warmup
    );
    println!(
        "BENCH {{\"workload\":\"user\",\"core\":\"{}\",\"instr_per_px\":{:.3},\"floor_instr_per_px\":null,\"last_row_instructions\":{:.0},\"pixels\":{},\"frames\":{},\"windows\":{},\"candidates\":{},\"compactions\":{},\"rescans\":{}}}",
        core,
        total / pixels,
        last_row / pass.max(1) as f64,
        pixels as u64,
        pass,
        stats.windows,
        stats.candidates,
        stats.compactions,
        stats.rescans
    );
}
