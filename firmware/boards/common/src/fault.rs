//! A fault's registers, kept across the reset that follows it.
//!
//! A HardFault used to show only as a watchdog reset. Now the board's
//! HardFault handler calls [`record`], which writes the stacked PC and LR
//! and the fault status and address registers into a `.uninit` static
//! (cortex-m-rt neither zeroes nor loads it, and a reset does not clear
//! RAM), then resets; at the next boot [`take_at_boot`] moves a valid
//! record into [`before_reset`], which the board reports in
//! `Status.health.faults` (`brightpix doctor`'s `last fault` line).
//!
//! RAM holds garbage after power-on, so a record counts only with its magic
//! number and a checksum over the registers; it is cleared once read, so
//! each fault is reported for exactly one run.

use core::cell::Cell;
use core::mem::MaybeUninit;

use brightpix_protocol::wire::{Fault, FaultKind, FaultLog};
use critical_section::Mutex;

/// "BPFLT" and a version: a record written by this layout.
const MAGIC: u32 = 0xB9F1_7A01;

/// The record as stored: plain words, so any bit pattern is safe to read.
#[repr(C)]
#[derive(Clone, Copy)]
struct Stored {
    magic: u32,
    /// pc, lr, cfsr, hfsr, mmfar, bfar.
    registers: [u32; 6],
    check: u32,
}

fn checksum(registers: &[u32; 6]) -> u32 {
    // FNV-1a over the words: any damage from power-on noise shows.
    registers.iter().fold(0x811C_9DC5u32, |h, &w| {
        (h ^ w).wrapping_mul(0x0100_0193).rotate_left(5)
    })
}

#[link_section = ".uninit.brightpix_fault"]
static mut STORED: MaybeUninit<Stored> = MaybeUninit::uninit();

static BEFORE_RESET: Mutex<Cell<Option<Fault>>> = Mutex::new(Cell::new(None));

/// The System Control Block's fault registers (ARMv7-M B3.2.15-B3.2.19).
const CFSR: *const u32 = 0xE000_ED28 as *const u32;
const HFSR: *const u32 = 0xE000_ED2C as *const u32;
const MMFAR: *const u32 = 0xE000_ED34 as *const u32;
const BFAR: *const u32 = 0xE000_ED38 as *const u32;

/// Writes the fault's record (from the HardFault handler: `pc` and `lr`
/// from its exception frame). Touches nothing but the record and the SCB's
/// fault registers, so it works however broken the rest of the program is.
pub fn record(pc: u32, lr: u32) {
    // SAFETY: reads of the SCB fault registers (read-only here), and a
    // write of the record, which only this function (in the HardFault
    // handler, which does not nest) and `take_at_boot` (before interrupts
    // run) touch.
    unsafe {
        let registers = [
            pc,
            lr,
            CFSR.read_volatile(),
            HFSR.read_volatile(),
            MMFAR.read_volatile(),
            BFAR.read_volatile(),
        ];
        let stored = Stored {
            magic: MAGIC,
            registers,
            check: checksum(&registers),
        };
        core::ptr::addr_of_mut!(STORED).write_volatile(MaybeUninit::new(stored));
    }
    cortex_m::asm::dsb();
}

/// At boot, before any interrupt runs: takes the record the previous run
/// left, if there is a valid one, and clears it.
pub fn take_at_boot() {
    // SAFETY: the record is plain words (any bit pattern is a valid
    // `Stored`); nothing else runs yet.
    let stored = unsafe {
        let stored = core::ptr::addr_of!(STORED).read_volatile().assume_init();
        core::ptr::addr_of_mut!(STORED).write_volatile(MaybeUninit::new(Stored {
            magic: 0,
            registers: [0; 6],
            check: 0,
        }));
        stored
    };
    if stored.magic != MAGIC || stored.check != checksum(&stored.registers) {
        return;
    }
    let [pc, lr, cfsr, hfsr, mmfar, bfar] = stored.registers;
    let fault = Fault {
        kind: FaultKind::HardFault,
        pc,
        lr,
        cfsr,
        hfsr,
        mmfar,
        bfar,
    };
    critical_section::with(|cs| BEFORE_RESET.borrow(cs).set(Some(fault)));
}

/// The fault that ended the run before the last reset, if any.
pub fn before_reset() -> Option<Fault> {
    critical_section::with(|cs| BEFORE_RESET.borrow(cs).get())
}

/// For `Status.health.faults`.
pub fn log() -> FaultLog {
    FaultLog {
        before_reset: before_reset(),
    }
}
