//! What the benchmark counts with.

/// Counts the work of a closure: instructions (QEMU's timer under
/// `-icount`), cycles (DWT CYCCNT), or whatever the board has.
pub trait Counter {
    /// The count of `f`, less the counter's own overhead, and its result.
    fn count<R>(&self, f: impl FnOnce() -> R) -> (f64, R);

    /// Called before each measured frame, untimed (a board feeds its
    /// watchdog here; [`Recorder`](crate::device::Recorder) starts the
    /// frame's counts).
    #[inline(always)]
    fn between_frames(&self) {}
}
