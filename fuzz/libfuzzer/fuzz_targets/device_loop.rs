//! `cargo fuzz run device_loop`: see `brightpix_fuzz_harness::device_loop`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| brightpix_fuzz_harness::device_loop(data));
