//! The device loop's watchdog hook: a board with an independent watchdog
//! (the STM32H743's IWDG) hands it to [`Device::with_watchdog`](super::Device::with_watchdog),
//! and the loop feeds it whenever it is alive: after every message and
//! pixel run it handles, and while it waits for the link, the camera or a
//! slow host (woken by [`Watchdog::due`] to do so). A loop that stops
//! returning to its awaits (a hang in the engine or the loop, a fault
//! handler spinning, a starved executor) stops feeding it, and the board
//! resets; `Status.reset_reason` then says `Watchdog`.

/// A watchdog the device loop feeds.
#[allow(async_fn_in_trait)]
pub trait Watchdog {
    /// Its timeout, reported in `Status.watchdog_ms`.
    fn timeout_ms(&self) -> Option<u32>;
    /// Reloads its counter.
    fn feed(&mut self);
    /// Completes when the loop, waiting for something else, should feed it
    /// (a timer well within the timeout). Must be cancel-safe.
    async fn due(&mut self);
}

/// No watchdog (QEMU, the in-process device, the tests).
pub struct NoWatchdog;

impl Watchdog for NoWatchdog {
    fn timeout_ms(&self) -> Option<u32> {
        None
    }
    fn feed(&mut self) {}
    async fn due(&mut self) {
        core::future::pending().await
    }
}
