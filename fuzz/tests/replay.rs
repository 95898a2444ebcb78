//! The fuzz targets on stable Rust, in CI: every file of the seed corpus
//! (`fuzz/seeds/<target>/`, built from the project's tests and examples)
//! and a few thousand mutations of them go through each target, so a
//! regression that the fuzzer would find in its first seconds fails
//! `cargo test`. The long runs are `cargo fuzz run <target>` (fuzz/README.md).
//!
//! `BRIGHTPIX_BLESS=1 cargo test -p brightpix-fuzz-harness` rewrites the
//! seed corpus (after the test inputs it is built from change).

use std::path::{Path, PathBuf};

use brightpix_fuzz_harness as harness;

type Target = fn(&[u8]);

const TARGETS: [(&str, Target, usize); 5] = [
    ("wire_decoder", harness::wire_decoder, 20_000),
    ("device_loop", harness::device_loop, 2_000),
    ("toml_loader", harness::toml_loader, 3_000),
    ("npy_reader", harness::npy_reader, 3_000),
    ("fits_reader", harness::fits_reader, 3_000),
];

fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("seeds")
        .join(target)
}

/// xorshift64*: deterministic mutations.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// A libFuzzer-like mutation: flip bits, change bytes to interesting
/// values, insert, delete, duplicate or splice.
fn mutate(rng: &mut Rng, seed: &[u8], other: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = v.len();
        match rng.below(7) {
            0 if len > 0 => {
                let at = rng.below(len);
                v[at] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let at = rng.below(len);
                v[at] = [0, 1, 0x7f, 0x80, 0xff, b'"', b'=', b'[', b'\n'][rng.below(9)];
            }
            2 => {
                let at = rng.below(len + 1);
                v.insert(at, rng.next() as u8);
            }
            3 if len > 0 => {
                let at = rng.below(len);
                let n = rng.below(len - at + 1).min(64);
                v.drain(at..at + n);
            }
            4 if len > 1 => {
                let at = rng.below(len);
                let n = rng.below(len - at).min(64);
                let piece = v[at..at + n].to_vec();
                let to = rng.below(v.len() + 1);
                v.splice(to..to, piece);
            }
            5 if !other.is_empty() => {
                let at = rng.below(other.len());
                let n = rng.below(other.len() - at + 1).min(256);
                let to = rng.below(v.len() + 1);
                v.splice(to..to, other[at..at + n].iter().copied());
            }
            _ => v.truncate(rng.below(len + 1)),
        }
    }
    v
}

/// The minimised corpus of the long libFuzzer runs (`fuzz/corpus/<target>/`,
/// `cargo fuzz cmin`), replayed beside the seeds: every input that reached
/// new coverage there.
fn fuzzed_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target)
}

fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e} (BRIGHTPIX_BLESS=1 writes it)", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap();
            (p, bytes)
        })
        .collect()
}

fn seeds(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = files(&corpus_dir(target));
    let fuzzed = fuzzed_dir(target);
    if fuzzed.is_dir() {
        out.extend(files(&fuzzed));
    }
    out.sort();
    out
}

fn replay(target: &str, run: Target, mutations: usize) {
    let seeds = seeds(target);
    assert!(!seeds.is_empty(), "no seeds for {target}");
    for (path, bytes) in &seeds {
        run(bytes);
        let _ = path;
    }
    let mut rng = Rng(0x5EED ^ target.len() as u64);
    for _ in 0..mutations {
        let a = &seeds[rng.below(seeds.len())].1;
        let b = &seeds[rng.below(seeds.len())].1;
        run(&mutate(&mut rng, a, b));
    }
    eprintln!(
        "{target}: {} seeds and {mutations} mutations, no finding",
        seeds.len()
    );
}

#[test]
fn wire_decoder() {
    replay(TARGETS[0].0, TARGETS[0].1, TARGETS[0].2);
}

#[test]
fn device_loop() {
    replay(TARGETS[1].0, TARGETS[1].1, TARGETS[1].2);
}

#[test]
fn toml_loader() {
    replay(TARGETS[2].0, TARGETS[2].1, TARGETS[2].2);
}

#[test]
fn npy_reader() {
    replay(TARGETS[3].0, TARGETS[3].1, TARGETS[3].2);
}

#[test]
fn fits_reader() {
    replay(TARGETS[4].0, TARGETS[4].1, TARGETS[4].2);
}

// --- the seed corpus ------------------------------------------------------------

mod seed {
    use super::*;
    use brightpix::io::write_array;
    use brightpix::link::{encode_pixel_rows, pixel_rows_frames};

    fn write(target: &str, name: &str, bytes: &[u8]) {
        let dir = corpus_dir(target);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(name), bytes).unwrap();
    }

    fn hex(text: &str) -> Vec<u8> {
        text.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    /// The device-loop input format (`harness::device`): configuration
    /// bytes in the order `draw_config` reads them, then steps.
    struct Steps(Vec<u8>);
    impl Steps {
        #[allow(clippy::too_many_arguments)]
        fn config(
            w: u8,
            h: u8,
            depth: u8,
            windows: &[[u8; 4]],
            rule: u8,
            flags: u8,
            n: u8,
        ) -> Self {
            let mut v = vec![w - 1, 0, h - 1, 0, depth - 1, windows.len() as u8 - 1, 0];
            for &[x, y, ww, hh] in windows {
                v.extend([ww, 0, hh, 0, x, 0, y, 0]);
            }
            v.push(rule);
            if rule % 4 == 3 {
                v.extend([3, 0]);
            }
            v.push(flags);
            let per = if flags & 1 != 0 { windows.len() } else { 1 };
            for _ in 0..per {
                v.extend([n, 0]);
            }
            if flags & 2 != 0 {
                v.extend([4, 0]); // gain shift 4
            }
            let pixels = w as usize * h as usize;
            if flags & 4 != 0 {
                v.extend((0..pixels).flat_map(|i| [(i % 5) as u8, 0])); // background
            }
            if flags & 8 != 0 {
                v.extend((0..pixels).flat_map(|i| [(i % 3) as u8, 0x10])); // gain ~1
            }
            if flags & 16 != 0 {
                v.extend([0, 0x10, 0, 0]); // threshold 4 counts
            }
            if flags & 32 != 0 {
                for k in 0..windows.len() {
                    v.extend([0, (k as u8) << 4, 0, 0, 0, 0x80, 0, 0]); // reference slopes
                }
            }
            if flags & 64 != 0 {
                v.extend([0, 1, 0, 0]); // min flux 16/16
            }
            v.extend([50, 0]); // max_read
            Steps(v)
        }
        fn op(mut self, bytes: &[u8]) -> Self {
            self.0.extend_from_slice(bytes);
            self
        }
    }

    #[test]
    fn write_seed_corpus() {
        if std::env::var_os("BRIGHTPIX_BLESS").is_none() {
            return;
        }
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        // wire: every frame of the protocol's test vectors, a whole frame
        // of pixels, and a stream of several.
        let vectors: String =
            std::fs::read_to_string(root.join("shared/protocol-vectors.json")).unwrap();
        let frames: Vec<Vec<u8>> = vectors
            .lines()
            .filter_map(|l| l.trim().strip_prefix("\"frame\": \""))
            .map(|l| hex(l.trim_end_matches(['"', ','])))
            .collect();
        assert!(frames.len() > 50);
        for (k, f) in frames.iter().enumerate() {
            write("wire_decoder", &format!("vector-{k:03}"), f);
        }
        write("wire_decoder", "stream", &frames.concat());
        let pixels: Vec<u16> = (0..300).map(|i| (i * 37 % 4096) as u16).collect();
        write("wire_decoder", "pixel-rows", &encode_pixel_rows(5, &pixels));
        write(
            "wire_decoder",
            "pixel-rows-one",
            &pixel_rows_frames(5, &pixels)[0],
        );

        // device loop: sessions with uploads and frames, each rule and option.
        let windows = [[0, 0, 6, 5], [6, 0, 6, 5], [0, 5, 12, 5]];
        let mut k = 0;
        for rule in 0..4u8 {
            for flags in [0u8, 1, 2, 4 | 8, 16 | 32 | 64, 127] {
                let steps = Steps::config(12, 10, 12, &windows, rule, flags, 4)
                    .op(&[1, 1, 0, 0, 0]) // Hello, session 1
                    .op(&[2, 9, 0, 0xff, 7, 0, 0, 0]) // upload (chunks of 80 bytes), id 7
                    .op(&[4, 1, 0, 0, 0, 5, 0, 0, 0, 1, 100, 0]) // frame 1
                    .op(&[5, 0]) // StatusRequest
                    .op(&[4, 2, 0, 0, 0, 6, 0, 0, 0, 0, 2, 0, 7, 0]) // frame 2, a bad pixel
                    .op(&[3, 3, 0, 0, 0, 9, 0, 0, 0, 4, 1, 0, 2, 0, 3, 0, 4, 0]); // a gap
                write("device_loop", &format!("session-{k:02}"), &steps.0);
                k += 1;
            }
        }
        // A client that uploads half, sends garbage and a partial frame; a
        // Hello of another version; a new session.
        let cut = Steps::config(8, 8, 16, &[[0, 0, 8, 8]], 1, 0, 5)
            .op(&[1, 9, 0, 0, 0]) // Hello, session 9
            .op(&[2, 0, 0, 1, 2, 0, 0, 0]) // ConfigBegin only
            .op(&[0, 3, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]) // 12 raw bytes
            .op(&[3, 1, 0, 0, 0, 0, 0, 0, 0, 3, 1, 0, 2, 0, 3, 0]) // 3 pixels of frame 1
            .op(&[7]) // 0x00
            .op(&[1, 5, 0, 0, 0, 3, 0, 1, 2, 3, 4]) // Hello of protocol 3
            .op(&[8]) // the link closes and reopens
            .op(&[1, 6, 0, 0, 0]) // Hello, session 6
            .op(&[2, 1, 0, 0xff, 3, 0, 0, 0]) // the whole upload
            .op(&[4, 1, 0, 0, 0, 7, 0, 0, 0, 5, 9, 0]); // a frame
        write("device_loop", "takeover", &cut.0);

        // TOML: the examples, and every key of the guide.
        for entry in std::fs::read_dir(root.join("examples")).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|e| e == "toml") {
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                write("toml_loader", &name, &std::fs::read(&p).unwrap());
            }
        }
        let base = "[camera]\nwidth = 8\nheight = 8\nbit_depth = 12\n";
        let tomls = [
            format!("{base}[subapertures.grid]\nx = 0\ny = 0\ncolumns = 2\nrows = 2\nwidth = 4\nheight = 4\npitch_x = 4\nskip = [[1, 1]]\n[calibration]\nbackground = \"bg.npy\"\nflat = \"flat.fits\"\npixel_weight = \"w.npy\"\nthreshold_counts = 2.5\n[selection]\nrule = \"subtract-mean\"\nmean_count = 2\npixels = [1, 2, 3]\n[selection.level_filter]\ngain_shift = 4\n"),
            format!("{base}[subapertures]\nfile = \"windows.npy\"\n[selection]\nrule = \"threshold\"\npixels_file = \"pixels.npy\"\n[centroid]\nreference_slopes = \"refs.npy\"\nmin_flux_counts = 10\n"),
            format!("{base}[[subapertures.window]]\nx = 1\ny = 1\nwidth = 5\nheight = 6\n[calibration]\nbackground_counts = -3.5\n[selection]\nrule = \"subtract-next-distinct\"\npixels = 7\n"),
        ];
        for (k, t) in tomls.iter().enumerate() {
            write("toml_loader", &format!("keys-{k}.toml"), t.as_bytes());
        }

        // npy and FITS: every element type the writers produce, cubes of
        // frames and maps.
        let tmp = std::env::temp_dir().join(format!("brightpix-seed-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).unwrap();
        for ext in ["npy", "fits"] {
            let target = if ext == "npy" {
                "npy_reader"
            } else {
                "fits_reader"
            };
            let p = |name: &str| tmp.join(format!("{name}.{ext}"));
            write_array(
                p("u16-cube"),
                &[2, 3, 4],
                &(0..24).map(|i| i as u16 * 2500).collect::<Vec<_>>(),
            )
            .unwrap();
            write_array(
                p("u8-frame"),
                &[3, 5],
                &(0..15).map(|i| i as u8).collect::<Vec<_>>(),
            )
            .unwrap();
            write_array(p("i16-map"), &[2, 2], &[-1i16, 2, -3, 4]).unwrap();
            write_array(p("i32-map"), &[4], &[-1i32, 2, 70000, 4]).unwrap();
            write_array(p("f32-map"), &[2, 2], &[0.5f32, 1.5, -2.0, 1e30]).unwrap();
            write_array(p("f64-slopes"), &[1, 2, 2], &[0.5f64, f64::NAN, -1.0, 2.0]).unwrap();
            for name in [
                "u16-cube",
                "u8-frame",
                "i16-map",
                "i32-map",
                "f32-map",
                "f64-slopes",
            ] {
                write(target, name, &std::fs::read(p(name)).unwrap());
            }
        }
        let _ = std::fs::remove_dir_all(tmp);
    }
}
