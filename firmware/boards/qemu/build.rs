//! Puts this board's memory.x and device.x where cortex-m-rt's link.x
//! (`INCLUDE memory.x`, `INCLUDE device.x`) finds them.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap());
    for file in ["memory.x", "device.x"] {
        fs::copy(file, out.join(file)).unwrap();
        println!("cargo:rerun-if-changed={file}");
    }
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=build.rs");
    // brightpix-bench's workloads.rs, compiled into the QEMU bench binary,
    // counts with that binary's `Meter` itself rather than a generic
    // counter (which moves the QEMU tables' figures: bench/src/lib.rs).
    println!("cargo::rustc-check-cfg=cfg(brightpix_qemu_bench)");
    println!("cargo:rustc-cfg=brightpix_qemu_bench");
}
