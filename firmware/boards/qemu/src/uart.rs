//! CMSDK APB UART0 (mps2 boards, 0x4000_4000) as an async byte transport.
//!
//! `Uart0` (or its halves from `split`) implements `embedded_io_async::{Read, Write}`,
//! so code written against those traits runs over it unchanged.
//!
//! RX is interrupt driven: the UART0 RX interrupt (IRQ 0) moves bytes from the
//! UART's one-byte holding register into a software FIFO (`RX_FIFO_LEN` bytes)
//! that `read` drains. When the FIFO is full, the handler masks its own IRQ and
//! leaves the byte in the UART, which stops QEMU from accepting more input (no
//! data is dropped); `read` unmasks it after making room.
//!
//! TX writes into the data register while it is free; when it is busy, `write`
//! enables the TX interrupt (IRQ 1) and sleeps until the byte has gone out.

use core::convert::Infallible;
use core::future::poll_fn;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use core::task::Poll;

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::NVIC;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::waitqueue::AtomicWaker;

const BASE: usize = 0x4000_4000;
const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
/// Reads give INTSTATUS; writes of 1 bits clear them (INTCLEAR).
const INTSTATUS: usize = 0x0C;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_TX_INTEN: u32 = 1 << 2;
const CTRL_RX_INTEN: u32 = 1 << 3;
const INT_TX: u32 = 1 << 0;
const INT_RX: u32 = 1 << 1;

/// QEMU drops data unless BAUDDIV >= 16; it has no effect on QEMU's speed.
const BAUD_DIVISOR: u32 = 16;
pub const RX_FIFO_LEN: usize = 256;

static RX_FIFO: Pipe<CriticalSectionRawMutex, RX_FIFO_LEN> = Pipe::new();
static TX_WAKER: AtomicWaker = AtomicWaker::new();
static RX_STALLS: AtomicU32 = AtomicU32::new(0);
static TX_WAITS: AtomicU32 = AtomicU32::new(0);

/// Flow-control counters, for tests and diagnostics.
#[derive(Clone, Copy, defmt::Format)]
pub struct Stats {
    /// Times the RX FIFO was full and the RX interrupt stopped taking bytes.
    pub rx_stalls: u32,
    /// Times a write had to wait for the TX interrupt.
    pub tx_waits: u32,
}

/// Current flow-control counters.
pub fn stats() -> Stats {
    Stats {
        rx_stalls: RX_STALLS.load(Ordering::Relaxed),
        tx_waits: TX_WAITS.load(Ordering::Relaxed),
    }
}

/// mps2-an385/an386/an500 interrupt lines of UART0.
#[derive(Clone, Copy)]
#[repr(u16)]
pub enum Irq {
    Uart0Rx = 0,
    Uart0Tx = 1,
}

// SAFETY: the values are valid IRQ numbers on the mps2 boards.
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

fn reg_read(offset: usize) -> u32 {
    // SAFETY: a valid, aligned MMIO register of UART0.
    unsafe { read_volatile((BASE + offset) as *const u32) }
}

fn reg_write(offset: usize, value: u32) {
    // SAFETY: a valid, aligned MMIO register of UART0.
    unsafe { write_volatile((BASE + offset) as *mut u32, value) }
}

fn modify_ctrl(f: impl FnOnce(u32) -> u32) {
    critical_section::with(|_| reg_write(CTRL, f(reg_read(CTRL))));
}

fn tx_full() -> bool {
    reg_read(STATE) & STATE_TX_FULL != 0
}

/// UART0, owned. Create once with [`Uart0::new`].
pub struct Uart0 {
    rx: Uart0Rx,
    tx: Uart0Tx,
}

/// The receiving half of [`Uart0`].
pub struct Uart0Rx {
    _private: (),
}

/// The transmitting half of [`Uart0`].
pub struct Uart0Tx {
    _private: (),
}

impl Uart0 {
    /// Configure UART0 (TX, RX, RX interrupt) and unmask its interrupts.
    /// Returns `None` if called more than once.
    pub fn new() -> Option<Self> {
        static TAKEN: AtomicBool = AtomicBool::new(false);
        if TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        reg_write(CTRL, 0);
        reg_write(INTSTATUS, INT_TX | INT_RX);
        reg_write(BAUDDIV, BAUD_DIVISOR);
        reg_write(CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INTEN);
        // SAFETY: the handlers (on_rx_interrupt/on_tx_interrupt) do not break any
        // critical section; unmasking cannot violate a mask-based critical section
        // since we use PRIMASK (critical-section-single-core).
        unsafe {
            NVIC::unmask(Irq::Uart0Rx);
            NVIC::unmask(Irq::Uart0Tx);
        }
        Some(Self {
            rx: Uart0Rx { _private: () },
            tx: Uart0Tx { _private: () },
        })
    }

    /// Split into halves that can be used from different tasks.
    pub fn split(self) -> (Uart0Rx, Uart0Tx) {
        (self.rx, self.tx)
    }
}

impl Uart0Rx {
    async fn read_bytes(&mut self, buf: &mut [u8]) -> usize {
        if buf.is_empty() {
            return 0;
        }
        let n = RX_FIFO.read(buf).await;
        // There is room in the FIFO again: let the RX handler run if it had to stop.
        // SAFETY: see Uart0::new.
        unsafe { NVIC::unmask(Irq::Uart0Rx) };
        n
    }
}

impl Uart0Tx {
    async fn write_bytes(&mut self, buf: &[u8]) -> usize {
        if buf.is_empty() {
            return 0;
        }
        poll_fn(|cx| {
            let mut n = 0;
            while n < buf.len() && !tx_full() {
                reg_write(DATA, u32::from(buf[n]));
                n += 1;
            }
            if n > 0 {
                return Poll::Ready(n);
            }
            TX_WAITS.fetch_add(1, Ordering::Relaxed);
            TX_WAKER.register(cx.waker());
            modify_ctrl(|c| c | CTRL_TX_INTEN);
            if tx_full() {
                Poll::Pending
            } else {
                // Drained between the check and enabling the interrupt.
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await
    }

    async fn wait_tx_idle(&mut self) {
        poll_fn(|cx| {
            if !tx_full() {
                return Poll::Ready(());
            }
            TX_WAKER.register(cx.waker());
            modify_ctrl(|c| c | CTRL_TX_INTEN);
            if tx_full() {
                Poll::Pending
            } else {
                Poll::Ready(())
            }
        })
        .await
    }
}

/// UART0 RX interrupt (IRQ 0).
#[unsafe(no_mangle)]
extern "C" fn UART0_RX() {
    loop {
        if RX_FIFO.is_full() {
            // Leave INTSTATUS.RX set and the byte in the UART; `read` unmasks us.
            NVIC::mask(Irq::Uart0Rx);
            RX_STALLS.fetch_add(1, Ordering::Relaxed);
            return;
        }
        // Clear first: a byte that arrives after this sets it again (no lost edge).
        reg_write(INTSTATUS, INT_RX);
        if reg_read(STATE) & STATE_RX_FULL == 0 {
            return;
        }
        let byte = reg_read(DATA) as u8;
        // Cannot fail: we checked there is room and only this handler writes.
        let _ = RX_FIFO.try_write(&[byte]);
    }
}

/// UART0 TX interrupt (IRQ 1): the transmit register became free.
#[unsafe(no_mangle)]
extern "C" fn UART0_TX() {
    reg_write(INTSTATUS, INT_TX);
    modify_ctrl(|c| c & !CTRL_TX_INTEN);
    TX_WAKER.wake();
}

impl embedded_io_async::ErrorType for Uart0 {
    type Error = Infallible;
}
impl embedded_io_async::ErrorType for Uart0Rx {
    type Error = Infallible;
}
impl embedded_io_async::ErrorType for Uart0Tx {
    type Error = Infallible;
}

impl embedded_io_async::Read for Uart0Rx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        Ok(self.read_bytes(buf).await)
    }
}

impl embedded_io_async::Write for Uart0Tx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        Ok(self.write_bytes(buf).await)
    }

    /// Waits until the last byte has left the transmit register.
    async fn flush(&mut self) -> Result<(), Infallible> {
        self.wait_tx_idle().await;
        Ok(())
    }
}

impl embedded_io_async::Read for Uart0 {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        Ok(self.rx.read_bytes(buf).await)
    }
}

impl embedded_io_async::Write for Uart0 {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        Ok(self.tx.write_bytes(buf).await)
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        self.tx.wait_tx_idle().await;
        Ok(())
    }
}
