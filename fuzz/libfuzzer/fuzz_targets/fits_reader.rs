//! `cargo fuzz run fits_reader`: see `brightpix_fuzz_harness::fits_reader`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| brightpix_fuzz_harness::fits_reader(data));
