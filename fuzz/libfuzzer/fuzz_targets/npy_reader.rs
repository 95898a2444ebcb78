//! `cargo fuzz run npy_reader`: see `brightpix_fuzz_harness::npy_reader`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| brightpix_fuzz_harness::npy_reader(data));
