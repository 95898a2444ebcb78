//! # brightpix-protocol
//!
//! What the brightpix firmware and host agree on, with no heap and no `std`:
//!
//! - [`config`]: the processing configuration (camera, sub-aperture windows,
//!   calibration maps, selection rule, centroiding) and its validation;
//! - `SPEC.md` beside this crate: the integer arithmetic that both the
//!   streaming engine and the host's reference implement, bit for bit;
//! - [`wire`]: the device–host protocol (messages, framing, configuration
//!   upload), described for other implementations in `PROTOCOL.md`.
#![no_std]
#![forbid(unsafe_code)]

pub mod config;
pub mod wire;

pub use config::*;
