//! The file targets: configuration files and the .npy and FITS readers,
//! through real files (the readers take paths) in a private directory.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use brightpix::config_file::ProcessingConfig;
use brightpix::engine_runner::HostEngine;
use brightpix::io::{self, FrameSource};

/// This process's directory: the input file, and the side files a fuzzed
/// configuration may name (`bg.npy`, `flat.fits`, `w.npy`, `windows.npy`,
/// `pixels.npy`, `refs.npy`, all for an 8x8 camera with 3 windows).
fn dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = if Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        let dir = base.join(format!("brightpix-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a private directory");
        let map: Vec<f64> = (0..64).map(|i| (i % 7) as f64 * 0.5).collect();
        io::write_array(dir.join("bg.npy"), &[8, 8], &map).unwrap();
        io::write_array(dir.join("flat.fits"), &[8, 8], &vec![1.0f64; 64]).unwrap();
        io::write_array(dir.join("w.npy"), &[1, 8, 8], &vec![0.5f32; 64]).unwrap();
        io::write_array(
            dir.join("windows.npy"),
            &[3, 4],
            &[0i32, 0, 4, 4, 4, 0, 4, 4, 0, 4, 8, 4],
        )
        .unwrap();
        io::write_array(dir.join("pixels.npy"), &[3], &[1u16, 4, 16]).unwrap();
        io::write_array(
            dir.join("refs.npy"),
            &[3, 2],
            &[0.5f64, -0.5, 0.0, 1.0, 63.9, -64.0],
        )
        .unwrap();
        dir
    })
}

/// A configuration file.
pub fn toml_loader(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(config) = ProcessingConfig::from_toml_str(text, &dir().join("c.toml")) {
        config.validate().expect("a loaded configuration is valid");
        HostEngine::new(config.view()).expect("the engine takes a loaded configuration");
    }
}

fn read_as(data: &[u8], name: &str) {
    let path = dir().join(name);
    std::fs::write(&path, data).expect("writing the input");
    let _ = io::read_array(&path);
    let _ = io::read_map(&path);
    if let Ok(mut frames) = FrameSource::open(&path) {
        let n = frames.len();
        let mut frame = Vec::new();
        for index in [0, n / 2, n.saturating_sub(1), n] {
            let _ = frames.read_frame_into(index, &mut frame);
        }
    }
}

/// A `.npy` file.
pub fn npy_reader(data: &[u8]) {
    read_as(data, "in.npy");
}

/// A FITS file.
pub fn fits_reader(data: &[u8]) {
    read_as(data, "in.fits");
}
