//! `brightpix soak`, briefly, as CI runs it: in-process and in QEMU, every
//! frame verified, the report complete, exit status 0.

use std::process::Command;

fn soak(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .arg("soak")
        .args(args)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    for line in [
        "frames:",
        "failures:   0 mismatches, 0 frames dropped, 0 missing",
        "device:",
        "memory:",
    ] {
        assert!(text.contains(line), "no `{line}` in:\n{text}");
    }
    eprintln!("{text}");
    text
}

#[test]
fn a_short_soak_in_process() {
    let text = soak(&["--minutes", "0.1", "--pool", "16"]);
    assert!(text.contains("kB resident at the start"), "{text}");
}

#[test]
fn a_short_soak_in_qemu() {
    // Built afresh (incremental): an older ELF would speak another schema.
    let elf = brightpix::sim_device::build_qemu_elf().unwrap();
    soak(&[
        "--minutes",
        "0.15",
        "--pool",
        "8",
        "--qemu",
        "--elf",
        elf.to_str().unwrap(),
    ]);
}

/// Ctrl-C ends the soak with the same report, the device's counters
/// included (it printed "no status at the end: interrupted" and exited 1).
#[test]
fn ctrl_c_gives_the_report() {
    let child = Command::new(env!("CARGO_BIN_EXE_brightpix"))
        .args(["soak", "--minutes", "5", "--pool", "16"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(3));
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let out = child.wait_with_output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("no status at the end"), "{text}");
    assert!(
        text.contains("frames processed") && text.contains("failures:   0 mismatches"),
        "{text}"
    );
}
