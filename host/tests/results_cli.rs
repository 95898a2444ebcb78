//! What `process --out` writes, read back: the .npy set (slopes, flux,
//! validity, provenance), FITS extensions with their keywords (read by
//! cfitsio), CSV rows, and the AO vector layout, all carrying the same
//! numbers as the reference computes.

mod common;
use common::run;

use std::path::{Path, PathBuf};

use brightpix::config_file::ProcessingConfig;
use brightpix::io::{read_array, write_array};
use brightpix::reference::Reference;

fn scratch(name: &str) -> PathBuf {
    common::scratch("results", name)
}

/// A 16x16 camera with four 8x8 sub-apertures (the last one dark, so
/// invalid), N = 5, and `count` frames.
fn case(dir: &Path, count: usize) -> (PathBuf, PathBuf, Vec<u16>) {
    let config = dir.join("small.toml");
    std::fs::write(
        &config,
        "[camera]\nwidth = 16\nheight = 16\nbit_depth = 12\n\
         [subapertures.grid]\nx = 0\ny = 0\ncolumns = 2\nrows = 2\nwidth = 8\nheight = 8\n\
         [selection]\npixels = 5\n[centroid]\nmin_flux_counts = 10\n",
    )
    .unwrap();
    let mut state = 11u64;
    let pixels: Vec<u16> = (0..count * 256)
        .map(|k| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let (row, col) = ((k % 256) / 16, k % 16);
            if row >= 8 && col >= 8 {
                0
            } else {
                (state % 4096) as u16
            }
        })
        .collect();
    let frames = dir.join("frames.npy");
    write_array(&frames, &[count, 16, 16], &pixels).unwrap();
    (config, frames, pixels)
}

/// The reference's results: (slopes [x, y] px, flux counts, valid).
fn expected(config: &Path, pixels: &[u16]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let config = ProcessingConfig::load(config).unwrap();
    let mut reference = Reference::new(&config.view()).unwrap();
    let (mut slopes, mut flux, mut valid) = (vec![], vec![], vec![]);
    for frame in pixels.chunks(256) {
        for o in reference.process_frame(frame).unwrap() {
            slopes.extend([o.slope_x as f64 / 65536.0, o.slope_y as f64 / 65536.0]);
            flux.push(o.flux as f64 / 16.0);
            valid.push(f64::from(u8::from(o.valid)));
        }
    }
    (slopes, flux, valid)
}

fn process(config: &Path, frames: &Path, out: &Path, extra: &[&str]) -> String {
    let mut args = vec![
        "process",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let (ok, text) = run(&args);
    assert!(ok, "{text}");
    text
}

#[test]
fn npy_set_holds_slopes_flux_validity_and_provenance() {
    let dir = scratch("npy");
    let (config, frames, pixels) = case(&dir, 6);
    let (slopes, flux, valid) = expected(&config, &pixels);
    assert!(valid.contains(&0.0) && valid.contains(&1.0), "{valid:?}");
    let out = dir.join("s.npy");
    let text = process(&config, &frames, &out, &[]);
    assert!(!text.contains("every sub-aperture is invalid"), "{text}");
    let s = read_array(&out).unwrap();
    assert_eq!(s.shape, [6, 4, 2]);
    assert_eq!(s.data, slopes);
    let f = read_array(dir.join("s.flux.npy")).unwrap();
    assert_eq!(f.shape, [6, 4]);
    assert_eq!(f.data, flux);
    let v = read_array(dir.join("s.valid.npy")).unwrap();
    assert_eq!(v.data, valid);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("s.json")).unwrap()).unwrap();
    assert_eq!(json["bprule"], "subtract-next");
    assert_eq!(json["bpnpix"], 5);
    assert_eq!(json["bpbits"], 12);
    assert_eq!(json["bpnframe"], 6);
    assert_eq!(json["bplayout"], "pairs");
    assert_eq!(json["bpvers"], env!("CARGO_PKG_VERSION"));
    assert_eq!(json["units"]["slopes"], "pixel");
    let view = ProcessingConfig::load(&config).unwrap();
    let digest = brightpix_protocol::wire::tables::config_digest(&view.view());
    assert_eq!(json["bpcfgdig"], format!("{digest:#010x}"));
    let crc = brightpix_protocol::wire::CRC32.checksum(&std::fs::read(&config).unwrap());
    assert_eq!(json["bpcfgcrc"], format!("{crc:#010x}"));

    // The AO vector layout: [x_0..x_3, y_0..y_3] per frame.
    let out = dir.join("v.npy");
    process(
        &config,
        &frames,
        &out,
        &["--layout", "vector", "--reference"],
    );
    let v = read_array(&out).unwrap();
    assert_eq!(v.shape, [6, 8]);
    for frame in 0..6 {
        for sub in 0..4 {
            assert_eq!(v.data[frame * 8 + sub], slopes[frame * 8 + 2 * sub]);
            assert_eq!(v.data[frame * 8 + 4 + sub], slopes[frame * 8 + 2 * sub + 1]);
        }
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn fits_has_extensions_units_and_provenance_keywords() {
    let dir = scratch("fits");
    let (config, frames, pixels) = case(&dir, 5);
    let (slopes, flux, valid) = expected(&config, &pixels);
    let out = dir.join("s.fits");
    process(&config, &frames, &out, &["--layout", "vector"]);
    let mut f = fitsio::FitsFile::open(&out).unwrap();
    let primary = f.primary_hdu().unwrap();
    let key = |f: &mut fitsio::FitsFile, k: &str| primary.read_key::<String>(f, k).unwrap();
    assert_eq!(key(&mut f, "BPRULE"), "subtract-next");
    assert_eq!(primary.read_key::<i64>(&mut f, "BPNPIX").unwrap(), 5);
    assert_eq!(primary.read_key::<i64>(&mut f, "BPBITS").unwrap(), 12);
    assert_eq!(primary.read_key::<i64>(&mut f, "BPNFRAME").unwrap(), 5);
    assert_eq!(primary.read_key::<i64>(&mut f, "BPFIRST").unwrap(), 0);
    assert_eq!(key(&mut f, "BPLAYOUT"), "vector");
    assert_eq!(key(&mut f, "BPVERS"), env!("CARGO_PKG_VERSION"));
    assert!(key(&mut f, "BPCFGDIG").starts_with("0x"));

    let hdu = f.hdu("SLOPES").unwrap();
    match &hdu.info {
        fitsio::hdu::HduInfo::ImageInfo { shape, .. } => assert_eq!(shape, &[5, 8]),
        other => panic!("{other:?}"),
    }
    assert_eq!(hdu.read_key::<String>(&mut f, "BUNIT").unwrap(), "pixel");
    let data: Vec<f64> = hdu.read_image(&mut f).unwrap();
    assert_eq!(data[4], slopes[1], "y_0 after the four x");
    let hdu = f.hdu("FLUX").unwrap();
    assert_eq!(hdu.read_key::<String>(&mut f, "BUNIT").unwrap(), "count");
    assert_eq!(hdu.read_image::<Vec<f64>>(&mut f).unwrap(), flux);
    let hdu = f.hdu("VALID").unwrap();
    let v: Vec<u8> = hdu.read_image(&mut f).unwrap();
    assert_eq!(v.iter().map(|&v| f64::from(v)).collect::<Vec<_>>(), valid);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn csv_has_one_row_per_frame_and_subaperture() {
    let dir = scratch("csv");
    let (config, frames, pixels) = case(&dir, 3);
    let (slopes, flux, valid) = expected(&config, &pixels);
    let out = dir.join("s.csv");
    process(&config, &frames, &out, &[]);
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(text.contains("# bprule: subtract-next"), "{text}");
    let rows: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows[0], "frame,subaperture,slope_x,slope_y,flux,valid");
    assert_eq!(rows.len(), 1 + 3 * 4);
    for (k, row) in rows[1..].iter().enumerate() {
        let cells: Vec<f64> = row.split(',').map(|c| c.parse().unwrap()).collect();
        assert_eq!(cells[0], (k / 4) as f64);
        assert_eq!(cells[1], (k % 4) as f64);
        assert_eq!(cells[2..4], slopes[2 * k..2 * k + 2]);
        assert_eq!(cells[4], flux[k]);
        assert_eq!(cells[5], valid[k]);
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn bad_outputs_are_refused_before_any_work() {
    let dir = scratch("bad");
    let (config, frames, _) = case(&dir, 2);
    let c = config.to_str().unwrap();
    let f = frames.to_str().unwrap();
    let (ok, text) = run(&["process", "--config", c, "--frames", f, "--out", "x.txt"]);
    assert!(!ok && text.contains(".csv"), "{text}");
    // --out s.npy writes s.valid.npy: --valid-out may not be that file.
    let s = dir.join("s.npy");
    let v = dir.join("s.valid.npy");
    let (ok, text) = run(&[
        "process",
        "--config",
        c,
        "--frames",
        f,
        "--out",
        s.to_str().unwrap(),
        "--valid-out",
        v.to_str().unwrap(),
    ]);
    assert!(!ok && text.contains("twice"), "{text}");
    // A frames file of the set would be overwritten.
    let (ok, text) = run(&[
        "process",
        "--config",
        c,
        "--frames",
        f,
        "--out",
        dir.join("frames.json")
            .with_extension("npy")
            .to_str()
            .unwrap(),
    ]);
    assert!(!ok && text.contains("input"), "{text}");
    assert!(!s.exists());
    let _ = std::fs::remove_dir_all(dir);
}

/// Frames in a tile-compressed image extension (the primary HDU empty),
/// chosen by `--hdu`, give the same results as the same frames in a .npy.
#[test]
fn a_tile_compressed_extension_is_processed_like_the_npy() {
    use fitsio::images::{ImageDescription, ImageType};
    let dir = scratch("hdu");
    let (config, frames, pixels) = case(&dir, 4);
    let packed = dir.join("packed.fits");
    {
        let name = format!("{}[compress R]", packed.display());
        let mut f = fitsio::FitsFile::create(&name).open().unwrap();
        let description = ImageDescription {
            data_type: ImageType::UnsignedShort,
            dimensions: &[4, 16, 16],
        };
        let hdu = f.create_image("SCI", &description).unwrap();
        hdu.write_image(&mut f, &pixels).unwrap();
    }
    let from_npy = dir.join("a.npy");
    let from_fits = dir.join("b.npy");
    process(&config, &frames, &from_npy, &[]);
    process(&config, &packed, &from_fits, &["--hdu", "SCI"]);
    for suffix in ["npy", "flux.npy", "valid.npy"] {
        let a = read_array(from_npy.with_extension(suffix)).unwrap();
        let b = read_array(from_fits.with_extension(suffix)).unwrap();
        assert_eq!(a, b, "{suffix}");
    }
    let (ok, text) = run(&[
        "process",
        "--config",
        config.to_str().unwrap(),
        "--frames",
        packed.to_str().unwrap(),
        "--hdu",
        "DARK",
        "--out",
        dir.join("c.npy").to_str().unwrap(),
    ]);
    assert!(
        !ok && text.contains("no HDU 'DARK'") && text.contains("'SCI'"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(dir);
}
