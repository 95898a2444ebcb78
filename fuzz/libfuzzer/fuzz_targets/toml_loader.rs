//! `cargo fuzz run toml_loader`: see `brightpix_fuzz_harness::toml_loader`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| brightpix_fuzz_harness::toml_loader(data));
