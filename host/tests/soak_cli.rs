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
