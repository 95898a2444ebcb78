//! # brightpix-firmware
#![no_std]
pub mod engine;
