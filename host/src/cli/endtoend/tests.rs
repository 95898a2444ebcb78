use super::super::{Cli, Command};
use crate::endtoend::{EndToEnd, Scenario};
use crate::evaluation::Method;
use clap::Parser;
use std::path::PathBuf;

fn run(argv: &[&str]) -> anyhow::Result<()> {
    match Cli::try_parse_from(argv).expect("valid arguments").command {
        Command::Endtoend(a) => super::run(a),
        Command::Process(a) => super::super::process::run(a),
        _ => unreachable!(),
    }
}

fn temp(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brightpix-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn reconstructor_slopes_are_bit_identical_to_brightpix_process() {
    let dir = temp("e2e-process");
    let e2e = EndToEnd::new(Scenario::canary(), 3).unwrap();
    let data = e2e.simulate_episode(11, 0, 0);
    let frames = data.frames;
    let n_sub = e2e.lenslets.subapertures.len();
    for (method, n) in [
        (Method::SUBTRACT_NEXT, 20),
        (Method::THRESHOLD, 7),
        (Method::SUBTRACT_NEXT, 256),
    ] {
        let ints = e2e.engine_slopes(&data, method, n).unwrap();
        // What the reconstructor is fed.
        let fed = e2e.slope_matrix(&ints, frames);
        let config = e2e.engine_config(method, n);
        let toml = config.save(&dir, "wfs").unwrap();
        for (w, raw) in data.raw.iter().enumerate() {
            let cube = dir.join(format!("frames-{w}.npy"));
            crate::io::write_array(&cube, &[frames, 112, 112], raw).unwrap();
            let out = dir.join(format!("slopes-{w}.npy"));
            let _ = std::fs::remove_file(&out);
            run(&[
                "brightpix",
                "process",
                "--config",
                toml.to_str().unwrap(),
                "--frames",
                cube.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .unwrap();
            let processed = crate::io::read_array(&out).unwrap();
            assert_eq!(processed.shape, vec![frames, n_sub, 2]);
            for t in 0..frames {
                for k in 0..n_sub {
                    for a in 0..2 {
                        let p = processed.data[(t * n_sub + k) * 2 + a];
                        let f = fed[((w * n_sub + k) * 2 + a, t)];
                        assert_eq!(
                            p.to_bits(),
                            f.to_bits(),
                            "{method:?} N={n} sensor {w} frame {t} window {k}"
                        );
                    }
                }
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_arguments_fail_before_any_work() {
    let dir = temp("e2e-args");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let started = std::time::Instant::now();
    for (extra, expected) in [
        (vec!["--episodes", "1"], "at least 2"),
        (vec!["--rules", "nope"], "unknown rule"),
        (vec!["--pixels", "0"], "at least 1"),
        (vec!["--layers", "0:1:5"], "ALTITUDE"),
        (vec!["--asterism", "40"], "RADIUS,ANGLE"),
        (vec!["--delay=-1"], "delay"),
        (vec!["--episode-frames", "100000"], "shorter episodes"),
        (vec!["--least-squares", "svd:0.1"], "tsvd:R"),
        (vec!["--least-squares", "tsvd:2"], "(0, 1)"),
        (vec!["--model-layers", "0:-1"], "fraction > 0"),
        (vec!["--model-layers", "500"], "ALTITUDE:FRACTION"),
    ] {
        let mut argv = vec!["brightpix", "endtoend", "--out", o];
        argv.extend(extra.iter().copied());
        let e = run(&argv).unwrap_err();
        assert!(format!("{e:#}").contains(expected), "{extra:?}: {e:#}");
    }
    let file = dir.join("file");
    std::fs::write(&file, "x").unwrap();
    let e = run(&["brightpix", "endtoend", "--out", file.to_str().unwrap()]).unwrap_err();
    assert!(e.to_string().contains("not a directory"), "{e}");
    // Nothing was simulated and nothing written.
    assert!(!out.exists() || std::fs::read_dir(&out).unwrap().next().is_none());
    assert!(started.elapsed().as_secs() < 20);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_users_conditions_run_end_to_end_and_reproduce_from_the_seed() {
    let dir = temp("e2e-user");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let args = |name: &'static str, seed: &'static str| {
        vec![
            "brightpix",
            "endtoend",
            "--out",
            o,
            "--name",
            name,
            "--asterism",
            "30,0;30,120;30,240",
            "--layers",
            "0:0.7:5:0,8000:0.3:20:90",
            "--photons",
            "500",
            "--read-noise",
            "1",
            "--rules",
            "subtract-next",
            "--pixels",
            "10,20",
            "--episodes",
            "2",
            "--episode-frames",
            "2",
            "--seed",
            seed,
        ]
    };
    run(&args("a", "7")).unwrap();
    run(&args("b", "7")).unwrap();
    run(&args("c", "8")).unwrap();
    let csv = |name: &str| std::fs::read_to_string(out.join(format!("{name}.csv"))).unwrap();
    // One row per N (10, 20, all pixels) and reconstructor.
    assert_eq!(csv("a").lines().count(), 1 + 3 * 2, "{}", csv("a"));
    assert_eq!(csv("a"), csv("b"), "the same seed reproduces the run");
    assert_ne!(csv("a"), csv("c"));
    let summary = std::fs::read_to_string(out.join("a.md")).unwrap();
    assert!(summary.contains("(30, 0) (30, 120) (30, 240)"), "{summary}");
    assert!(summary.contains("(8000, 0.3, 20, 90)"), "{summary}");
    for suffix in ["", "-strehl", "-budget"] {
        for ext in ["svg", "png"] {
            assert!(out.join(format!("a{suffix}.{ext}")).is_file());
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_variants_run_and_say_what_they_assumed() {
    let dir = temp("e2e-variants");
    let out = dir.join("out");
    run(&[
        "brightpix",
        "endtoend",
        "--out",
        out.to_str().unwrap(),
        "--name",
        "v",
        "--least-squares",
        "tikhonov:0.05",
        "--model-layers",
        "0:5,1000:3,7000:2",
        "--emccd",
        "--noise-weights",
        "--pixels-by-light",
        "--rules",
        "subtract-next",
        "--pixels",
        "20",
        "--episodes",
        "2",
        "--episode-frames",
        "2",
    ])
    .unwrap();
    let csv = std::fs::read_to_string(out.join("v.csv")).unwrap();
    // N = 20 and all pixels, each with the matched MMSE and the
    // least-squares reconstructor.
    assert_eq!(csv.matches(",matched,").count(), 2, "{csv}");
    assert_eq!(csv.matches(",ls-tikhonov:0.05,").count(), 2, "{csv}");
    let summary = std::fs::read_to_string(out.join("v.md")).unwrap();
    for said in [
        "(1000, 0.300)",
        "each sub-aperture weighted by its own measured noise",
        "N x its lit fraction",
        "EMCCD at high gain",
        "Tikhonov alpha = (0.05",
        "singular modes of G",
    ] {
        assert!(summary.contains(said), "{said}: {summary}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
