//! Glue shared by the brightpix boards.
//!
//! Only what every board needs and that must exist exactly once per binary:
//! the embassy executor loop and its `__pender`.
#![no_std]

pub mod executor;
