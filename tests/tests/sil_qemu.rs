//! Simulation in the loop with the real firmware: the QEMU board's ELF
//! (`brightpix-qemu`) in `qemu-system-arm`, UART0 on a pseudo-terminal,
//! pixels through a FIFO that the board reads by semihosting (the emulated
//! UART takes only ~8 KB/s from the host: a CANARY frame every ~3 s). Driven through the host tool's client;
//! every result is checked bit for bit against the reference.
//!
//! Two builds: Cortex-M4F on mps2-an386 (every test) and Cortex-M7 on
//! mps2-an500 (`-C target-cpu=cortex-m7`, the STM32H743's code generation,
//! built into `firmware/target/cortex-m7`): every case bit-exact, the
//! limits and `doctor` (the `_m7` tests).
//!
//! Needs `qemu-system-arm` and the thumbv7em-none-eabihf target
//! (`scripts/test` installs both). The ELFs are (re)built by cargo in
//! `firmware/` first, which is quick when they are up to date.

mod sil_common;

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use brightpix::link::{Client, PixelSink};
use brightpix::sim_device::{build_qemu_elf_for, QemuCpu, QemuDevice, QemuOptions, SimLinkKind};
use brightpix_protocol::wire::PixelSourceKind;
use sil_common::*;

/// Builds the firmware for `cpu` once for all tests of this file.
fn elf_for(cpu: QemuCpu) -> std::path::PathBuf {
    static M4: OnceLock<std::path::PathBuf> = OnceLock::new();
    static M7: OnceLock<std::path::PathBuf> = OnceLock::new();
    let cell = match cpu {
        QemuCpu::M4 => &M4,
        QemuCpu::M7 => &M7,
    };
    cell.get_or_init(|| {
        let t = Instant::now();
        let elf = build_qemu_elf_for(cpu).unwrap_or_else(|e| panic!("{e:#}"));
        eprintln!(
            "  firmware build ({}): {:.1} s",
            cpu.cpu(),
            t.elapsed().as_secs_f64()
        );
        elf
    })
    .clone()
}

fn elf() -> std::path::PathBuf {
    elf_for(QemuCpu::M4)
}

fn launch_on(cpu: QemuCpu, pixels_fifo: bool) -> QemuDevice {
    let device = QemuDevice::launch(QemuOptions {
        elf: Some(elf_for(cpu)),
        pixels_fifo,
        cpu,
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    device.release_fifo(Duration::from_secs(10)).unwrap();
    device
}

fn launch(pixels_fifo: bool) -> QemuDevice {
    launch_on(QemuCpu::M4, pixels_fifo)
}

fn connect(device: &QemuDevice) -> Client {
    let mut client =
        Client::open(device.port()).unwrap_or_else(|e| panic!("{}: {e}", device.port()));
    if let Some(fifo) = device.pixels_fifo() {
        assert_eq!(client.info().pixel_source, PixelSourceKind::Stream);
        client.set_pixel_sink(PixelSink::Fifo(fifo.to_path_buf()));
    }
    client
}

/// Fails with the firmware's fate and log if QEMU has exited.
fn check_alive(device: &mut QemuDevice) {
    if let Some(status) = device.exit_status() {
        panic!(
            "the firmware {}; log:\n{}",
            QemuDevice::describe_exit(status),
            device.decoded_log().unwrap_or_default()
        );
    }
}

fn every_case_bit_exact(cpu: QemuCpu) {
    let cases = timed("simulating frames", all_cases);
    let mut device = launch_on(cpu, true);
    let mut client = connect(&device);
    eprintln!("  {}", client.info());
    for case in &cases {
        let t = Instant::now();
        let run = run_case(&mut client, case);
        check_alive(&mut device);
        eprintln!(
            "  {}: {} frames verified, row kernel in {} (expected: {}), stream {:.0} ms, case {:.0} ms",
            case.name,
            case.frames.len(),
            run.engine.kernel_frames,
            match kernel_expected(case) {
                Some(true) => "some",
                Some(false) => "none",
                None => "not checked",
            },
            run.stream.as_secs_f64() * 1e3,
            t.elapsed().as_secs_f64() * 1e3
        );
    }
}

#[test]
fn every_case_bit_exact_in_qemu() {
    every_case_bit_exact(QemuCpu::M4);
}

/// The Cortex-M7 build (the H743's code generation), bit for bit.
#[test]
fn every_case_bit_exact_in_qemu_m7() {
    every_case_bit_exact(QemuCpu::M7);
}

/// `doctor` against the QEMU device: the stack is read (painted, guarded
/// by the MPU, well within its size); silicon, clocks, USB clock, camera
/// interface, CPU idle, reset reason and watchdog are hardware only.
fn doctor_reads_the_stack_and_marks_the_rest(cpu: QemuCpu, board: &str) {
    use brightpix::cli::doctor::{diagnose, Verdict};
    let mut device = launch_on(cpu, true);
    let mut client = connect(&device);
    assert_eq!(client.info().board, board);
    // Some work first, so the stack has been used.
    run_case(&mut client, &edge_cases()[0]);
    let lines = diagnose(&mut client, Duration::ZERO).unwrap();
    check_alive(&mut device);
    let line = |name: &str| lines.iter().find(|l| l.name == name).unwrap().clone();
    let stack = line("stack");
    assert_eq!(stack.verdict, Verdict::Ok, "{stack}");
    assert!(stack.detail.contains("guarded"), "{stack}");
    let status = client.status().unwrap();
    let usage = status.health.stack.expect("the QEMU board reads its stack");
    assert!(usage.guarded);
    assert!(usage.peak > 256 && usage.peak < usage.size / 4, "{usage:?}");
    for name in [
        "silicon",
        "clocks",
        "usb clock",
        "camera interface",
        "cpu idle",
        "last reset",
        "watchdog",
    ] {
        let l = line(name);
        assert_eq!(l.verdict, Verdict::NotRead, "{l}");
        assert!(l.detail.contains("hardware only"), "{l}");
    }
    for name in ["link", "counters", "last fault"] {
        assert_eq!(line(name).verdict, Verdict::Ok, "{}", line(name));
    }
}

/// A deliberate HardFault (`selftest=fault-once`: an undefined instruction
/// at boot unless the last reset was a recorded fault): the handler keeps
/// the registers in no-init RAM and resets the board, which boots again,
/// serves, and reports the fault in `Status.health.faults` and `doctor`.
#[test]
fn a_hard_fault_is_reported_after_the_reboot() {
    use brightpix::cli::doctor::{diagnose, Verdict};
    let mut device = QemuDevice::launch(QemuOptions {
        elf: Some(elf_for(QemuCpu::M4)),
        board_args: vec!["selftest=fault-once".into()],
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    let mut client = connect(&device);
    let status = client.status().unwrap();
    let fault = status
        .health
        .faults
        .expect("the QEMU board keeps a fault record")
        .before_reset
        .expect("the fault before the reboot");
    // UDF: CFSR.UNDEFINSTR, escalated (HFSR.FORCED); the PC in the code.
    assert_ne!(fault.cfsr & (1 << 16), 0, "{fault:x?}");
    assert_ne!(fault.hfsr & (1 << 30), 0, "{fault:x?}");
    assert!(fault.pc > 0 && fault.pc < 0x40_0000, "{fault:x?}");
    let lines = diagnose(&mut client, Duration::ZERO).unwrap();
    let l = lines.iter().find(|l| l.name == "last fault").unwrap();
    assert_eq!(l.verdict, Verdict::Fail, "{l}");
    assert!(l.detail.contains("UNDEFINSTR"), "{l}");
    // And the rebooted board works.
    run_case(&mut client, &edge_cases()[0]);
    check_alive(&mut device);
}

#[test]
fn doctor_in_qemu() {
    doctor_reads_the_stack_and_marks_the_rest(QemuCpu::M4, "qemu-mps2-an386");
}

#[test]
fn doctor_in_qemu_m7() {
    doctor_reads_the_stack_and_marks_the_rest(QemuCpu::M7, "qemu-mps2-an500");
}

fn case_with_maps() -> Case {
    edge_cases()
        .into_iter()
        .find(|c| c.config.background.is_some() && c.config.gain.is_some())
        .unwrap()
}

#[test]
fn failed_upload_keeps_the_old_configuration_in_qemu() {
    let mut device = launch(true);
    let case = case_with_maps();
    failed_uploads_keep_old_config(&mut || connect(&device), &case);
    check_alive(&mut device);
}

/// Issue 10, fault 1, as found: in QEMU, over UART0 (a client killed
/// mid-frame, then `stream --count 3 --verify` verified only 2 frames).
#[test]
fn a_dead_clients_leftovers_do_not_reach_the_next_session_in_qemu() {
    let mut device = launch(false);
    dead_client_leaves_nothing_behind(&mut || connect(&device), &edge_cases()[0]);
    check_alive(&mut device);
}

/// `check-config --device qemu` checks against what the firmware reports
/// (the M7 build: the same limits under its own board name).
fn the_qemu_limits_known_offline_are_the_firmwares_on(cpu: QemuCpu) {
    let mut device = launch_on(cpu, false);
    let client = connect(&device);
    let reported = brightpix::link::limits::DeviceLimits::of(client.info());
    let mut known = brightpix::link::limits::DeviceLimits::named("qemu").unwrap();
    if cpu == QemuCpu::M7 {
        known.board = "qemu-mps2-an500".into();
    }
    assert_eq!(reported, known);
    check_alive(&mut device);
}

#[test]
fn the_qemu_limits_known_offline_are_the_firmwares() {
    the_qemu_limits_known_offline_are_the_firmwares_on(QemuCpu::M4);
}

#[test]
fn the_qemu_limits_known_offline_are_the_firmwares_m7() {
    the_qemu_limits_known_offline_are_the_firmwares_on(QemuCpu::M7);
}

/// Issue 10, fault 4: `simulate-device --qemu` killed with SIGKILL left
/// `qemu-system-arm` running as an orphan holding the pty. This test runs
/// itself as the parent (a child process of the test binary that launches
/// QEMU and waits), kills that parent with SIGKILL, and checks that QEMU is
/// gone within 3 s.
#[test]
fn qemu_dies_with_its_parent() {
    const ROLE: &str = "BRIGHTPIX_TEST_QEMU_PARENT";
    if std::env::var_os(ROLE).is_some() {
        let device = launch(false);
        println!("qemu-pid {}", device.pid());
        std::io::Write::flush(&mut std::io::stdout()).unwrap();
        std::thread::sleep(Duration::from_secs(60));
        return;
    }
    let mut parent = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "qemu_dies_with_its_parent",
            "--exact",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(ROLE, "1")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let stdout = parent.stdout.take().unwrap();
    let mut pid = None;
    for line in std::io::BufRead::lines(std::io::BufReader::new(stdout)) {
        let line = line.unwrap();
        // The test harness may have printed "test ... " on the same line.
        if let Some(at) = line.find("qemu-pid ") {
            pid = Some(line[at + 9..].trim().parse::<u32>().unwrap());
            break;
        }
    }
    let pid = pid.expect("the parent reports QEMU's pid");
    let alive = |pid: u32| {
        // A zombie (state Z) has exited; only its parent's reaping is due.
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .map(|s| {
                !s.rsplit(')')
                    .next()
                    .unwrap_or("")
                    .trim_start()
                    .starts_with('Z')
            })
            .unwrap_or(false)
    };
    assert!(alive(pid), "QEMU runs while its parent does");
    parent.kill().unwrap(); // SIGKILL: no handler, no destructor runs
    parent.wait().unwrap();
    let t = std::time::Instant::now();
    while alive(pid) && t.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let orphan = alive(pid);
    if orphan {
        // Do not leave it behind for the next test.
        let _ = std::process::Command::new("kill")
            .args(["-KILL", &pid.to_string()])
            .status();
    }
    assert!(!orphan, "qemu-system-arm (pid {pid}) outlived its parent");
}

#[test]
fn corrupted_pixel_frame_is_counted_and_rejected_in_qemu() {
    let mut device = launch(true);
    let mut client = connect(&device);
    // The damaged frame goes over UART0; the others through the FIFO.
    corrupted_pixel_frame_is_rejected(&mut client, &case_with_maps());
    check_alive(&mut device);
}

#[test]
fn pixels_over_the_uart_and_a_unix_socket_in_qemu() {
    // The slow path, briefly: 20 small frames (1.9 KB each) over UART0,
    // which QEMU serves on a Unix socket (every case above runs 100 frames
    // through the FIFO).
    let dir = brightpix::sim_device::temp_dir("brightpix-test-qemu-unix").unwrap();
    let mut device = QemuDevice::launch(QemuOptions {
        elf: Some(elf()),
        link: SimLinkKind::Unix(dir.join("uart0.sock")),
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    let mut client = connect(&device);
    assert_eq!(client.info().pixel_source, PixelSourceKind::Link);
    let first = edge_cases().swap_remove(0);
    let case = &Case {
        frames: first.frames[..20].to_vec(),
        ..first
    };
    let stream = run_case(&mut client, case).stream;
    eprintln!(
        "  over UART0: {} frames in {:.2} s",
        case.frames.len(),
        stream.as_secs_f64()
    );
    check_alive(&mut device);
    drop(client);
    device.stop();
    let _ = std::fs::remove_dir_all(dir);
}

/// A rig of three QEMU boards (Cortex-M4, M7, M4) on one CANARY camera:
/// each board runs its rectangle's part, the merged results equal the
/// whole-camera reference bit for bit (issue 23: `demo --boards 3 --qemu`).
#[test]
fn rig_of_three_boards_m4_and_m7() {
    use brightpix::rig::{self, BoardKind, Rig};
    use brightpix::sil::{canary_config, canary_frames};
    let whole = canary_config();
    let kind = BoardKind::QemuM4;
    let plan = rig::plan(&whole, 3, kind, &kind.cost_model()).unwrap();
    let rig = Rig::from_plan(whole, kind, None, &plan).unwrap();
    let devices: Vec<QemuDevice> = [QemuCpu::M4, QemuCpu::M7, QemuCpu::M4]
        .into_iter()
        .map(|cpu| launch_on(cpu, true))
        .collect();
    let mut clients: Vec<Client> = devices.iter().map(connect).collect();
    rig::configure(&rig, &mut clients).unwrap();
    let frames = canary_frames(12, 5);
    let run = rig::stream(&rig, clients, &frames, 0, true, |_| {});
    let v = run.verifier.as_ref().unwrap();
    assert_eq!((run.frames_complete, run.frames_partial), (12, 0));
    assert!(
        v.all_match() && v.frames_verified == 12 && v.slopes_compared == 12 * 49,
        "{:?}",
        v.mismatches
    );
    for r in &run.boards {
        assert!(r.error.is_none(), "{:?}", r.error);
    }
}

/// `rig capture` in QEMU: three boards (Cortex-M4, M7, M4) on one
/// simulated camera (one timeline of frames, one sync line: the boards'
/// frame servers share a `SharedCamera`), each configured with its band
/// of the CANARY sensor as its crop: the firmware's camera task reads the
/// whole sensor and keeps the band (the DCMI crop's software twin). Board
/// 1's start comes two frame periods late (USB latency, as the test knob
/// of the shared camera). Without the sync line the boards begin on
/// different camera frames: they say so, and the merge by frame number
/// differs from the whole-camera reference. On the sync line (board 0
/// leading) every board begins on the frame after the leader's edge and
/// the merge equals the reference bit for bit. The bands share a row with
/// their neighbours (`with_shared_rows`): the boards' checksums of it
/// (`EdgeRows`, from the firmware) disagree on every skewed frame and
/// agree on every synced one.
#[test]
fn rig_capture_in_qemu_is_aligned_by_the_sync_line_and_not_without() {
    use brightpix::rig::{self, BoardKind, Rig, RigStart, RigStream};
    use brightpix::sil::canary_config;
    use brightpix::sim_device::{CameraFrames, CameraSpec, SharedCamera};
    use std::sync::Arc;
    let whole = canary_config();
    let kind = BoardKind::QemuM4;
    let plan = rig::plan(&whole, 3, kind, &kind.cost_model()).unwrap();
    // Neighbouring bands share a row: the boards checksum it every frame.
    let rig = Rig::from_plan(whole, kind, None, &plan)
        .unwrap()
        .with_shared_rows()
        .unwrap();
    assert!(rig.boards.iter().all(|b| b.config.crop.is_some()));
    assert_eq!(rig.shared_rows(), [(0, 1), (1, 2)]);
    let shared = Arc::new(
        SharedCamera::new(CameraSpec { seed: 6 }, 10)
            .with_sync_line()
            .with_start_delays(vec![0, 2, 0]),
    );
    let mut devices: Vec<QemuDevice> = [QemuCpu::M4, QemuCpu::M7, QemuCpu::M4]
        .into_iter()
        .enumerate()
        .map(|(b, cpu)| {
            QemuDevice::launch(QemuOptions {
                elf: Some(elf_for(cpu)),
                cpu,
                camera: Some(shared.board(b)),
                ..QemuOptions::default()
            })
            .unwrap_or_else(|e| panic!("{e:#}"))
        })
        .collect();
    let mut clients: Vec<Client> = devices.iter().map(connect).collect();
    rig::configure(&rig, &mut clients).unwrap();
    let camera = CameraFrames::new(rig.whole.camera, 6);
    let mut capture = |start: RigStart| {
        let mut capture = RigStream::new(&rig, true);
        capture.capture(
            &mut clients,
            12,
            start,
            &mut |k| camera.frames(u64::from(k), 1).pop(),
            &mut |_| {},
        );
        capture.finish(&mut |_| {})
    };

    let skewed = capture(RigStart::Immediate);
    let firsts: Vec<u32> = skewed
        .boards
        .iter()
        .map(|r| {
            assert!(r.error.is_none(), "{:?}", r.error);
            let began = r.began.expect("every board says how it began");
            assert!(!began.synced);
            began
                .camera_frame
                .expect("a simulated camera numbers frames")
        })
        .collect();
    assert!(firsts[1] > firsts[0], "board 1 starts late: {firsts:?}");
    let v = skewed.verifier.as_ref().unwrap();
    assert!(
        !v.all_match() && v.mismatch_count > 0,
        "a merge of different camera frames must not verify ({firsts:?})"
    );
    // The shared rows tell too, without the reference.
    assert_eq!(skewed.edge_check.frames_checked, 12);
    assert_eq!(skewed.edge_check.frames_disagreeing, 12);

    let synced = capture(RigStart::Sync { leader: 0 });
    for d in &mut devices {
        check_alive(d);
    }
    let firsts: Vec<u32> = synced
        .boards
        .iter()
        .map(|r| {
            assert!(r.error.is_none(), "{:?}", r.error);
            let began = r.began.expect("every board says how it began");
            assert!(began.synced, "{began:?}");
            began.camera_frame.unwrap()
        })
        .collect();
    assert!(firsts.iter().all(|&f| f == firsts[0]), "{firsts:?}");
    assert_eq!(synced.edge_check.frames_checked, 12);
    assert_eq!(synced.edge_check.frames_disagreeing, 0);
    let v = synced.verifier.as_ref().unwrap();
    assert_eq!((synced.frames_complete, synced.frames_partial), (12, 0));
    assert!(
        v.all_match() && v.frames_verified == 12 && v.slopes_compared == 12 * 49,
        "{:?}",
        v.mismatches
    );
}

/// The board's bench mode, the whole path: `brightpix bench --port` (the
/// CLI's function) against the QEMU board under `-icount shift=6`, on the
/// CANARY workload. The board counts instructions with the QEMU bench's
/// meter on the same generated frames, so its figures must be the QEMU
/// bench's (`run-bench m4 --only ...`, run here too) within a small band:
/// not bit for bit, because the board's copy of the measuring code is
/// generic over the counter and linked into the device, which moves the
/// code around the timed calls by a few instructions a row. What must hold
/// exactly: the floor's slopes equal the engine's on every frame (checked
/// on the board), the counts are instructions and consistent, and the
/// device's configuration survives the bench: same digest, and frames
/// streamed afterwards are bit-exact without configuring again. Between
/// the two, the link test (`bench --port --link`'s request) on the same
/// firmware: its fill arrives intact and as counted.
#[test]
fn bench_port_counts_instructions_and_keeps_the_configuration() {
    use brightpix::cli::bench_port::{self, PortBench};
    use brightpix_protocol::wire::{BenchFault, BenchResult, CountUnit, DeviceError, FloorCheck};

    const WORKLOAD: &str = "canary-subtract-next-n20";
    let mut device = QemuDevice::launch(QemuOptions {
        elf: Some(elf()),
        pixels_fifo: true,
        icount: Some(6),
        ..QemuOptions::default()
    })
    .unwrap_or_else(|e| panic!("{e:#}"));
    device.release_fifo(Duration::from_secs(10)).unwrap();
    let case = canary_case();
    let digest = {
        let mut client = connect(&device);
        run_case(&mut client, &case);
        // Refusals change nothing.
        let refused = |r: Result<_, brightpix::link::LinkError>| match r {
            Err(brightpix::link::LinkError::Device {
                error: DeviceError::Bench(fault),
                ..
            }) => fault,
            other => panic!("expected a refusal, got {other:?}"),
        };
        let long = Duration::from_secs(60);
        assert_eq!(
            refused(client.bench("no-such-workload", 0, long, |_| {})),
            BenchFault::UnknownWorkload
        );
        assert_eq!(
            refused(client.bench(WORKLOAD, 65, long, |_| {})),
            BenchFault::TooManyFrames { max: 64 }
        );
        client.status().unwrap().config_digest
    };
    assert!(digest.is_some());

    let dir = brightpix::sim_device::temp_dir("brightpix-bench-port").unwrap();
    let json_path = dir.join("bench.json");
    let rows = bench_port::run(&PortBench {
        port: device.port(),
        workload: Some(WORKLOAD),
        frames: 0,
        json: Some(&json_path),
        per_workload: Duration::from_secs(120),
    })
    .unwrap_or_else(|e| panic!("bench --port: {e:#}"));
    check_alive(&mut device);
    assert_eq!(rows.len(), 1);
    let row = &rows[0];
    assert_eq!(row.workload, WORKLOAD);
    assert_eq!(row.unit, CountUnit::Instructions, "QEMU runs with -icount");
    assert_eq!((row.pixels, row.frames), (112 * 112, 8));
    let BenchResult::Measured(f) = row.result else {
        panic!("not measured: {row:?}");
    };
    assert_eq!(f.floor_check, FloorCheck::Equal);
    for (name, s, total) in [
        ("engine", f.engine_frame, f.engine_total),
        ("floor", f.floor_frame, f.floor_total),
    ] {
        assert!(
            s.min > 0 && s.min <= s.median && s.median <= s.max,
            "{name}: {s:?}"
        );
        let frames = row.frames as u64;
        assert!(
            s.min * frames <= total + frames && total <= s.max * frames + frames,
            "{name}: total {total} outside the frames' {s:?}"
        );
    }
    assert!(f.engine_last_row.median > 0 && f.engine_last_row.median < f.engine_frame.min);
    let (engine, floor) = (
        bench_port::per_pixel(row, f.engine_total),
        bench_port::per_pixel(row, f.floor_total),
    );
    assert!(
        engine > floor && engine / floor < 6.0,
        "{engine} vs {floor}"
    );

    // The QEMU bench on the same workload and core.
    let repo = brightpix::bench::qemu::repository_root().expect("the repository");
    let qemu = brightpix::bench::qemu::run(
        &repo,
        brightpix::bench::qemu::QemuCore::M4,
        &["--only".into(), WORKLOAD.into()],
    )
    .unwrap_or_else(|e| panic!("the QEMU bench: {e}"));
    let q = qemu.rows.iter().find(|r| r.workload == WORKLOAD).unwrap();
    let near = |a: f64, b: f64, band: f64| (a - b).abs() <= band * b;
    eprintln!(
        "  board: engine {engine:.3} instr/px, floor {floor:.3}, last row {}; QEMU bench: {:.3}, {:.3}, {:.0}",
        f.engine_last_row.median,
        q.instr_per_px,
        q.floor_instr_per_px.unwrap(),
        q.last_row_instructions
    );
    assert!(
        near(engine, q.instr_per_px, 0.02),
        "engine {engine} vs {}",
        q.instr_per_px
    );
    assert!(
        near(floor, q.floor_instr_per_px.unwrap(), 0.03),
        "floor {floor} vs {:?}",
        q.floor_instr_per_px
    );
    assert!(
        near(
            f.engine_last_row.median as f64,
            q.last_row_instructions,
            0.15
        ),
        "last row {:?} vs {}",
        f.engine_last_row,
        q.last_row_instructions
    );

    // The JSON the CLI wrote.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    assert_eq!(json["board"], "qemu-mps2-an386");
    let w = &json["workloads"][0];
    for key in [
        "workload",
        "unit",
        "pixels",
        "frames",
        "engine_per_px",
        "floor_per_px",
        "x_floor",
        "engine_frame",
        "engine_last_row",
        "floor_frame",
        "floor_last_row",
        "floor_check",
    ] {
        assert!(!w[key].is_null(), "{key} missing in {w}");
    }
    assert_eq!(w["unit"], "instructions");
    assert!(w["mpx_per_s"].is_null(), "no Mpx/s from instructions");
    assert_eq!(json["config_digest"], serde_json::json!(digest));

    // The link test (PROTOCOL.md §15) on the real firmware: the fill
    // arrives intact, counted as sent.
    let mut client = connect(&device);
    let link = client
        .link_test(4_000, 100)
        .unwrap_or_else(|e| panic!("link test: {e:#}"));
    assert_eq!((link.bytes, link.messages), (4_000, 40));
    assert!(link.link_bytes > 4_000 && link.link_bytes < 4_000 + 40 * 16);

    // The configuration is intact: same digest, and streaming without
    // configuring again is bit-exact.
    assert_eq!(client.status().unwrap().config_digest, digest);
    let view = case.config.view();
    let run = brightpix::sil::stream_and_verify(&mut client, &view, &case.frames[..20], 500, 5);
    assert!(run.error.is_none(), "{:?}", run.error);
    assert!(run.verifier.all_match() && run.verifier.frames_verified == 20);
    check_alive(&mut device);
    let _ = std::fs::remove_dir_all(dir);
}
