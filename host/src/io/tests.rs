//! Tests of frame and array reading and writing.

use super::test_util::temp_dir;
use super::*;
use brightpix_protocol::Camera;

fn camera(width: u16, height: u16, bit_depth: u8) -> Camera {
    Camera {
        width,
        height,
        bit_depth,
    }
}

fn ramp_u16(n: usize) -> Vec<u16> {
    (0..n)
        .map(|i| (i as u64 * 2654435761 % 65536) as u16)
        .collect()
}

#[test]
fn format_by_extension() {
    assert_eq!(
        FileFormat::from_path(Path::new("a/b.npy")).unwrap(),
        FileFormat::Npy
    );
    for name in ["x.fits", "x.FITS", "x.fit", "x.fts"] {
        assert_eq!(
            FileFormat::from_path(Path::new(name)).unwrap(),
            FileFormat::Fits
        );
    }
    for name in ["x.txt", "x", "x.fits.gz", "x.npz"] {
        let err = FileFormat::from_path(Path::new(name)).unwrap_err();
        assert!(matches!(err, IoError::UnknownFormat { .. }), "{name}");
        let msg = err.to_string();
        assert!(
            msg.contains(name) && msg.contains(".npy") && msg.contains(".fits"),
            "{msg}"
        );
    }
}

#[test]
fn frames_round_trip_u16_and_u8_both_formats() {
    let dir = temp_dir("frames");
    let shape = FrameShape {
        frames: 3,
        height: 5,
        width: 7,
    };
    let pixels = ramp_u16(3 * 5 * 7);
    let cube = FrameCube {
        shape,
        pixels: pixels.clone(),
    };
    for ext in ["npy", "fits"] {
        let path = dir.join(format!("cube16.{ext}"));
        cube.write(&path).unwrap();
        assert_eq!(read_frames(&path).unwrap(), cube, "{ext}");
        // streaming, out of order, and as an iterator
        let mut source = FrameSource::open(&path).unwrap();
        assert_eq!(source.shape(), shape);
        assert_eq!(source.read_frame(2).unwrap(), cube.frame(2));
        assert_eq!(source.read_frame(0).unwrap(), cube.frame(0));
        let frames: Vec<Vec<u16>> = source.map(|f| f.unwrap()).collect();
        assert_eq!(frames.len(), 3);
        assert_eq!(frames[1], cube.frame(1));

        let bytes: Vec<u8> = pixels.iter().map(|&v| v as u8).collect();
        let path = dir.join(format!("cube8.{ext}"));
        write_array(&path, &[3, 5, 7], &bytes).unwrap();
        let back = read_frames(&path).unwrap();
        assert_eq!(back.shape, shape);
        assert!(back.pixels.iter().zip(&bytes).all(|(&a, &b)| a == b as u16));
    }
}

#[test]
fn single_2d_frame_is_one_frame() {
    let dir = temp_dir("single");
    let data = ramp_u16(4 * 6);
    for ext in ["npy", "fits"] {
        let path = dir.join(format!("one.{ext}"));
        write_array(&path, &[4, 6], &data).unwrap();
        let cube = read_frames(&path).unwrap();
        assert_eq!(
            cube.shape,
            FrameShape {
                frames: 1,
                height: 4,
                width: 6
            }
        );
        assert_eq!(cube.pixels, data);
    }
}

#[test]
fn frames_checked_against_camera() {
    let dir = temp_dir("camera");
    let mut data = vec![100u16; 2 * 3 * 4];
    data[12 + 4 + 2] = 4096; // frame 1, row 1, column 2
    for ext in ["npy", "fits"] {
        let path = dir.join(format!("f.{ext}"));
        write_array(&path, &[2, 3, 4], &data).unwrap();
        // 16-bit camera: fine
        read_frames_for_camera(&path, &camera(4, 3, 16)).unwrap();
        // 12-bit camera: 4096 is out of range
        let err = read_frames_for_camera(&path, &camera(4, 3, 12)).unwrap_err();
        match &err {
            IoError::PixelRange {
                frame: 1,
                row: 1,
                column: 2,
                value: 4096,
                bit_depth: 12,
                ..
            } => {}
            other => panic!("{other:?}"),
        }
        let msg = err.to_string();
        assert!(
            msg.contains("frame 1, row 1, column 2: value 4096"),
            "{msg}"
        );
        assert!(msg.contains("0..=4095"), "{msg}");
        // frame 0 is still readable
        let mut source = FrameSource::open_for_camera(&path, &camera(4, 3, 12)).unwrap();
        source.read_frame(0).unwrap();
        // wrong size
        let err = FrameSource::open_for_camera(&path, &camera(3, 4, 16)).unwrap_err();
        assert!(matches!(err, IoError::Unexpected { .. }), "{err}");
        assert!(err.to_string().contains("4x3"), "{err}");
    }
}

#[test]
fn a_run_of_frames_is_read_at_once_as_frame_by_frame() {
    let dir = temp_dir("runs");
    let pixels = ramp_u16(4 * 3 * 5);
    let bytes: Vec<u8> = pixels.iter().map(|&v| v as u8).collect();
    for ext in ["npy", "fits"] {
        let path16 = dir.join(format!("run16.{ext}"));
        write_array(&path16, &[4, 3, 5], &pixels).unwrap();
        let path8 = dir.join(format!("run8.{ext}"));
        write_array(&path8, &[4, 3, 5], &bytes).unwrap();
        for path in [&path16, &path8] {
            let mut source = FrameSource::open(path).unwrap();
            let mut expected = vec![7u16];
            for index in 1..4 {
                expected.extend(source.read_frame(index).unwrap());
            }
            // Appended after what `out` holds.
            let mut out = vec![7u16];
            source.read_frames_into(1, 3, &mut out).unwrap();
            assert_eq!(out, expected, "{}", path.display());
            let mut none = Vec::new();
            source.read_frames_into(4, 0, &mut none).unwrap();
            assert!(none.is_empty());
            let err = source.read_frames_into(2, 3, &mut out).unwrap_err();
            assert!(err.to_string().contains("frame 4"), "{err}");
            assert_eq!(out, expected, "a failed read leaves `out` as it was");
            // Into a buffer of whole frames, over what it held.
            let mut buffer = vec![9u16; 2 * 15];
            source.read_frames_to(2, &mut buffer).unwrap();
            assert_eq!(buffer, expected[1 + 15..]);
            let err = source.read_frames_to(0, &mut buffer[..7]).unwrap_err();
            assert!(err.to_string().contains("whole frames of 15"), "{err}");
        }
    }
    // The camera check names the frame within the run.
    let mut data = vec![100u16; 3 * 3 * 5];
    data[2 * 15 + 7] = 4096; // frame 2, row 1, column 2
    let path = dir.join("bad.npy");
    write_array(&path, &[3, 3, 5], &data).unwrap();
    let mut source = FrameSource::open_for_camera(&path, &camera(5, 3, 12)).unwrap();
    match source.read_frames_into(0, 3, &mut Vec::new()).unwrap_err() {
        IoError::PixelRange {
            frame: 2,
            row: 1,
            column: 2,
            ..
        } => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn truncated_cube_is_an_error() {
    let dir = temp_dir("trunc");
    for ext in ["npy", "fits"] {
        let path = dir.join(format!("t.{ext}"));
        write_array(&path, &[4, 30, 30], &vec![1u16; 3600]).unwrap();
        let len = std::fs::metadata(&path).unwrap().len();
        let file = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        file.set_len(len - 3000).unwrap();
        let err = FrameSource::open(&path).unwrap_err();
        assert!(err.to_string().contains("truncated"), "{err}");
    }
}

#[test]
fn read_map_rejects_3d() {
    let dir = temp_dir("map3d");
    let path = dir.join("m.npy");
    write_array(&path, &[2, 2, 2], &[0.0f64; 8]).unwrap();
    let err = read_map(&path).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("(2, 2, 2)") && msg.contains("1-D or 2-D"),
        "{msg}"
    );
    assert_eq!(read_array(&path).unwrap().shape, vec![2, 2, 2]);
}

#[test]
fn write_checks_length() {
    let dir = temp_dir("len");
    let err = write_array(dir.join("x.npy"), &[2, 3], &[1.0f64; 5]).unwrap_err();
    assert!(err.to_string().contains("6 values"), "{err}");
}

#[test]
fn missing_file_names_path() {
    let err = read_array("/nonexistent/dir/bg.fits").unwrap_err();
    assert!(matches!(err, IoError::Io { .. }));
    assert!(
        err.to_string().contains("/nonexistent/dir/bg.fits"),
        "{err}"
    );
}

/// Found by the fits_reader fuzz target: a header whose shape claims 2.7 GB
/// of values was allocated before anything was read; the shape is refused.
#[test]
fn a_fits_shape_beyond_any_map_is_refused_before_allocating() {
    let seed = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/seeds/fits_reader/finding-huge-shape-oom");
    let dir = temp_dir("fits-huge-shape");
    let path = dir.join("huge.fits");
    std::fs::copy(&seed, &path).unwrap();
    let e = read_array(&path).unwrap_err();
    assert!(e.to_string().contains("more values than a map"), "{e}");
}
