use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::simulator::camera::{CameraSimulator, CameraWindow};
use crate::simulator::{SimulationParams, Simulator};
use clap::Parser;
use std::path::{Path, PathBuf};

/// A whole command line, as `main` runs it (the options given are known).
fn run(argv: &[&str]) -> anyhow::Result<()> {
    super::super::run_from(argv)
}

fn temp(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brightpix-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const EXAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/canary.toml");

/// The `[tuned]` table of a written configuration.
fn tuned_table(path: &Path) -> toml::Table {
    let text = std::fs::read_to_string(path).unwrap();
    let t: toml::Table = toml::from_str(&text).unwrap();
    t["tuned"].as_table().unwrap().clone()
}

/// Two frames of the whole 112x112 camera of `config`: its windows
/// simulated at the defaults, written as .npy.
fn canary_cube(config: &ProcessingConfig, dir: &Path) -> PathBuf {
    let sim = Simulator::new(SimulationParams::canary()).unwrap();
    let mut data = vec![50u16; 2 * 112 * 112];
    let spots = sim.frames(5, 0, 2 * config.windows.len());
    for f in 0..2 {
        for (s, w) in config.windows.iter().enumerate() {
            let spot = &spots[f * config.windows.len() + s];
            for y in 0..16 {
                for x in 0..16 {
                    data[f * 112 * 112 + (w.y as usize + y) * 112 + w.x as usize + x] =
                        spot.raw[y * 16 + x];
                }
            }
        }
    }
    let frames = dir.join("frames.npy");
    crate::io::write_array(&frames, &[2, 112, 112], &data).unwrap();
    frames
}

#[test]
fn arguments_are_checked_before_any_work() {
    let dir = temp("tune-args");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let started = std::time::Instant::now();
    for (extra, expected) in [
        (vec!["--count", "0"], "at least 20"),
        (vec!["--classes", "0"], "at least one distance class"),
        (vec!["--angle-classes", "0"], "at least one azimuth class"),
        (vec!["--score", "sideways"], "one of along, pooled"),
        (vec!["--spot-model", "x"], "effective-wavelength"),
        (
            vec!["--illumination-threshold", "0"],
            "illumination threshold",
        ),
        (vec!["--frames", "0"], "--frames 0"),
    ] {
        let mut argv = vec!["brightpix", "tune", "--config", EXAMPLE, "--out", o];
        argv.extend(extra.iter().copied());
        let e = run(&argv).unwrap_err();
        assert!(format!("{e:#}").contains(expected), "{extra:?}: {e:#}");
    }
    // --out is an existing file: refused at once, the file untouched.
    let file = dir.join("taken");
    std::fs::write(&file, "keep").unwrap();
    let e = run(&[
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--out",
        file.to_str().unwrap(),
    ])
    .unwrap_err();
    assert!(e.to_string().contains("not a directory"), "{e}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep");
    assert!(!out.join("tuned.toml").exists());
    assert!(started.elapsed().as_secs() < 10, "{:?}", started.elapsed());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `tune` with a Rayleigh LGS on the CANARY example: the windows outside
/// the 4.2 m pupil are left out, partly lit ones are their own class, the
/// assumptions are in the TOML (which loads), and `process` runs it.
#[test]
fn tune_writes_a_configuration_that_process_accepts() {
    let dir = temp("tune");
    let out = dir.to_str().unwrap();
    run(&[
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--out",
        out,
        "--name",
        "lgs",
        "--lgs",
        "rayleigh:1500",
        "--launch",
        "0,0",
        "--classes",
        "2",
        "--count",
        "40",
    ])
    .unwrap();
    let tuned = ProcessingConfig::load(dir.join("lgs.toml")).unwrap();
    let original = ProcessingConfig::load(EXAMPLE).unwrap();
    // The 4 corner windows are outside the 4.2 m pupil and 8 more are lit
    // below half their area.
    assert_eq!(tuned.windows.len(), 37);
    assert!(tuned.windows.iter().all(|w| original.windows.contains(w)));
    assert_eq!(tuned.background, original.background);
    for f in ["lgs-tune.csv", "lgs-tune.svg", "lgs-tune.png"] {
        assert!(dir.join(f).exists(), "{f}");
    }
    if let PixelCounts::PerSubaperture(list) = &tuned.pixels {
        assert_eq!(list.len(), 37);
    }
    let t = tuned_table(&dir.join("lgs.toml"));
    assert_eq!(t["score"].as_str(), Some("along the elongation"));
    assert_eq!(t["r0_m"].as_float(), Some(0.125));
    assert_eq!(t["dark_windows"].as_array().unwrap().len(), 12);
    let text = std::fs::read_to_string(dir.join("lgs.toml")).unwrap();
    assert!(text.contains("# ---- brightpix tune"));
    assert!(text.contains("read noise 2.000 e-"));

    let frames = canary_cube(&tuned, &dir);
    let slopes = dir.join("slopes.npy");
    run(&[
        "brightpix",
        "process",
        "--config",
        dir.join("lgs.toml").to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        slopes.to_str().unwrap(),
    ])
    .unwrap();
    let out = crate::io::read_array(&slopes).unwrap();
    assert_eq!(out.shape, vec![2, 37, 2]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The paper's sodium conditions: scored along the elongation; at the
/// default 0.22"/pixel the spots do not fit and tune fails after writing.
#[test]
fn sodium_is_scored_along_the_elongation_and_truncation_fails() {
    let dir = temp("tune-na");
    let out = dir.to_str().unwrap();
    let common = [
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--out",
        out,
        "--photons",
        "1000",
        "--launch",
        "21,0",
        "--lgs",
        "sodium:8000",
        "--classes",
        "1",
        "--angle-classes",
        "1",
        "--count",
        "20",
    ];
    let mut argv = common.to_vec();
    argv.extend(["--pixel-scale", "1.5", "--name", "fits"]);
    run(&argv).unwrap();
    let t = tuned_table(&dir.join("fits.toml"));
    assert_eq!(t["score"].as_str(), Some("along the elongation"));
    assert_eq!(t["truncated"].as_bool(), Some(false));
    let mut argv = common.to_vec();
    argv.extend(["--name", "small"]);
    let e = run(&argv).unwrap_err();
    assert!(e.to_string().contains("truncated"), "{e}");
    let t = tuned_table(&dir.join("small.toml"));
    assert_eq!(t["truncated"].as_bool(), Some(true));
    argv.push("--allow-truncation");
    run(&argv).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A recorded cube (simulated: corners dark, partly lit edges, 2.5 e- read
/// noise, 300 photons): tune measures what was put in, and the tuned
/// per-sub-aperture configuration is accepted by `process` and by a
/// simulated device, which streams it bit-exact.
#[test]
fn tune_from_recorded_frames_measures_the_conditions() {
    let dir = temp("tune-rec");
    let original = ProcessingConfig::load(EXAMPLE).unwrap();
    let placements = crate::evaluation::tune::pupil_positions(&original, 0.6);
    let windows = original
        .windows
        .iter()
        .zip(&placements)
        .map(|(w, &c)| {
            let lit = crate::evaluation::tune::lit_fraction(c, 0.6, 4.2, 0.0);
            CameraWindow {
                x: w.x as usize,
                y: w.y as usize,
                params: SimulationParams {
                    photons: 300.0 * lit.max(0.001),
                    read_noise_e: 2.5,
                    ..SimulationParams::canary()
                },
            }
        })
        .collect();
    let cam = CameraSimulator::new(112, 112, windows).unwrap();
    let frames = cam.frames(9, 0, 200);
    let raw: Vec<u16> = frames.iter().flat_map(|f| f.raw.iter().copied()).collect();
    let cube = dir.join("recorded.npy");
    crate::io::write_array(&cube, &[200, 112, 112], &raw).unwrap();
    let out = dir.to_str().unwrap();
    run(&[
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--out",
        out,
        "--frames",
        cube.to_str().unwrap(),
        "--count",
        "40",
    ])
    .unwrap();
    let path = dir.join("tuned.toml");
    let t = tuned_table(&path);
    let read_noise = t["read_noise_e"].as_float().unwrap();
    assert!((read_noise - 2.5).abs() < 0.15, "{read_noise}");
    let photons = t["photons_fully_lit"].as_float().unwrap();
    assert!((photons - 300.0).abs() < 15.0, "{photons}");
    assert!(t["background_error_counts"].as_float().unwrap().abs() < 0.3);
    assert_eq!(t["measured_from_frames"].as_bool(), Some(true));
    let r0 = t["r0_m"].as_float().unwrap();
    // 0.125 simulated (0.0995 fitted while the spot size counted whole pixels).
    assert!((0.11..0.14).contains(&r0), "{r0}");
    let tuned = ProcessingConfig::load(&path).unwrap();
    assert_eq!(tuned.windows.len(), 37);
    assert_eq!(t["dark_windows"].as_array().unwrap().len(), 12);

    // process accepts it.
    let slopes = dir.join("slopes.npy");
    run(&[
        "brightpix",
        "process",
        "--config",
        path.to_str().unwrap(),
        "--frames",
        cube.to_str().unwrap(),
        "--out",
        slopes.to_str().unwrap(),
    ])
    .unwrap();
    assert_eq!(
        crate::io::read_array(&slopes).unwrap().shape,
        vec![200, 37, 2]
    );

    // And a simulated device, verified against the reference bit for bit.
    let view = tuned.view();
    let device = crate::sim_device::InProcessDevice::start_pty().unwrap();
    let mut client = crate::link::Client::open(device.port()).unwrap();
    client.configure(&view).unwrap();
    let recorded: Vec<Vec<u16>> = frames.iter().take(3).map(|f| f.raw.clone()).collect();
    let run = crate::sil::stream_and_verify(&mut client, &view, &recorded, 0, 3);
    assert!(run.error.is_none(), "{:?}", run.error);
    assert!(run.verifier.all_match(), "{:#?}", run.verifier.mismatches);
    assert_eq!(run.verifier.frames_verified, 3);
    drop(client);
    device.stop();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn criterion_wfe_writes_the_n_of_least_residual_wavefront_error() {
    let dir = temp("tune-wfe");
    let out = dir.join("out");
    let argv = [
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--criterion",
        "wfe",
        "--episodes",
        "2",
        "--episode-frames",
        "3",
        "--out",
        out.to_str().unwrap(),
    ];
    run(&argv).unwrap();
    let tuned = tuned_table(&out.join("tuned.toml"));
    assert_eq!(tuned["criterion"].as_str(), Some("wfe"));
    // The N written is the CSV's least residual (matched reconstructor).
    let csv = std::fs::read_to_string(out.join("tuned-endtoend.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let best = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|f| f[col("reconstructor")] == "matched")
        .min_by(|a, b| {
            let v = |f: &Vec<&str>| f[col("wfe_nm")].parse::<f64>().unwrap();
            v(a).total_cmp(&v(b))
        })
        .unwrap();
    assert_eq!(
        tuned["N"].as_integer(),
        Some(best[col("N")].parse::<i64>().unwrap()),
        "{best:?}"
    );
    let config = ProcessingConfig::load(out.join("tuned.toml")).unwrap();
    // The dark windows of the 7x7 grid (corners, obscuration) are left out.
    let dark = tuned["dark_windows"].as_array().unwrap().len();
    assert!(dark >= 4, "{dark}");
    assert_eq!(config.windows.len(), 49 - dark);
    // An LGS is refused: the simulation models natural guide stars.
    let e = run(&[
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--criterion",
        "wfe",
        "--lgs",
        "sodium:8000",
        "--out",
        out.to_str().unwrap(),
    ])
    .unwrap_err();
    assert!(e.to_string().contains("natural guide stars"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An option of the other criterion is refused before any work (it would
/// be ignored), naming the flag; its default is not "given". The wfe TOML
/// says what was scored, not R's classes.
#[test]
fn an_option_of_the_other_criterion_is_refused() {
    let dir = temp("tune-other-criterion");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let refused = |extra: &[&str], wanted: &[&str]| {
        let mut argv = vec!["brightpix", "tune", "--config", EXAMPLE, "--out", o];
        argv.extend_from_slice(extra);
        let e = format!("{:#}", run(&argv).unwrap_err());
        for w in wanted {
            assert!(e.contains(w), "{extra:?}: {e}");
        }
        assert!(!out.exists(), "{extra:?}: wrote {}", out.display());
    };
    let wfe = ["--criterion", "wfe"];
    refused(
        &[&wfe[..], &["--count", "100"]].concat(),
        &["--count", "criterion wfe has no use for frames"],
    );
    refused(
        &[&wfe[..], &["--score", "pooled"]].concat(),
        &["--score", "criterion wfe"],
    );
    refused(&[&wfe[..], &["--classes", "3"]].concat(), &["--classes"]);
    refused(&[&wfe[..], &["--keep-dark"]].concat(), &["--keep-dark"]);
    refused(
        &[&wfe[..], &["--allow-truncation"]].concat(),
        &["--allow-truncation", "truncation"],
    );
    refused(&[&wfe[..], &["--launch", "1,0"]].concat(), &["--launch"]);
    refused(&["--episodes", "3"], &["--episodes", "criterion wfe only"]);
    refused(
        &["--criterion", "r", "--layers", "0:1:10:0"],
        &["--layers", "criterion wfe only"],
    );
    // Defaults are not given: criterion wfe with its own options runs.
    run(&[
        "brightpix",
        "tune",
        "--config",
        EXAMPLE,
        "--out",
        o,
        "--criterion",
        "wfe",
        "--episodes",
        "2",
        "--episode-frames",
        "2",
        "--seed",
        "3",
    ])
    .unwrap();
    let text = std::fs::read_to_string(out.join("tuned.toml")).unwrap();
    assert!(
        text.contains("# scoring: on-axis residual wavefront error"),
        "{text}"
    );
    assert!(
        !text.contains("frames per class") && !text.contains("representative"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn end_to_end_options_are_the_librarys_conditions() {
    let conditions = |extra: &[&str]| {
        let mut argv = vec!["brightpix", "tune", "--config", EXAMPLE, "--out", "unused"];
        argv.extend(extra);
        match super::super::Cli::try_parse_from(argv)
            .expect("valid arguments")
            .command
        {
            super::super::Command::Tune(a) => a.endtoend.conditions().unwrap(),
            _ => unreachable!(),
        }
    };
    // The command line's defaults are the library's (and so the Python keywords').
    assert_eq!(conditions(&[]), crate::endtoend::Conditions::default());
    let c = conditions(&[
        "--asterism",
        "30,0;30,120",
        "--science",
        "10,45",
        "--layers",
        "0:3:5:10,1000:1:10:90",
        "--wind-scale",
        "2",
        "--frame-rate",
        "500",
        "--delay",
        "1",
        "--science-wavelength",
        "2.2e-6",
        "--dm-actuators",
        "9",
        "--dm-coupling",
        "0.3",
        "--fixed-noise",
        "0.1",
        "--episodes",
        "3",
        "--episode-frames",
        "7",
        "--calibration-episodes",
        "2",
    ]);
    let stars: Vec<[f64; 2]> = c
        .guide_stars
        .as_ref()
        .unwrap()
        .iter()
        .map(|g| [g.radius_arcsec, g.angle_deg])
        .collect();
    assert_eq!(stars, [[30.0, 0.0], [30.0, 120.0]]);
    assert_eq!([c.science.radius_arcsec, c.science.angle_deg], [10.0, 45.0]);
    // The layers as written: the library normalises them, once.
    let layers = c.layers.as_ref().unwrap();
    assert_eq!(
        layers
            .iter()
            .map(|l| [
                l.altitude_m,
                l.fraction,
                l.wind_speed_m_s,
                l.wind_direction_deg
            ])
            .collect::<Vec<_>>(),
        [[0.0, 3.0, 5.0, 10.0], [1000.0, 1.0, 10.0, 90.0]]
    );
    assert_eq!(
        (
            c.wind_scale,
            c.frame_rate_hz,
            c.delay_frames,
            c.science_wavelength_m
        ),
        (2.0, 500.0, 1.0, 2.2e-6)
    );
    assert_eq!(
        (c.dm_actuators_across, c.dm_coupling, c.fixed_noise_px),
        (Some(9), 0.3, 0.1)
    );
    assert_eq!(
        (c.episodes, c.episode_frames, c.calibration_episodes),
        (3, 7, 2)
    );
}
