//! A minimal FITS reader and writer for primary-HDU images.
//!
//! Reading: the primary header (2880-byte blocks of 80-character cards) and
//! the image that follows it, BITPIX 8, 16, 32, 64, -32 or -64, big-endian,
//! `NAXIS1` fastest. Physical values are `BZERO + BSCALE * stored`; integer
//! pixels equal to `BLANK` are undefined (NaN in maps, an error in frames).
//! Extensions after the primary HDU are ignored; an image stored only in an
//! extension (primary `NAXIS = 0`) is not supported.
//!
//! Writing: `SIMPLE`, `BITPIX`, `NAXISn`, and for `u16` data `BZERO = 32768`
//! / `BSCALE = 1`; header and data padded to 2880 bytes.
//!
//! Why not a crate: `fitsrs` 0.4 reads these images but hands back stored
//! values without applying `BSCALE`/`BZERO`, cannot write, and brings in
//! async runtimes, WCS and compression crates; `fitsio` needs the C cfitsio.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, Write};
use std::path::Path;

use super::{shape_string, Array, Element, Encoding, FrameLayout, FrameShape, IoError};

/// FITS block size in bytes.
pub const BLOCK: usize = 2880;
const CARD: usize = 80;
/// Give up looking for `END` after this many header blocks.
const MAX_HEADER_BLOCKS: usize = 10_000;

/// The parts of a primary header this reader uses.
#[derive(Clone, Debug, PartialEq)]
pub struct FitsHeader {
    pub bitpix: i32,
    /// `NAXIS1, NAXIS2, ...`: fastest axis first (the reverse of NumPy order).
    pub naxes: Vec<usize>,
    pub bscale: f64,
    pub bzero: f64,
    pub blank: Option<i64>,
    /// Byte offset of the data (the header's length).
    pub data_offset: u64,
}

impl FitsHeader {
    /// Shape in NumPy order (slowest first): `[NAXISn, ..., NAXIS1]`.
    pub fn shape(&self) -> Vec<usize> {
        self.naxes.iter().rev().copied().collect()
    }
    pub fn bytes_per_value(&self) -> usize {
        (self.bitpix.unsigned_abs() / 8) as usize
    }
    pub fn value_count(&self) -> usize {
        if self.naxes.is_empty() {
            0
        } else {
            self.naxes.iter().product()
        }
    }
}

/// A header card's value, as far as this reader cares.
#[derive(Clone, Debug, PartialEq)]
enum Value {
    Logical(bool),
    Integer(i64),
    Real(f64),
    Other(String),
}

impl Value {
    fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Integer(i) => Some(*i as f64),
            Value::Real(r) => Some(*r),
            _ => None,
        }
    }
}

fn parse_value(field: &str) -> Value {
    let field = field.trim_start();
    if let Some(rest) = field.strip_prefix('\'') {
        // A string: '' is an escaped quote; the comment follows the closing quote.
        let mut s = String::new();
        let mut chars = rest.chars().peekable();
        while let Some(c) = chars.next() {
            if c == '\'' {
                if chars.peek() == Some(&'\'') {
                    chars.next();
                    s.push('\'');
                } else {
                    break;
                }
            } else {
                s.push(c);
            }
        }
        return Value::Other(s.trim_end().to_string());
    }
    let text = field.split('/').next().unwrap_or("").trim();
    match text {
        "T" => return Value::Logical(true),
        "F" => return Value::Logical(false),
        _ => {}
    }
    if let Ok(i) = text.parse::<i64>() {
        return Value::Integer(i);
    }
    if let Ok(r) = text.replace(['D', 'd'], "E").parse::<f64>() {
        return Value::Real(r);
    }
    Value::Other(text.to_string())
}

/// Reads the primary header from the start of `reader`.
pub fn read_header(path: &Path, reader: &mut impl Read) -> Result<FitsHeader, IoError> {
    let mut cards: Vec<(String, Option<Value>)> = Vec::new();
    let mut block = vec![0u8; BLOCK];
    let mut blocks = 0usize;
    'blocks: loop {
        if blocks == MAX_HEADER_BLOCKS {
            return Err(IoError::malformed(path, "FITS header has no END card"));
        }
        if let Err(e) = reader.read_exact(&mut block) {
            return Err(if e.kind() == std::io::ErrorKind::UnexpectedEof {
                if blocks == 0 {
                    IoError::malformed(path, "not a FITS file: shorter than one 2880-byte block")
                } else {
                    IoError::malformed(path, "FITS header ends before its END card")
                }
            } else {
                IoError::io(path, e)
            });
        }
        blocks += 1;
        for card in block.chunks_exact(CARD) {
            if !card.iter().all(|&b| (0x20..=0x7e).contains(&b)) {
                return Err(IoError::malformed(
                    path,
                    if cards.is_empty() {
                        "not a FITS file (it does not start with SIMPLE = T)".to_string()
                    } else {
                        format!(
                            "FITS header card {} is not printable ASCII",
                            cards.len() + 1
                        )
                    },
                ));
            }
            let card = std::str::from_utf8(card).expect("ASCII checked");
            let keyword = card[..8].trim_end().to_string();
            if keyword == "END" {
                break 'blocks;
            }
            let value = (&card[8..10] == "= ").then(|| parse_value(&card[10..]));
            if cards.is_empty() && !(keyword == "SIMPLE" && value == Some(Value::Logical(true))) {
                return Err(IoError::malformed(
                    path,
                    "not a FITS file (it does not start with SIMPLE = T)",
                ));
            }
            cards.push((keyword, value));
        }
    }
    let find = |key: &str| {
        cards
            .iter()
            .find(|(k, _)| k == key)
            .and_then(|(_, v)| v.clone())
    };
    let integer = |key: &str| -> Result<Option<i64>, IoError> {
        match find(key) {
            None => Ok(None),
            Some(Value::Integer(i)) => Ok(Some(i)),
            Some(other) => Err(IoError::malformed(
                path,
                format!("FITS keyword {key} is {other:?}, expected an integer"),
            )),
        }
    };
    let required = |key: &str| -> Result<i64, IoError> {
        integer(key)?.ok_or_else(|| IoError::malformed(path, format!("FITS header lacks {key}")))
    };
    let real = |key: &str, default: f64| -> Result<f64, IoError> {
        match find(key) {
            None => Ok(default),
            Some(v) => v.as_f64().ok_or_else(|| {
                IoError::malformed(
                    path,
                    format!("FITS keyword {key} is {v:?}, expected a number"),
                )
            }),
        }
    };
    let bitpix = required("BITPIX")?;
    if ![8, 16, 32, 64, -32, -64].contains(&bitpix) {
        return Err(IoError::malformed(
            path,
            format!("FITS BITPIX = {bitpix}; expected 8, 16, 32, 64, -32 or -64"),
        ));
    }
    let naxis = required("NAXIS")?;
    if !(0..=999).contains(&naxis) {
        return Err(IoError::malformed(
            path,
            format!("FITS NAXIS = {naxis} is invalid"),
        ));
    }
    let mut naxes = Vec::with_capacity(naxis as usize);
    for k in 1..=naxis {
        let n = required(&format!("NAXIS{k}"))?;
        if n < 0 {
            return Err(IoError::malformed(
                path,
                format!("FITS NAXIS{k} = {n} is negative"),
            ));
        }
        naxes.push(n as usize);
    }
    if naxes.first() == Some(&0) && find("GROUPS") == Some(Value::Logical(true)) {
        return Err(IoError::unexpected(
            path,
            "FITS random groups",
            "a primary-HDU image",
        ));
    }
    Ok(FitsHeader {
        bitpix: bitpix as i32,
        naxes,
        bscale: real("BSCALE", 1.0)?,
        bzero: real("BZERO", 0.0)?,
        blank: if bitpix > 0 { integer("BLANK")? } else { None },
        data_offset: (blocks * BLOCK) as u64,
    })
}

/// Big-endian signed integer of 1 (unsigned, as FITS BITPIX 8), 2, 4 or 8 bytes.
pub(crate) fn be_int(bytes: &[u8]) -> i64 {
    match bytes.len() {
        1 => bytes[0] as i64,
        2 => i16::from_be_bytes([bytes[0], bytes[1]]) as i64,
        4 => i32::from_be_bytes(bytes.try_into().unwrap()) as i64,
        8 => i64::from_be_bytes(bytes.try_into().unwrap()),
        n => unreachable!("no {n}-byte FITS integer"),
    }
}

fn open_header(path: &Path) -> Result<(BufReader<File>, FitsHeader), IoError> {
    let file = File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut reader = BufReader::new(file);
    let header = read_header(path, &mut reader)?;
    if header.naxes.is_empty() {
        return Err(IoError::unexpected(
            path,
            "no image in the primary HDU (NAXIS = 0)",
            "a primary-HDU image (images in FITS extensions are not supported)",
        ));
    }
    Ok((reader, header))
}

/// Reads the primary image as physical values (`BZERO + BSCALE * stored`).
pub fn read_array(path: &Path) -> Result<Array, IoError> {
    let (mut reader, header) = open_header(path)?;
    let count = header.value_count();
    let size = header.bytes_per_value();
    let mut bytes = vec![0u8; count * size];
    reader.read_exact(&mut bytes).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            IoError::malformed(
                path,
                format!(
                    "file is truncated: the FITS image {} needs {} data bytes",
                    shape_string(&header.shape()),
                    count * size
                ),
            )
        } else {
            IoError::io(path, e)
        }
    })?;
    let (scale, zero) = (header.bscale, header.bzero);
    let physical = |v: f64| zero + scale * v;
    let data: Vec<f64> = match header.bitpix {
        -32 => bytes
            .chunks_exact(4)
            .map(|b| physical(f32::from_be_bytes(b.try_into().unwrap()) as f64))
            .collect(),
        -64 => bytes
            .chunks_exact(8)
            .map(|b| physical(f64::from_be_bytes(b.try_into().unwrap())))
            .collect(),
        _ => bytes
            .chunks_exact(size)
            .map(|b| {
                let raw = be_int(b);
                if header.blank == Some(raw) {
                    f64::NAN
                } else {
                    physical(raw as f64)
                }
            })
            .collect(),
    };
    Ok(Array {
        shape: header.shape(),
        data,
    })
}

/// Locates the frames of an integer FITS image of NAXIS 2 or 3.
pub(crate) fn frame_layout(path: &Path, file: &mut File) -> Result<FrameLayout, IoError> {
    let header = {
        let mut reader = BufReader::new(&mut *file);
        read_header(path, &mut reader)?
    };
    file.rewind().map_err(|e| IoError::io(path, e))?;
    let expected = "an integer image (BITPIX 8, 16, 32 or 64, BSCALE 1, integer BZERO) \
                    of NAXIS 2 (one frame) or 3 (NAXIS3 frames)";
    let found = format!(
        "BITPIX {}, BSCALE {}, BZERO {}, shape {} (NAXIS = {})",
        header.bitpix,
        header.bscale,
        header.bzero,
        shape_string(&header.shape()),
        header.naxes.len()
    );
    if header.bitpix < 0
        || header.bscale != 1.0
        || header.bzero.fract() != 0.0
        || header.bzero.abs() > (1u64 << 62) as f64
    {
        return Err(IoError::unexpected(path, found, expected));
    }
    let shape = match header.naxes[..] {
        [width, height] => FrameShape {
            frames: 1,
            height,
            width,
        },
        [width, height, frames] => FrameShape {
            frames,
            height,
            width,
        },
        _ => return Err(IoError::unexpected(path, found, expected)),
    };
    let encoding = if header.bitpix == 8 && header.bzero == 0.0 && header.blank.is_none() {
        Encoding::U8
    } else {
        Encoding::FitsInt {
            bytes: header.bytes_per_value(),
            zero: header.bzero as i64,
            blank: header.blank,
        }
    };
    Ok(FrameLayout {
        shape,
        data_offset: header.data_offset,
        encoding,
        preloaded: None,
    })
}

fn card(key: &str, value: &str, comment: &str) -> String {
    let mut c = format!("{key:<8}= {value:>20}");
    if !comment.is_empty() {
        c.push_str(" / ");
        c.push_str(comment);
    }
    c.truncate(CARD);
    format!("{c:<80}")
}

/// Writes a primary-HDU image; `shape` in NumPy order (slowest first).
pub fn write<T: Element>(path: &Path, shape: &[usize], data: &[T]) -> Result<(), IoError> {
    let mut header = String::new();
    header.push_str(&card("SIMPLE", "T", "conforms to FITS standard"));
    header.push_str(&card(
        "BITPIX",
        &T::BITPIX.to_string(),
        "bits per data value",
    ));
    header.push_str(&card("NAXIS", &shape.len().to_string(), "number of axes"));
    let names = ["columns (fastest)", "rows", "frames"];
    for (k, n) in shape.iter().rev().enumerate() {
        header.push_str(&card(
            &format!("NAXIS{}", k + 1),
            &n.to_string(),
            names.get(k).copied().unwrap_or(""),
        ));
    }
    if let Some(zero) = T::BZERO {
        header.push_str(&card(
            "BZERO",
            &zero.to_string(),
            "unsigned data: physical = stored + BZERO",
        ));
        header.push_str(&card("BSCALE", "1", ""));
    }
    header.push_str(&format!("{:<80}", "END"));
    let mut bytes = header.into_bytes();
    bytes.resize(bytes.len().div_ceil(BLOCK) * BLOCK, b' ');
    bytes.reserve(data.len() * (T::BITPIX.unsigned_abs() as usize / 8) + BLOCK);
    for &v in data {
        v.put_fits(&mut bytes);
    }
    bytes.resize(bytes.len().div_ceil(BLOCK) * BLOCK, 0);
    let file = File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut writer = BufWriter::new(file);
    writer
        .write_all(&bytes)
        .and_then(|_| writer.flush())
        .map_err(|e| IoError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::super::test_util::temp_dir;
    use super::super::{read_array, read_frames, write_array, FrameSource};
    use super::*;

    /// Builds a FITS file from header cards (without END) and raw data bytes.
    fn raw_fits(cards: &[(&str, &str)], data: &[u8]) -> Vec<u8> {
        let mut h = String::new();
        for (k, v) in cards {
            h.push_str(&card(k, v, ""));
        }
        h.push_str(&format!("{:<80}", "END"));
        let mut out = h.into_bytes();
        out.resize(out.len().div_ceil(BLOCK) * BLOCK, b' ');
        out.extend_from_slice(data);
        out.resize(out.len().div_ceil(BLOCK) * BLOCK, 0);
        out
    }

    #[test]
    fn written_file_layout() {
        let dir = temp_dir("fitslayout");
        let path = dir.join("u16.fits");
        write_array(&path, &[2, 3], &[0u16, 1, 32768, 65535, 2, 3]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 2 * BLOCK);
        let text = std::str::from_utf8(&bytes[..BLOCK]).unwrap();
        assert!(text.starts_with("SIMPLE  =                    T"));
        assert!(text.contains("BITPIX  =                   16"));
        assert!(text.contains("NAXIS1  =                    3"));
        assert!(text.contains("NAXIS2  =                    2"));
        assert!(text.contains("BZERO   =                32768"));
        // stored = value - 32768, big-endian
        assert_eq!(
            &bytes[BLOCK..BLOCK + 8],
            &[0x80, 0x00, 0x80, 0x01, 0x00, 0x00, 0x7f, 0xff]
        );
        let header = read_header(&path, &mut &bytes[..]).unwrap();
        assert_eq!(header.naxes, vec![3, 2]);
        assert_eq!(header.bzero, 32768.0);
        assert_eq!(header.data_offset, BLOCK as u64);
    }

    #[test]
    fn round_trips_all_bitpix() {
        let dir = temp_dir("fitsrt");
        let p = dir.join("a.fits");
        let f: Vec<f64> = (0..12).map(|i| i as f64 * 1.5 - 4.0).collect();
        write_array(&p, &[3, 4], &f).unwrap();
        let back = read_array(&p).unwrap();
        assert_eq!((back.shape.clone(), back.data), (vec![3, 4], f.clone()));

        let f32s: Vec<f32> = f.iter().map(|&v| v as f32).collect();
        write_array(&p, &[2, 2, 3], &f32s).unwrap();
        let back = read_array(&p).unwrap();
        assert_eq!(back.shape, vec![2, 2, 3]);
        assert_eq!(back.data, f);

        let ints: Vec<i32> = vec![-70000, 0, 1, 70000];
        write_array(&p, &[4], &ints).unwrap();
        assert_eq!(
            read_array(&p).unwrap().data,
            vec![-70000.0, 0.0, 1.0, 70000.0]
        );

        let i16s: Vec<i16> = vec![-32768, -1, 0, 32767];
        write_array(&p, &[2, 2], &i16s).unwrap();
        assert_eq!(
            read_array(&p).unwrap().data,
            vec![-32768.0, -1.0, 0.0, 32767.0]
        );

        let u16s: Vec<u16> = vec![0, 1, 32767, 32768, 65535, 12345];
        write_array(&p, &[3, 2], &u16s).unwrap();
        let back = read_array(&p).unwrap();
        assert_eq!(
            back.data,
            vec![0.0, 1.0, 32767.0, 32768.0, 65535.0, 12345.0]
        );

        let u8s: Vec<u8> = vec![0, 1, 128, 255];
        write_array(&p, &[2, 2], &u8s).unwrap();
        assert_eq!(read_array(&p).unwrap().data, vec![0.0, 1.0, 128.0, 255.0]);
    }

    #[test]
    fn bscale_bzero_and_blank_applied_to_maps() {
        let dir = temp_dir("fitsscale");
        let p = dir.join("s.fits");
        let data: Vec<u8> = [10i16, -2, 7, 99]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        std::fs::write(
            &p,
            raw_fits(
                &[
                    ("SIMPLE", "T"),
                    ("BITPIX", "16"),
                    ("NAXIS", "2"),
                    ("NAXIS1", "2"),
                    ("NAXIS2", "2"),
                    ("BSCALE", "0.5D0"),
                    ("BZERO", "1.0E2"),
                    ("BLANK", "99"),
                ],
                &data,
            ),
        )
        .unwrap();
        let a = read_array(&p).unwrap();
        assert_eq!(a.data[..3], [105.0, 99.0, 103.5]);
        assert!(a.data[3].is_nan());
        // not integer frames
        let msg = FrameSource::open(&p).unwrap_err().to_string();
        assert!(msg.contains("BSCALE 0.5"), "{msg}");
    }

    #[test]
    fn frames_with_signed_16_bit_and_32_bit_data() {
        let dir = temp_dir("fitsframes");
        let p = dir.join("s16.fits");
        // BITPIX 16 without BZERO: non-negative values are fine, negatives are errors.
        let data: Vec<u8> = [5i16, 4095, 0, 12]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let cards = [
            ("SIMPLE", "T"),
            ("BITPIX", "16"),
            ("NAXIS", "3"),
            ("NAXIS1", "2"),
            ("NAXIS2", "1"),
            ("NAXIS3", "2"),
        ];
        std::fs::write(&p, raw_fits(&cards, &data)).unwrap();
        let cube = read_frames(&p).unwrap();
        assert_eq!(cube.shape.frames, 2);
        assert_eq!(cube.pixels, vec![5, 4095, 0, 12]);
        let data: Vec<u8> = [5i16, 4095, 0, -3]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        std::fs::write(&p, raw_fits(&cards, &data)).unwrap();
        let err = read_frames(&p).unwrap_err();
        assert!(
            matches!(
                err,
                IoError::PixelRange {
                    frame: 1,
                    row: 0,
                    column: 1,
                    value: -3,
                    ..
                }
            ),
            "{err:?}"
        );
        // BITPIX 32 within range
        let p = dir.join("s32.fits");
        let data: Vec<u8> = [0i32, 65535].iter().flat_map(|v| v.to_be_bytes()).collect();
        let cards = [
            ("SIMPLE", "T"),
            ("BITPIX", "32"),
            ("NAXIS", "2"),
            ("NAXIS1", "2"),
            ("NAXIS2", "1"),
        ];
        std::fs::write(&p, raw_fits(&cards, &data)).unwrap();
        assert_eq!(read_frames(&p).unwrap().pixels, vec![0, 65535]);
        // BZERO 32768 with BLANK: the blank pixel is named
        let p = dir.join("blank.fits");
        let data: Vec<u8> = [-32768i16, 7]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let cards = [
            ("SIMPLE", "T"),
            ("BITPIX", "16"),
            ("NAXIS", "2"),
            ("NAXIS1", "2"),
            ("NAXIS2", "1"),
            ("BZERO", "32768"),
            ("BLANK", "7"),
        ];
        std::fs::write(&p, raw_fits(&cards, &data)).unwrap();
        let mut source = FrameSource::open(&p).unwrap();
        let err = source.read_frame(0).unwrap_err();
        assert!(
            matches!(
                err,
                IoError::BlankPixel {
                    frame: 0,
                    row: 0,
                    column: 1,
                    ..
                }
            ),
            "{err:?}"
        );
    }

    #[test]
    fn float_frames_and_bad_headers_rejected() {
        let dir = temp_dir("fitsbad");
        let p = dir.join("f.fits");
        write_array(&p, &[2, 2], &[1.0f64; 4]).unwrap();
        let msg = FrameSource::open(&p).unwrap_err().to_string();
        assert!(
            msg.contains("f.fits") && msg.contains("BITPIX -64"),
            "{msg}"
        );
        assert!(msg.contains("expected an integer image"), "{msg}");

        write_array(&p, &[1, 2, 2, 2], &[1u16; 8]).unwrap();
        let msg = FrameSource::open(&p).unwrap_err().to_string();
        assert!(msg.contains("NAXIS = 4"), "{msg}");

        std::fs::write(
            &p,
            raw_fits(&[("SIMPLE", "T"), ("BITPIX", "16"), ("NAXIS", "0")], &[]),
        )
        .unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(msg.contains("NAXIS = 0"), "{msg}");

        std::fs::write(
            &p,
            raw_fits(&[("SIMPLE", "T"), ("BITPIX", "12"), ("NAXIS", "0")], &[]),
        )
        .unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(msg.contains("BITPIX = 12"), "{msg}");

        std::fs::write(&p, b"\x93NUMPY not a fits file").unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(msg.contains("not a FITS file"), "{msg}");

        // header without END
        let mut h = card("SIMPLE", "T", "");
        while h.len() < BLOCK {
            h.push(' ');
        }
        std::fs::write(&p, h).unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(msg.contains("before its END"), "{msg}");

        // truncated data
        write_array(&p, &[100, 100], &[1.0f64; 10000]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..BLOCK * 3]).unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(msg.contains("truncated"), "{msg}");
    }

    #[test]
    fn parses_card_values() {
        assert_eq!(
            parse_value("                   T / c"),
            Value::Logical(true)
        );
        assert_eq!(
            parse_value("                32768 / x"),
            Value::Integer(32768)
        );
        assert_eq!(parse_value("   3.2768E4"), Value::Real(32768.0));
        assert_eq!(parse_value(" 1.5D-1"), Value::Real(0.15));
        assert_eq!(
            parse_value(" 'it''s / here'  / comment"),
            Value::Other("it's / here".into())
        );
    }

    #[test]
    fn multi_block_header() {
        let dir = temp_dir("fitsblocks");
        let p = dir.join("m.fits");
        let mut cards: Vec<(String, String)> = vec![
            ("SIMPLE".into(), "T".into()),
            ("BITPIX".into(), "8".into()),
            ("NAXIS".into(), "2".into()),
            ("NAXIS1".into(), "3".into()),
            ("NAXIS2".into(), "2".into()),
        ];
        for i in 0..40 {
            cards.push((format!("KEY{i}"), format!("{i}")));
        }
        let refs: Vec<(&str, &str)> = cards
            .iter()
            .map(|(a, b)| (a.as_str(), b.as_str()))
            .collect();
        std::fs::write(&p, raw_fits(&refs, &[1, 2, 3, 4, 5, 6])).unwrap();
        let cube = read_frames(&p).unwrap();
        assert_eq!(cube.pixels, vec![1, 2, 3, 4, 5, 6]);
        assert_eq!(FrameSource::open(&p).unwrap().shape().width, 3);
    }
}
