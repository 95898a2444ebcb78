//! The board's health, reported at the end of [`Status`](super::Status):
//! what a bring-up engineer checks first on a new board (`brightpix
//! doctor`). Every part is an `Option`: `None` is a reading this board
//! cannot make (a simulated device has no silicon revision, clock tree,
//! HSI48 trimming or camera interface), never "zero".

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// The board's own view of itself (PROTOCOL.md §5, `Health`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Health {
    /// The chip and its errata workarounds.
    pub silicon: Option<Silicon>,
    /// The system clock and core voltage, as configured and as read back.
    pub clocks: Option<Clocks>,
    /// The trimming of the USB kernel clock (HSI48 by the CRS).
    pub usb_clock: Option<UsbClockSync>,
    /// The main stack: size, deepest use so far, guard.
    pub stack: Option<StackUsage>,
    /// Fault counters of the camera interface and its DMA, since start.
    pub camera_interface: Option<CameraInterface>,
    /// Share of time the CPU slept (WFI) since the previous `Status`, in
    /// 1/1000.
    pub idle_permille: Option<u16>,
    /// What ended the run before the last reset, as the fault handler
    /// recorded it in memory that survives a reset (protocol 4).
    pub faults: Option<FaultLog>,
}

/// The board's record of a fault across a reset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct FaultLog {
    /// The fault that reset the board before this run (`None`: the last
    /// reset was not a fault this board records, e.g. power-on, the reset
    /// pin, or a watchdog reset after a hang).
    pub before_reset: Option<Fault>,
}

/// A fault, with the registers that say where and why (Cortex-M, ARMv7-M
/// ARM B3.2: the stacked PC and LR, and the fault status and address
/// registers as the handler found them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Fault {
    pub kind: FaultKind,
    /// The instruction that faulted (or was about to run, for an
    /// imprecise bus fault).
    pub pc: u32,
    /// The link register at the fault: the caller, usually.
    pub lr: u32,
    /// Configurable Fault Status Register (0xE000ED28): MemManage (bits
    /// 7:0), BusFault (15:8), UsageFault (31:16) causes.
    pub cfsr: u32,
    /// HardFault Status Register (0xE000ED2C): FORCED (bit 30) is a
    /// configurable fault escalated, VECTTBL (bit 1) a vector read.
    pub hfsr: u32,
    /// MemManage fault address (0xE000ED34); valid if CFSR.MMARVALID (bit 7).
    pub mmfar: u32,
    /// Bus fault address (0xE000ED38); valid if CFSR.BFARVALID (bit 15).
    pub bfar: u32,
}

/// What kind of fault a [`Fault`] was.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum FaultKind {
    /// The HardFault handler ran (every configurable fault escalates to
    /// it on these boards).
    HardFault,
}

/// The chip, as its debug unit identifies it (STM32: DBGMCU_IDCODE).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Silicon {
    /// DEV_ID (0x450: STM32H742/743/750/753).
    pub device_id: u16,
    /// REV_ID (STM32H743: 0x1003 revision Y, 0x2003 revision V).
    pub revision_id: u16,
    /// The AXI SRAM read erratum's workaround (STM32H743 rev Y).
    pub axi_sram_fix: ErratumFix,
}

/// Whether an erratum's workaround is in place.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum ErratumFix {
    /// This revision does not have the erratum.
    NotNeeded,
    /// Needed, applied and read back.
    Applied,
    /// Needed, but the register did not read back as written.
    Failed,
}

/// Clock and core voltage.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Clocks {
    /// System (CPU) clock the firmware asked for, Hz.
    pub sysclk_configured_hz: u32,
    /// System clock worked out from the clock registers as they are, Hz.
    pub sysclk_read_hz: u32,
    /// Voltage scale asked for (STM32H7: VOS 0-3; 1 is the highest without
    /// overdrive).
    pub voltage_scale_configured: u8,
    /// Voltage scale the regulator reports.
    pub voltage_scale_read: u8,
    /// The regulator reports its output ready at that scale.
    pub voltage_ready: bool,
}

/// REV_ID of the STM32H743's revision Y (DBGMCU_IDCODE bits 31:16).
pub const STM32H7_REV_Y: u16 = 0x1003;

/// CRS_CFGR.SYNCSRC that selects USB2 (OTG_FS) start-of-frame on an
/// STM32H7 of `revision_id`: revision Y and earlier encode the USB2 SOF as
/// 0b00 and the CRS_SYNC pin as 0b11, later revisions the other way round
/// (as ST's HAL_RCCEx_CRSConfig does).
pub const fn crs_sync_source_usb2(revision_id: u16) -> u8 {
    if revision_id <= STM32H7_REV_Y {
        0b00
    } else {
        0b11
    }
}

/// What CRS_CFGR.SYNCSRC = `code` selects on an STM32H7 of `revision_id`
/// (see [`crs_sync_source_usb2`]).
pub const fn crs_sync_source_name(code: u8, revision_id: u16) -> &'static str {
    let usb2 = crs_sync_source_usb2(revision_id);
    match code {
        1 => "LSE",
        2 => "USB1 (OTG_HS) SOF",
        c if c == usb2 => "USB2 (OTG_FS) SOF",
        0 | 3 => "CRS_SYNC pin",
        _ => "invalid",
    }
}

/// The USB clock's automatic trimming (STM32: the CRS trims HSI48 against
/// the USB start-of-frame every millisecond).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct UsbClockSync {
    /// Synchronisation source, CRS_CFGR.SYNCSRC as read back; its meaning
    /// depends on the silicon revision ([`crs_sync_source_name`]).
    pub sync_source: u8,
    /// A "synchronisation OK" event has been seen since start.
    pub synced: bool,
    /// The oscillator's trim now (HSI48: 6 bits, 32 is the middle).
    pub trim: u8,
    /// Synchronisation errors, misses and trim overflows since start.
    pub sync_errors: u32,
}

/// The main stack.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct StackUsage {
    /// Bytes reserved for it.
    pub size: u32,
    /// Most bytes used so far (the painted stack's high-water mark).
    pub peak: u32,
    /// An overflow faults (a guard region below the stack) instead of
    /// overwriting other data.
    pub guarded: bool,
}

/// Fault counters of the camera interface (STM32: DCMI and its DMA stream).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct CameraInterface {
    /// The interface's own FIFO overflowed: pixels lost before the DMA.
    pub overruns: u32,
    /// Synchronisation errors (embedded codes out of order).
    pub sync_errors: u32,
    /// DMA transfer and direct-mode errors (each stops the stream).
    pub dma_transfer_errors: u32,
    /// DMA FIFO errors (under- or overrun of the DMA's own FIFO).
    pub dma_fifo_errors: u32,
    /// Frame ends at which the interface's FIFO had not drained.
    pub fifo_not_drained: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crs_sync_source_by_revision() {
        // Revision Y (0x1003): USB2 SOF is 0b00; V (0x2003): 0b11.
        assert_eq!(crs_sync_source_usb2(0x1003), 0);
        assert_eq!(crs_sync_source_usb2(0x2003), 3);
        assert_eq!(crs_sync_source_name(0, 0x1003), "USB2 (OTG_FS) SOF");
        assert_eq!(crs_sync_source_name(3, 0x1003), "CRS_SYNC pin");
        assert_eq!(crs_sync_source_name(3, 0x2003), "USB2 (OTG_FS) SOF");
        assert_eq!(crs_sync_source_name(0, 0x2003), "CRS_SYNC pin");
        assert_eq!(crs_sync_source_name(2, 0x2003), "USB1 (OTG_HS) SOF");
    }
}
