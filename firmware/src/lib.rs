//! # brightpix-firmware
#![no_std]
pub mod device;
pub mod engine;
