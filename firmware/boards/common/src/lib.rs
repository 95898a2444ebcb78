//! Glue shared by the brightpix boards.
//!
//! What every board needs: the embassy executor loop and its `__pender`
//! (exactly once per binary), the stack's guard and high-water mark, and
//! the fault record kept across a reset.
#![no_std]

pub mod executor;
pub mod fault;
pub mod stack;
