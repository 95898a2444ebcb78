//! The AOT writer and reader, and bad AOT input.

use std::path::Path;

use brightpix_protocol::SubapertureWindow;
use fitsio::FitsFile;

use super::super::results::{Provenance, Results};
use super::super::test_util::temp_dir;
use super::super::{read_frames, FrameCube, FrameShape, FrameSource, Raw};
use super::tables::*;
use super::write::{grid_of, image};
use super::{is_aot_name, locate_pixels, stage};

fn window(x: u16, y: u16, side: u16) -> SubapertureWindow {
    SubapertureWindow {
        x,
        y,
        width: side,
        height: side,
    }
}

/// 3 sub-apertures, 2 frames; sub-aperture 1 of frame 1 invalid.
fn sample(windows: Vec<SubapertureWindow>) -> (Results, Provenance) {
    let mut results = Results::new(3);
    for frame in 0..2i32 {
        for s in 0..3i32 {
            results.push(Some(Raw {
                slope_x: (10 * frame + s) * 65536,
                slope_y: -(10 * frame + s) * 32768,
                flux: 16 * i64::from(100 + s),
                valid: !(frame == 1 && s == 1),
            }));
        }
    }
    let mut provenance = Provenance::unknown_config("test", Some(7));
    provenance.rule = Some("subtract-next".into());
    provenance.pixels = Some(20);
    provenance.config_digest = Some(0x1234_abcd);
    provenance.first_frame = 5;
    provenance.windows = windows;
    provenance.reference_slopes = Some(vec![[65536, -32768], [0, 0], [16384, 8]]);
    (results, provenance)
}

fn cube(frames: usize) -> FrameCube {
    let shape = FrameShape {
        frames,
        height: 8,
        width: 12,
    };
    let pixels = (0..frames * 96).map(|i| (i * 37 % 4096) as u16).collect();
    FrameCube { shape, pixels }
}

fn image_f64(file: &mut FitsFile, name: &str) -> (Vec<usize>, Vec<f64>) {
    let hdu = file.hdu(name).unwrap();
    let shape = match &hdu.info {
        fitsio::hdu::HduInfo::ImageInfo { shape, .. } => shape.clone(),
        other => panic!("{other:?}"),
    };
    (shape, hdu.read_image(file).unwrap())
}

fn col_strings(file: &mut FitsFile, table: &str, name: &str) -> Vec<String> {
    strings(file, Path::new("t"), table, name).unwrap()
}

/// Row 1 of a numeric column, scalar or list.
fn col_f64(file: &mut FitsFile, table: &str, name: &str) -> Vec<f64> {
    let path = Path::new("t");
    table_rows(file, path, table).unwrap();
    let number = column_number(file, path, table, name).unwrap();
    let (mut status, mut code, mut repeat, mut width) = (0, 0, 0i64, 0i64);
    let (mut length, mut offset) = (0i64, 0i64);
    unsafe {
        let fptr = file.as_raw();
        fitsio::sys::ffgtclll(
            fptr,
            number,
            &mut code,
            &mut repeat,
            &mut width,
            &mut status,
        );
        if code < 0 {
            fitsio::sys::ffgdesll(fptr, number, 1, &mut length, &mut offset, &mut status);
        } else {
            length = repeat;
        }
        let mut out = vec![0.0; length as usize];
        let mut any_null = 0;
        fitsio::sys::ffgcvd(
            fptr,
            number,
            1,
            1,
            length,
            f64::NAN,
            out.as_mut_ptr(),
            &mut any_null,
            &mut status,
        );
        assert_eq!(status, 0, "{table}.{name}");
        out
    }
}

#[test]
fn writes_the_aot_tables_images_and_provenance() {
    let dir = temp_dir("aotw");
    let path = dir.join("r.aot.fits");
    // A 2x2 grid of 4-pixel windows with one cell empty, out of order.
    let (results, provenance) = sample(vec![window(6, 2, 4), window(2, 2, 4), window(2, 6, 4)]);
    stage(&path, &results, &provenance, Some(&cube(2)))
        .unwrap()
        .commit()
        .unwrap();
    let mut file = FitsFile::open(&path).unwrap();
    let primary = file.primary_hdu().unwrap();
    let key = |file: &mut FitsFile, k: &str| primary.read_key::<String>(file, k).unwrap();
    assert_eq!(key(&mut file, "AOT-VERS"), "2.0.0");
    assert_eq!(key(&mut file, "TIMESYS"), "UTC");
    assert_eq!(key(&mut file, "AO-MODE"), "SCAO");
    assert_eq!(key(&mut file, "BPRULE"), "subtract-next");
    assert_eq!(key(&mut file, "BPCFGDIG"), "0x1234abcd");
    assert_eq!(key(&mut file, "BPLAYOUT"), "vector");
    for table in [
        "AOT_TIME",
        "AOT_ATMOSPHERIC_PARAMETERS",
        "AOT_ABERRATIONS",
        "AOT_TELESCOPES",
        "AOT_SOURCES",
        "AOT_DETECTORS",
        "AOT_SCORING_CAMERAS",
        "AOT_WAVEFRONT_SENSORS",
        "AOT_WAVEFRONT_SENSORS_SHACK_HARTMANN",
        "AOT_WAVEFRONT_CORRECTORS",
        "AOT_LOOPS",
    ] {
        table_rows(&mut file, &path, table).unwrap_or_else(|e| panic!("{table}: {e}"));
    }
    let t = "AOT_WAVEFRONT_SENSORS";
    assert_eq!(col_strings(&mut file, t, "UID"), ["WFS"]);
    assert_eq!(col_strings(&mut file, t, "TYPE"), ["Shack-Hartmann"]);
    assert_eq!(
        col_strings(&mut file, t, "SOURCE_UID"),
        ["ROWREF<GUIDE STAR>"]
    );
    assert_eq!(col_f64(&mut file, t, "DIMENSIONS"), [2.0]);
    assert_eq!(col_f64(&mut file, t, "N_VALID_SUBAPERTURES"), [3.0]);
    assert_eq!(col_f64(&mut file, t, "SUBAPERTURE_SIZE"), [4.0]);
    assert_eq!(
        col_strings(&mut file, t, "MEASUREMENTS"),
        ["INTREF<MEASUREMENTS>"]
    );
    assert!(col_f64(&mut file, "AOT_TELESCOPES", "LATITUDE")[0].is_nan());
    assert_eq!(col_f64(&mut file, t, "MASK_X_OFFSETS"), [2.0]);
    assert_eq!(col_f64(&mut file, t, "MASK_Y_OFFSETS"), [2.0]);
    assert_eq!(col_f64(&mut file, "AOT_TIME", "FRAME_NUMBERS"), [5.0, 6.0]);
    assert!(col_f64(&mut file, "AOT_TIME", "TIMESTAMPS").is_empty());
    assert_eq!(
        col_strings(
            &mut file,
            "AOT_WAVEFRONT_SENSORS_SHACK_HARTMANN",
            "CENTROIDING_ALGORITHM"
        ),
        ["brightest pixels, subtract-next, N = 20"]
    );
    // Measurements: (frames, 2, sub-apertures), x then y.
    let (shape, m) = image_f64(&mut file, "MEASUREMENTS");
    assert_eq!(shape, [2, 2, 3]);
    assert_eq!(&m[..6], &[0.0, 1.0, 2.0, -0.0, -0.5, -1.0]);
    assert_eq!(&m[6..9], &[10.0, 11.0, 12.0]);
    let (shape, r) = image_f64(&mut file, "REF_MEASUREMENTS");
    assert_eq!(
        (shape, r),
        (vec![2, 3], vec![1.0, 0.0, 0.25, -0.5, 0.0, 8.0 / 65536.0])
    );
    let (shape, mask) = image_f64(&mut file, "SUBAPERTURE_MASK");
    assert_eq!((shape, mask), (vec![2, 2], vec![1.0, 0.0, 2.0, -1.0]));
    let (_, flux) = image_f64(&mut file, "SUBAPERTURE_INTENSITIES");
    assert_eq!(flux, results.flux);
    assert_eq!(col_f64(&mut file, "BP_VALID", "VALID"), [1.0, 1.0, 1.0]);
    assert_eq!(table_rows(&mut file, &path, "BP_VALID").unwrap(), 2);
    assert!(table_rows(&mut file, &path, "BP_WINDOWS").is_err());
    let hdu = file.hdu("MEASUREMENTS").unwrap();
    assert_eq!(hdu.read_key::<String>(&mut file, "BUNIT").unwrap(), "pix");
    assert_eq!(
        hdu.read_key::<String>(&mut file, "TIME_UID").unwrap(),
        "ROWREF<FRAMES>"
    );
    // The frames come back as the sensor's pixels.
    assert_eq!(read_frames(&path).unwrap(), cube(2));
    // Its tables (variable-length columns) are named or skipped, never
    // described by the fitsio crate, which would panic.
    let err = FrameSource::open_hdu(&path, Some("AOT_TIME")).unwrap_err();
    assert!(err.to_string().contains("('AOT_TIME') is a table"), "{err}");
    let err = FrameSource::open_hdu(&path, Some("NOPE")).unwrap_err();
    assert!(
        err.to_string().contains("1 'AOT_TIME': table of 1 rows"),
        "{err}"
    );
    assert_eq!(
        FrameSource::open_hdu(&path, Some("PIXEL_INTENSITIES"))
            .unwrap()
            .len(),
        2
    );
    let at = locate_pixels(&path, Some("wfs")).unwrap().unwrap();
    assert_eq!(
        (at.sensor.as_str(), at.hdu.as_deref()),
        ("WFS", Some("PIXEL_INTENSITIES"))
    );
}

#[test]
fn windows_that_are_not_a_grid_are_listed() {
    let dir = temp_dir("aotnogrid");
    let path = dir.join("r.AOT.FITS");
    assert!(is_aot_name(&path));
    let (results, provenance) = sample(vec![window(0, 0, 4), window(5, 0, 4), window(0, 4, 4)]);
    stage(&path, &results, &provenance, None)
        .unwrap()
        .commit()
        .unwrap();
    let mut file = FitsFile::open(&path).unwrap();
    assert!(file.hdu("SUBAPERTURE_MASK").is_err());
    assert_eq!(table_rows(&mut file, &path, "BP_WINDOWS").unwrap(), 3);
    assert_eq!(col_f64(&mut file, "BP_WINDOWS", "X"), [0.0]);
    assert_eq!(col_f64(&mut file, "BP_WINDOWS", "WIDTH"), [4.0]);
    assert!(col_f64(&mut file, "AOT_WAVEFRONT_SENSORS", "SUBAPERTURE_SIZE")[0].is_nan());
    assert!(grid_of(&[window(0, 0, 4), window(0, 0, 4)]).is_none());
    assert!(grid_of(&[window(0, 0, 4), window(4, 0, 3)]).is_none());
}

#[test]
fn bad_shapes_are_refused_before_writing() {
    let dir = temp_dir("aotshape");
    let path = dir.join("r.aot.fits");
    let (results, provenance) = sample(vec![window(0, 0, 4)]);
    let err = stage(&path, &results, &provenance, None).unwrap_err();
    assert!(err.to_string().contains("1 windows"), "{err}");
    let (results, provenance) = sample(Vec::new());
    let err = stage(&path, &results, &provenance, Some(&cube(3))).unwrap_err();
    assert!(err.to_string().contains("3 frames of pixels"), "{err}");
    assert!(!path.exists());
}

/// An AOT file of `sensors` (UID, TYPE, DETECTOR_UID) and `detectors`
/// (UID, PIXEL_INTENSITIES), with one 2x3x4 image named `PIX`.
fn crafted(path: &Path, sensors: &[(&str, &str, &str)], detectors: &[(&str, &str)]) {
    let mut file = FitsFile::create(path).open().unwrap();
    let primary = file.primary_hdu().unwrap();
    primary.write_key(&mut file, "AOT-VERS", "2.0.0").unwrap();
    let rows = |v: Vec<Vec<(&'static str, Cell)>>| v;
    write_table(
        &mut file,
        path,
        &Table {
            name: "AOT_WAVEFRONT_SENSORS",
            columns: SENSOR_COLUMNS,
            rows: rows(
                sensors
                    .iter()
                    .map(|(u, t, d)| {
                        vec![
                            ("UID", text(*u)),
                            ("TYPE", text(*t)),
                            ("DETECTOR_UID", text(*d)),
                        ]
                    })
                    .collect(),
            ),
        },
    )
    .unwrap();
    write_table(
        &mut file,
        path,
        &Table {
            name: "AOT_DETECTORS",
            columns: DETECTOR_COLUMNS,
            rows: detectors
                .iter()
                .map(|(u, p)| vec![("UID", text(*u)), ("PIXEL_INTENSITIES", text(*p))])
                .collect(),
        },
    )
    .unwrap();
    let data: Vec<f32> = (0..24).map(|v| v as f32).collect();
    image(&mut file, path, "PIX", &[2, 3, 4], &data, None, false).unwrap();
}

fn open_error(path: &Path, sensor: Option<&str>) -> String {
    let err = FrameSource::open_sensor(path, None, sensor).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains(&path.display().to_string()), "{msg}");
    msg
}

#[test]
fn reads_the_named_sensor_and_refuses_bad_input() {
    let dir = temp_dir("aotr");
    let path = dir.join("two.fits");
    crafted(
        &path,
        &[
            ("LGS", "Shack-Hartmann", "ROWREF<CAM1>"),
            ("NGS", "Shack-Hartmann", "ROWREF<CAM2>"),
            ("PYR", "Pyramid", "ROWREF<CAM2>"),
            ("DARK", "Shack-Hartmann", ""),
        ],
        &[("CAM1", ""), ("CAM2", "INTREF<PIX>")],
    );
    // Float pixels that are whole counts are frames.
    let mut source = FrameSource::open_sensor(&path, None, Some("NGS")).unwrap();
    assert_eq!(source.shape().frames, 2);
    assert_eq!(source.read_frame(1).unwrap()[..3], [12, 13, 14]);
    let msg = open_error(&path, None);
    assert!(
        msg.contains("4 wavefront sensors") && msg.contains("'LGS' (Shack-Hartmann)"),
        "{msg}"
    );
    let msg = open_error(&path, Some("TTS"));
    assert!(
        msg.contains("no wavefront sensor 'TTS'") && msg.contains("'NGS'"),
        "{msg}"
    );
    let msg = open_error(&path, Some("LGS"));
    assert!(
        msg.contains("'LGS' has detector 'CAM1' without PIXEL_INTENSITIES"),
        "{msg}"
    );
    let msg = open_error(&path, Some("PYR"));
    assert!(msg.contains("of type 'Pyramid'"), "{msg}");
    let msg = open_error(&path, Some("DARK"));
    assert!(msg.contains("has no detector"), "{msg}");

    // A file with no sensor at all.
    let empty = dir.join("empty.fits");
    crafted(&empty, &[], &[]);
    let msg = open_error(&empty, None);
    assert!(msg.contains("no wavefront sensor"), "{msg}");

    // A detector named but absent; an external file, by index.
    let missing = dir.join("missing.fits");
    crafted(&missing, &[("W", "Shack-Hartmann", "ROWREF<GONE>")], &[]);
    assert!(open_error(&missing, None).contains("'GONE', which AOT_DETECTORS does not have"));
    let external = dir.join("external.fits");
    crafted(
        &external,
        &[("W", "Shack-Hartmann", "ROWREF<C>")],
        &[("C", "FILEREF<two.fits>4")],
    );
    let at = locate_pixels(&external, None).unwrap().unwrap();
    assert_eq!(
        (at.file, at.hdu),
        (dir.join("two.fits"), Some("4".to_string()))
    );
    let url = dir.join("url.fits");
    crafted(
        &url,
        &[("W", "Shack-Hartmann", "ROWREF<C>")],
        &[("C", "URLREF<http://x/y.fits>")],
    );
    assert!(open_error(&url, None).contains("a URL or unknown reference"));

    // --sensor for a plain FITS cube, or with --hdu.
    let plain = dir.join("plain.fits");
    cube(1).write(&plain).unwrap();
    let msg = open_error(&plain, Some("WFS"));
    assert!(msg.contains("not AOT"), "{msg}");
    let err = FrameSource::open_sensor(&plain, Some("0"), Some("WFS")).unwrap_err();
    assert!(err.to_string().contains("with --hdu"), "{err}");
    // No AOT tables at all but the version keyword.
    let bare = dir.join("bare.fits");
    let mut file = FitsFile::create(&bare).open().unwrap();
    let primary = file.primary_hdu().unwrap();
    primary.write_key(&mut file, "AOT-VERS", "2.0.0").unwrap();
    drop(file);
    assert!(open_error(&bare, None).contains("no AOT_WAVEFRONT_SENSORS table"));
}
