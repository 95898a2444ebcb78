//! # brightpix-firmware
#![no_std]
pub mod camera;
pub mod device;
pub mod engine;
