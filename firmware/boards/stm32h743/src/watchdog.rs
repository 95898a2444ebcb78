//! The independent watchdog (IWDG1, clocked by the 32 kHz LSI, so it runs
//! whatever happens to the main clocks) fed by the device loop
//! (`brightpix_firmware::device::Watchdog`), and the reset reason read from
//! RCC_RSR at boot, both reported in `Status`.
//!
//! If the device loop stops coming back to its awaits for
//! [`TIMEOUT_MS`] (a hang in the engine or the loop, a fault handler that
//! spins, an interrupt storm that starves the executor), the board resets
//! and the next `Status` says `reset_reason: Watchdog`. The board feeds it
//! itself while no host is connected (`main`). A debugger that halts the
//! core lets it expire unless DBGMCU_APB4FZ1.DBG_IWDG1 is set.

use brightpix_firmware::device::Watchdog;
use brightpix_protocol::wire::ResetReason;
use embassy_stm32::pac;
use embassy_stm32::peripherals::IWDG1;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::Peri;
use embassy_time::Timer;

/// The watchdog's timeout.
pub const TIMEOUT_MS: u32 = 2000;

/// The loop feeds it at least this often while it waits.
pub const FEED_EVERY_MS: u64 = TIMEOUT_MS as u64 / 4;

pub struct Iwdg<'d>(IndependentWatchdog<'d, IWDG1>);

impl<'d> Iwdg<'d> {
    /// Starts IWDG1 (it cannot be stopped again until the next reset).
    pub fn start(iwdg: Peri<'d, IWDG1>) -> Self {
        let mut wdg = IndependentWatchdog::new(iwdg, TIMEOUT_MS * 1000);
        wdg.unleash();
        Iwdg(wdg)
    }
}

impl Watchdog for Iwdg<'_> {
    fn timeout_ms(&self) -> Option<u32> {
        Some(TIMEOUT_MS)
    }

    fn feed(&mut self) {
        self.0.pet();
    }

    async fn due(&mut self) {
        Timer::after_millis(FEED_EVERY_MS).await;
    }
}

/// Why the MCU last reset (RCC_RSR), then clears the flags so that the
/// next reset reports only itself. Several flags are set together (a
/// watchdog reset also sets PINRSTF: NRST is driven low); the most specific
/// wins.
pub fn reset_reason() -> ResetReason {
    let rsr = pac::RCC.rsr().read();
    let reason = if rsr.iwdg1rstf() {
        ResetReason::Watchdog
    } else if rsr.wwdg1rstf() || rsr.lpwrrstf() {
        ResetReason::Other
    } else if rsr.sftrstf() {
        ResetReason::Software
    } else if rsr.porrstf() {
        ResetReason::PowerOn
    } else if rsr.borrstf() {
        ResetReason::Brownout
    } else if rsr.pinrstf() {
        ResetReason::Pin
    } else {
        ResetReason::Unknown
    };
    pac::RCC.rsr().modify(|w| w.set_rmvf(true));
    reason
}
