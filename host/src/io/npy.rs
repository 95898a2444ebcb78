//! NumPy `.npy` files through the `npyz` crate.
//!
//! Reading accepts format versions 1-3, both byte orders, C or Fortran order.
//! Writing always produces C-ordered little-endian version-1 files.

use std::fs::File;
use std::io::{BufReader, BufWriter, Seek};
use std::path::Path;

use npyz::{DType, NpyFile, NpyHeader, Order, TypeChar, WriterBuilder};

use super::{shape_string, Array, Element, Encoding, FrameLayout, FrameShape, IoError};

fn header_error(path: &Path, e: std::io::Error) -> IoError {
    if e.kind() == std::io::ErrorKind::UnexpectedEof || e.kind() == std::io::ErrorKind::InvalidData
    {
        IoError::malformed(path, format!("not a readable NumPy .npy file: {e}"))
    } else {
        IoError::io(path, e)
    }
}

fn shape_of(header: &NpyHeader) -> Vec<usize> {
    header.shape().iter().map(|&d| d as usize).collect()
}

/// `uint16 ('<u2')`-style description of a dtype.
fn describe_dtype(dtype: &DType) -> String {
    match dtype {
        DType::Plain(ts) => {
            let name = match ts.type_char() {
                TypeChar::Bool => "bool".to_string(),
                TypeChar::Int => format!("int{}", ts.size_field() * 8),
                TypeChar::Uint => format!("uint{}", ts.size_field() * 8),
                TypeChar::Float => format!("float{}", ts.size_field() * 8),
                TypeChar::Complex => format!("complex{}", ts.size_field() * 8),
                _ => "non-numeric".to_string(),
            };
            format!("{name} ('{ts}')")
        }
        other => format!("a structured dtype ({})", other.descr()),
    }
}

/// Element (i0, .., in-1) of a Fortran-ordered array is at
/// `i0 + n0 * (i1 + n1 * (...))`; returns the data in C order.
pub(crate) fn fortran_to_c<T: Copy>(data: &[T], shape: &[usize]) -> Vec<T> {
    if shape.len() <= 1 {
        return data.to_vec();
    }
    let ndim = shape.len();
    // Fortran strides.
    let mut strides = vec![1usize; ndim];
    for k in 1..ndim {
        strides[k] = strides[k - 1] * shape[k - 1];
    }
    let total: usize = shape.iter().product();
    let mut out = Vec::with_capacity(total);
    let mut index = vec![0usize; ndim];
    for _ in 0..total {
        let offset: usize = index.iter().zip(&strides).map(|(i, s)| i * s).sum();
        out.push(data[offset]);
        // increment the C-order multi-index (last axis fastest)
        for k in (0..ndim).rev() {
            index[k] += 1;
            if index[k] < shape[k] {
                break;
            }
            index[k] = 0;
        }
    }
    out
}

/// Checks the `.npy` prefix (magic, version, header length) against the
/// file's size before a reader trusts it, and returns the data offset and
/// the file's length. (A 128-byte file whose header length field says 3.6 GB
/// made the reader allocate that much: found by `fuzz/`'s npy_reader.)
fn check_prefix(path: &Path, file: &mut File) -> Result<(u64, u64), IoError> {
    use std::io::Read;
    let io = |e| IoError::io(path, e);
    let len = file.metadata().map_err(io)?.len();
    let mut prefix = [0u8; 12];
    let n = file.read(&mut prefix).map_err(io)?;
    file.seek(std::io::SeekFrom::Start(0)).map_err(io)?;
    if n < 10 || &prefix[..6] != b"\x93NUMPY" {
        return Err(IoError::malformed(
            path,
            "not a readable NumPy .npy file (no \\x93NUMPY magic)",
        ));
    }
    let (header_len, header_start) = match prefix[6] {
        1 => (u16::from_le_bytes([prefix[8], prefix[9]]) as u64, 10),
        2 | 3 if n == 12 => (
            u32::from_le_bytes([prefix[8], prefix[9], prefix[10], prefix[11]]) as u64,
            12,
        ),
        v => {
            return Err(IoError::malformed(
                path,
                format!(".npy format version {v} is not 1, 2 or 3"),
            ))
        }
    };
    if header_start + header_len > len {
        return Err(IoError::malformed(
            path,
            format!("the .npy header claims {header_len} bytes; the file has {len}"),
        ));
    }
    // A header is one flat dictionary (descr, fortran_order, shape). The
    // reader's literal parser backtracks exponentially on nesting (a
    // 126-byte header of 22 '{' took over 10 s, and one of 55 '[' as long:
    // fuzz/'s npy_reader), so a header with more than one brace, more than
    // one parenthesis (the shape's tuple) or any bracket (a structured
    // dtype's list, which no reader here takes) is refused before it is
    // parsed.
    let mut header = vec![0u8; header_len.min(1 << 16) as usize];
    file.seek(std::io::SeekFrom::Start(header_start))
        .map_err(io)?;
    file.read_exact(&mut header).map_err(io)?;
    file.seek(std::io::SeekFrom::Start(0)).map_err(io)?;
    let count = |c: u8| header.iter().filter(|&&b| b == c).count();
    if count(b'{') > 1 {
        return Err(IoError::malformed(
            path,
            "the .npy header is not one flat dictionary (nested braces)",
        ));
    }
    if count(b'[') > 0 || count(b'(') > 1 {
        return Err(IoError::malformed(
            path,
            "the .npy header is not one flat dictionary of a plain dtype and a shape (nested brackets)",
        ));
    }
    Ok((header_start + header_len, len))
}

/// Reads any integer or float `.npy` array as `f64`, in C order.
pub fn read_array(path: &Path) -> Result<Array, IoError> {
    let mut file = File::open(path).map_err(|e| IoError::io(path, e))?;
    let (data_offset, file_len) = check_prefix(path, &mut file)?;
    let npy = NpyFile::new(BufReader::new(file)).map_err(|e| header_error(path, e))?;
    let shape = shape_of(npy.header());
    // The data the shape promises must be in the file (before allocating it).
    let values = shape.iter().try_fold(1u64, |n, &d| n.checked_mul(d as u64));
    let item = npy.header().dtype().num_bytes().unwrap_or(1) as u64;
    match values.and_then(|v| v.checked_mul(item)) {
        Some(bytes) if bytes <= file_len - data_offset => {}
        _ => {
            return Err(IoError::malformed(
                path,
                format!(
                    "the .npy header's shape {} needs more data than the file's {} bytes",
                    shape_string(&shape),
                    file_len - data_offset
                ),
            ))
        }
    }
    let order = npy.header().order();
    let dtype = npy.header().dtype();
    let unsupported = || {
        IoError::unexpected(
            path,
            format!("dtype {}", describe_dtype(&dtype)),
            "an integer or floating-point array",
        )
    };
    let ts = match &dtype {
        DType::Plain(ts) => ts.clone(),
        _ => return Err(unsupported()),
    };
    macro_rules! read_as {
        ($t:ty) => {
            npy.into_vec::<$t>()
                .map_err(|e| header_error(path, e))?
                .into_iter()
                .map(|v| v as f64)
                .collect::<Vec<f64>>()
        };
    }
    let data: Vec<f64> = match (ts.type_char(), ts.size_field()) {
        (TypeChar::Float, 8) => read_as!(f64),
        (TypeChar::Float, 4) => read_as!(f32),
        (TypeChar::Int, 1) => read_as!(i8),
        (TypeChar::Int, 2) => read_as!(i16),
        (TypeChar::Int, 4) => read_as!(i32),
        (TypeChar::Int, 8) => read_as!(i64),
        (TypeChar::Uint, 1) => read_as!(u8),
        (TypeChar::Uint, 2) => read_as!(u16),
        (TypeChar::Uint, 4) => read_as!(u32),
        (TypeChar::Uint, 8) => read_as!(u64),
        _ => return Err(unsupported()),
    };
    let data = match order {
        Order::C => data,
        Order::Fortran => fortran_to_c(&data, &shape),
    };
    Ok(Array { shape, data })
}

/// Locates the frames of a uint8/uint16 `.npy` of shape (frames, height,
/// width) or (height, width).
pub(crate) fn frame_layout(path: &Path, file: &mut File) -> Result<FrameLayout, IoError> {
    check_prefix(path, file)?;
    let header = NpyHeader::from_reader(&mut *file).map_err(|e| header_error(path, e))?;
    let data_offset = file.stream_position().map_err(|e| IoError::io(path, e))?;
    let dims = shape_of(&header);
    let dtype = header.dtype();
    let expected = "a uint8 or uint16 array of shape (frames, height, width) or (height, width)";
    let found = || {
        format!(
            "dtype {} with shape {}",
            describe_dtype(&dtype),
            shape_string(&dims)
        )
    };
    let encoding = match &dtype {
        DType::Plain(ts) => match (ts.type_char(), ts.size_field()) {
            (TypeChar::Uint, 1) => Encoding::U8,
            (TypeChar::Uint, 2) => Encoding::U16 {
                big_endian: ts.endianness() == npyz::Endianness::Big,
            },
            _ => return Err(IoError::unexpected(path, found(), expected)),
        },
        _ => return Err(IoError::unexpected(path, found(), expected)),
    };
    let shape = match dims[..] {
        [frames, height, width] => FrameShape {
            frames,
            height,
            width,
        },
        [height, width] => FrameShape {
            frames: 1,
            height,
            width,
        },
        _ => return Err(IoError::unexpected(path, found(), expected)),
    };
    let preloaded = if header.order() == Order::Fortran && dims.len() > 1 {
        // Not contiguous per frame: load and reorder the whole cube.
        let npy = NpyFile::with_header(header, BufReader::new(&mut *file));
        let raw: Vec<u16> = match encoding {
            Encoding::U8 => npy
                .into_vec::<u8>()
                .map_err(|e| header_error(path, e))?
                .into_iter()
                .map(u16::from)
                .collect(),
            _ => npy.into_vec::<u16>().map_err(|e| header_error(path, e))?,
        };
        Some(fortran_to_c(&raw, &dims))
    } else {
        None
    };
    Ok(FrameLayout {
        shape,
        data_offset,
        encoding,
        preloaded,
    })
}

/// Writes a C-ordered `.npy` of the element type's native NumPy dtype.
pub fn write<T: Element>(path: &Path, shape: &[usize], data: &[T]) -> Result<(), IoError> {
    let file = File::create(path).map_err(|e| IoError::io(path, e))?;
    let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
    let result = (|| {
        let mut writer = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&shape)
            .writer(BufWriter::new(file))
            .begin_nd()?;
        writer.extend(data.iter().copied())?;
        writer.finish()
    })();
    result.map_err(|e| IoError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::super::test_util::temp_dir;
    use super::super::{read_array, read_frames, write_array, FrameSource};
    use super::*;

    /// A hand-made .npy (version 1) with the given descr, order and shape.
    fn raw_npy(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
        let mut dict = format!(
            "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}",
            if fortran { "True" } else { "False" }
        );
        while (10 + dict.len() + 1) % 64 != 0 {
            dict.push(' ');
        }
        dict.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        out.extend_from_slice(dict.as_bytes());
        out.extend_from_slice(data);
        out
    }

    /// Found by the npy_reader fuzz target: nested braces in the header
    /// took the header parser over 10 s; refused at once.
    #[test]
    fn nested_braces_in_the_header_are_refused() {
        use base64_free::decode;
        let bytes = decode("k05VTVBZAQB2AHsnZGVzY3InOiAnfHUxJywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJyVzaGFwZUAnOiAoMyx7e3t7e3t7e3t7e3t7e3t7e3t7e3t7eyA1LCApLCB9ICAgICAgICAgICAgICAgICAgICAgICAgISAgICAgICAgICAgICAgICAgICAgIDAgICAgICAgICAgCgB+AAAABQYHCAkKCwwNDg==");
        let dir = temp_dir("nested");
        let path = dir.join("nested.npy");
        std::fs::write(&path, bytes).unwrap();
        let started = std::time::Instant::now();
        let e = read_array(&path).unwrap_err();
        assert!(e.to_string().contains("nested braces"), "{e}");
        let e = read_frames(&path).unwrap_err();
        assert!(e.to_string().contains("nested braces"), "{e}");
        // Not a timed assertion of speed: a hang guard far above any machine.
        assert!(started.elapsed().as_secs() < 5);
    }

    /// Found by the npy_reader fuzz target after the test above: 55 '['
    /// in the header took the header parser over 10 s; refused at once.
    #[test]
    fn nested_brackets_in_the_header_are_refused() {
        use base64_free::decode;
        let bytes = decode("k05VTVBZAQB2AHsnZGVzY3YnOiAnPGk0JyxbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbW1tbWyAnZm9ydHJhbl9vcmRlcic6IEZhbHNlLCAnc2hkVHJ1ZWVyJzogRmFsc2UsICdzaGFwZW9ydHJhbl9vcmRlcic6IEZhbFxcXDogc2hhcGUnOiAoMiwgMiwgKSwgfSAgICAgICAgICAgICAg////////////////////////////////////////////////////////////////////SP8gICAgIAr/////AgAAAHARAQAEAAAA");
        let dir = temp_dir("brackets");
        let path = dir.join("brackets.npy");
        std::fs::write(&path, bytes).unwrap();
        let started = std::time::Instant::now();
        let e = read_array(&path).unwrap_err();
        assert!(e.to_string().contains("nested brackets"), "{e}");
        let e = read_frames(&path).unwrap_err();
        assert!(e.to_string().contains("nested brackets"), "{e}");
        // Not a timed assertion of speed: a hang guard far above any machine.
        assert!(started.elapsed().as_secs() < 5);
    }

    /// A minimal base64 decoder for the test's input (no dependency).
    mod base64_free {
        pub fn decode(text: &str) -> Vec<u8> {
            let value = |c: u8| match c {
                b'A'..=b'Z' => c - b'A',
                b'a'..=b'z' => c - b'a' + 26,
                b'0'..=b'9' => c - b'0' + 52,
                b'+' => 62,
                _ => 63,
            } as u32;
            let chars: Vec<u8> = text.bytes().filter(|&c| c != b'=').collect();
            let mut out = Vec::new();
            for chunk in chars.chunks(4) {
                let mut n = 0u32;
                for (k, &c) in chunk.iter().enumerate() {
                    n |= value(c) << (18 - 6 * k);
                }
                for k in 0..chunk.len().saturating_sub(1) {
                    out.push((n >> (16 - 8 * k)) as u8);
                }
            }
            out
        }
    }

    /// Found by the npy_reader fuzz target: a header length or a shape
    /// larger than the file is an error, not an allocation of gigabytes.
    #[test]
    fn lengths_beyond_the_file_are_refused_before_allocating() {
        let dir = temp_dir("npyhuge");
        let path = dir.join("huge.npy");
        // Version 3, header length 0xd884ff8a (3.6 GB), in a 128-byte file.
        let mut bytes = b"\x93NUMPY\x03\x00\x8a\xff\x84\xd8".to_vec();
        bytes.resize(128, b' ');
        std::fs::write(&path, &bytes).unwrap();
        for e in [
            read_array(&path).unwrap_err(),
            FrameSource::open(&path).err().unwrap(),
        ] {
            assert!(
                e.to_string().contains("header claims 3632594826 bytes"),
                "{e}"
            );
        }
        // A shape of 10^12 values with no data.
        std::fs::write(&path, raw_npy("<f8", false, "(1000000, 1000000)", &[])).unwrap();
        let e = read_array(&path).unwrap_err();
        assert!(e.to_string().contains("needs more data"), "{e}");
    }

    #[test]
    fn f64_round_trip_any_shape() {
        let dir = temp_dir("npyf64");
        let path = dir.join("slopes.npy");
        let data: Vec<f64> = (0..24).map(|i| i as f64 * 0.25 - 3.0).collect();
        write_array(&path, &[2, 6, 2], &data).unwrap();
        let back = read_array(&path).unwrap();
        assert_eq!(back.shape, vec![2, 6, 2]);
        assert_eq!(back.data, data);
    }

    #[test]
    fn integer_and_f32_maps_read_as_f64() {
        let dir = temp_dir("npyint");
        let path = dir.join("w.npy");
        write_array(&path, &[2, 2], &[1i32, -2, 3, 40000]).unwrap();
        assert_eq!(
            read_array(&path).unwrap().data,
            vec![1.0, -2.0, 3.0, 40000.0]
        );
        write_array(&path, &[3], &[0.5f32, 1.5, -2.0]).unwrap();
        let back = read_array(&path).unwrap();
        assert_eq!(back.shape, vec![3]);
        assert_eq!(back.data, vec![0.5, 1.5, -2.0]);
        write_array(&path, &[2], &[7u16, 65535]).unwrap();
        assert_eq!(read_array(&path).unwrap().data, vec![7.0, 65535.0]);
    }

    #[test]
    fn big_endian_uint16_frames() {
        let dir = temp_dir("npybe");
        let path = dir.join("be.npy");
        let values: [u16; 6] = [1, 2, 300, 40000, 5, 65535];
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        std::fs::write(&path, raw_npy(">u2", false, "(1, 2, 3)", &bytes)).unwrap();
        let cube = read_frames(&path).unwrap();
        assert_eq!(cube.pixels, values);
        assert_eq!(read_array(&path).unwrap().data[3], 40000.0);
    }

    #[test]
    fn fortran_order_is_reordered() {
        let dir = temp_dir("npyf");
        let path = dir.join("f.npy");
        // C-order [[1,2,3],[4,5,6]] stored column-major: 1,4,2,5,3,6
        let stored: [u16; 6] = [1, 4, 2, 5, 3, 6];
        let bytes: Vec<u8> = stored.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&path, raw_npy("<u2", true, "(2, 3)", &bytes)).unwrap();
        assert_eq!(read_frames(&path).unwrap().pixels, vec![1, 2, 3, 4, 5, 6]);
        assert_eq!(
            read_array(&path).unwrap().data,
            vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
        );
        // 3-D
        let shape = [2, 3, 4];
        let c: Vec<usize> = (0..24).collect();
        let mut f = vec![0usize; 24];
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..4 {
                    f[i + 2 * (j + 3 * k)] = c[(i * 3 + j) * 4 + k];
                }
            }
        }
        assert_eq!(fortran_to_c(&f, &shape), c);
    }

    #[test]
    fn wrong_frame_dtype_and_shape_are_named() {
        let dir = temp_dir("npywrong");
        let path = dir.join("bad.npy");
        write_array(&path, &[2, 3, 4], &[0.0f32; 24]).unwrap();
        let msg = FrameSource::open(&path).unwrap_err().to_string();
        assert!(msg.contains("bad.npy"), "{msg}");
        assert!(msg.contains("float32 ('<f4')"), "{msg}");
        assert!(msg.contains("(2, 3, 4)"), "{msg}");
        assert!(msg.contains("expected a uint8 or uint16 array"), "{msg}");

        write_array(&path, &[2, 3, 4], &[0i16; 24]).unwrap();
        let msg = FrameSource::open(&path).unwrap_err().to_string();
        assert!(msg.contains("int16 ('<i2')"), "{msg}");

        write_array(&path, &[1, 2, 3, 4], &[0u16; 24]).unwrap();
        let msg = FrameSource::open(&path).unwrap_err().to_string();
        assert!(
            msg.contains("uint16 ('<u2') with shape (1, 2, 3, 4)"),
            "{msg}"
        );

        write_array(&path, &[24], &[0u8; 24]).unwrap();
        let msg = FrameSource::open(&path).unwrap_err().to_string();
        assert!(msg.contains("shape (24,)"), "{msg}");
    }

    #[test]
    fn non_numeric_and_garbage_rejected() {
        let dir = temp_dir("npygarbage");
        let path = dir.join("b.npy");
        std::fs::write(&path, raw_npy("|b1", false, "(2,)", &[0, 1])).unwrap();
        let msg = read_array(&path).unwrap_err().to_string();
        assert!(
            msg.contains("bool") && msg.contains("integer or floating-point"),
            "{msg}"
        );
        std::fs::write(&path, b"SIMPLE  = T this is not npy").unwrap();
        let err = read_array(&path).unwrap_err();
        assert!(matches!(err, IoError::Malformed { .. }), "{err}");
        assert!(
            err.to_string().contains("not a readable NumPy .npy file"),
            "{err}"
        );
    }
}
