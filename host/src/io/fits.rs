//! The FITS writer of plain arrays (`write_array`, and the growing image of
//! `stream --out`, [`super::Appender`]): a primary-HDU image, `SIMPLE`,
//! `BITPIX`, `NAXISn`, and for `u16` data `BZERO = 32768` / `BSCALE = 1`;
//! header and data padded to 2880 bytes. It stays hand-written because the
//! appender must rewrite `NAXIS3` in place after every frame so that a killed
//! process leaves a valid file, which cfitsio's buffered writes do not
//! promise. Reading (every HDU, tile compression, scaling) is cfitsio's:
//! `fits_in.rs`; results with extensions and keywords: `fits_out.rs`.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use super::{Element, IoError};

/// FITS block size in bytes.
pub const BLOCK: usize = 2880;
const CARD: usize = 80;

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
        // cfitsio reads it back
        let back = read_array(&path).unwrap();
        assert_eq!(back.shape, [2, 3]);
        assert_eq!(back.data, [0.0, 1.0, 32768.0, 65535.0, 2.0, 3.0]);
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
        // As frames: the scaled 105 is a count; 99.0 * 0.5 + 100 = 149.5 is not.
        let mut source = FrameSource::open(&p).unwrap();
        let msg = source.read_frame(0).unwrap_err().to_string();
        assert!(
            msg.contains("row 1, column 0") && msg.contains("not a whole camera count"),
            "{msg}"
        );
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
    fn float_frames_and_bad_files_rejected() {
        let dir = temp_dir("fitsbad");
        let p = dir.join("f.fits");
        // Floating-point frames: whole counts are read, others named.
        write_array(&p, &[2, 2], &[1.0f64, 2.0, 3.0, 4.5]).unwrap();
        let mut source = FrameSource::open(&p).unwrap();
        let msg = source.read_frame(0).unwrap_err().to_string();
        assert!(
            msg.contains("f.fits") && msg.contains("value 4.5") && msg.contains("row 1, column 1"),
            "{msg}"
        );
        write_array(&p, &[2, 2], &[1.0f32, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(read_frames(&p).unwrap().pixels, [1, 2, 3, 4]);

        write_array(&p, &[1, 2, 2, 2], &[1u16; 8]).unwrap();
        let msg = FrameSource::open(&p).unwrap_err().to_string();
        assert!(msg.contains("NAXIS = 4"), "{msg}");

        // No data anywhere: the HDUs are listed.
        std::fs::write(
            &p,
            raw_fits(&[("SIMPLE", "T"), ("BITPIX", "16"), ("NAXIS", "0")], &[]),
        )
        .unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(
            msg.contains("no image with data") && msg.contains("0: no data"),
            "{msg}"
        );

        // SIMPLE = F: not conforming FITS, refused naming the file and the card,
        // though cfitsio would read it.
        std::fs::write(
            &p,
            raw_fits(
                &[
                    ("SIMPLE", "F"),
                    ("BITPIX", "16"),
                    ("NAXIS", "2"),
                    ("NAXIS1", "2"),
                    ("NAXIS2", "2"),
                ],
                &[0u8; 8],
            ),
        )
        .unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(
            msg.contains("f.fits")
                && msg.contains("SIMPLE  =                    F")
                && msg.contains("does not conform"),
            "{msg}"
        );
        assert!(FrameSource::open(&p).is_err());

        std::fs::write(&p, b"\x93NUMPY not a fits file").unwrap();
        let msg = read_array(&p).unwrap_err().to_string();
        assert!(msg.contains("not a readable FITS file"), "{msg}");

        // truncated data
        write_array(&p, &[100, 100], &[1.0f64; 10000]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..BLOCK * 3]).unwrap();
        assert!(read_array(&p).is_err());
    }

    /// An image in an extension (the primary HDU empty, a table beside
    /// it, as camera software and astropy write), a tile-compressed cube,
    /// and `--hdu` by index and by name.
    #[test]
    fn extension_and_tile_compressed_frames() {
        use fitsio::images::{ImageDescription, ImageType};
        let dir = temp_dir("fitsext");
        let pixels: Vec<u16> = (0..2 * 3 * 4).map(|v| (v * 1000) as u16).collect();
        let description = ImageDescription {
            data_type: ImageType::UnsignedShort,
            dimensions: &[2, 3, 4],
        };
        let ext = dir.join("ext.fits");
        {
            let mut f = fitsio::FitsFile::create(&ext).open().unwrap();
            let hdu = f
                .create_image(
                    "DARK",
                    &ImageDescription {
                        data_type: ImageType::UnsignedShort,
                        dimensions: &[3, 4],
                    },
                )
                .unwrap();
            hdu.write_image(&mut f, &[7u16; 12]).unwrap();
            let hdu = f.create_image("SCI", &description).unwrap();
            hdu.write_image(&mut f, &pixels).unwrap();
        }
        // The first image with data is DARK (one frame); SCI by name or index.
        let dark = read_frames(&ext).unwrap();
        assert_eq!((dark.shape.frames, dark.pixels[0]), (1, 7));
        for hdu in ["SCI", "sci", "2"] {
            let cube = FrameSource::open_hdu(&ext, Some(hdu))
                .unwrap()
                .read_all()
                .unwrap();
            assert_eq!(cube.shape.frames, 2);
            assert_eq!((cube.shape.height, cube.shape.width), (3, 4));
            assert_eq!(cube.pixels, pixels);
        }
        let msg = FrameSource::open_hdu(&ext, Some("FLAT"))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("no HDU 'FLAT'") && msg.contains("2 'SCI': image (2, 3, 4)"),
            "{msg}"
        );

        // Tile-compressed (Rice), written by cfitsio's extended file name.
        let packed = dir.join("packed.fits");
        {
            let name = format!("{}[compress R]", packed.display());
            let mut f = fitsio::FitsFile::create(&name).open().unwrap();
            let hdu = f.create_image("SCI", &description).unwrap();
            hdu.write_image(&mut f, &pixels).unwrap();
        }
        let raw = std::fs::read(&packed).unwrap();
        let text = String::from_utf8_lossy(&raw);
        assert!(
            text.contains("ZIMAGE") && text.contains("RICE_1"),
            "not tile-compressed"
        );
        let cube = read_frames(&packed).unwrap();
        assert_eq!(cube.shape.frames, 2);
        assert_eq!(cube.pixels, pixels);
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
