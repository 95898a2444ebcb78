//! Glue shared by the brightpix boards.
//!
//! What every board needs: the embassy executor loop and its `__pender`
//! (exactly once per binary), and the stack's guard and high-water mark.
#![no_std]

pub mod executor;
pub mod stack;
