//! `cargo fuzz run wire_decoder`: see `brightpix_fuzz_harness::wire_decoder`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| brightpix_fuzz_harness::wire_decoder(data));
