//! What the board reads about itself for `Status.health` (`brightpix
//! doctor`), and the start-up fixes those readings check: the AXI SRAM
//! erratum of revision Y silicon and the HSI48 trimming for USB.
//!
//! Register level with the addresses and bits of RM0433 (rev 8) and
//! ES0392 cited at each use, so a reviewer can check them against the
//! documents without knowing embassy's PAC.
//!
//! NOT RUN ON HARDWARE: built only (see firmware/boards/stm32h743/README.md, "Bring-up").

use core::cell::Cell;

use brightpix_protocol::wire::{
    crs_sync_source_usb2, CameraInterface, Clocks, ErratumFix, Health, Silicon, StackUsage,
    UsbClockSync,
};
use cortex_m::interrupt::Mutex;

/// The CPU clock `main::clocks` asks for.
pub const SYSCLK_HZ: u32 = 400_000_000;
/// The voltage scale it asks for (VOS1: up to 400 MHz on rev Y and V).
pub const VOLTAGE_SCALE: u8 = 1;

fn read(address: usize) -> u32 {
    // SAFETY: called only with the documented register addresses below.
    unsafe { (address as *const u32).read_volatile() }
}

fn write(address: usize, value: u32) {
    // SAFETY: called only with the documented register addresses below.
    unsafe { (address as *mut u32).write_volatile(value) }
}

// --- silicon and the AXI SRAM erratum ------------------------------------------

/// DBGMCU_IDCODE (RM0433, DBGMCU): REV_ID bits 31:16, DEV_ID bits 11:0.
const DBGMCU_IDCODE: usize = 0x5C00_1000;
/// AXI interconnect (GPV at 0x5100_0000) AXI_TARG7_FN_MOD: target 7 is
/// the AXI SRAM; bit 0 READ_ISS_OVERRIDE (RM0433, AXI interconnect
/// registers; ES0392 gives the address).
const AXI_TARG7_FN_MOD: usize = 0x5100_8108;
const READ_ISS_OVERRIDE: u32 = 1 << 0;
/// REV_ID of revision Y; revisions before V (0x2003) have the erratum.
const REV_V: u16 = 0x2003;

static SILICON: Mutex<Cell<Option<Silicon>>> = Mutex::new(Cell::new(None));

/// ES0392 "Reading from AXI SRAM may lead to data read corruption"
/// (revision Y, REV_ID 0x1003, and earlier): the workaround is to set
/// READ_ISS_OVERRIDE so the AXI SRAM takes one read at a time. Call before
/// anything reads the AXI SRAM (`storage::take` zeroes it).
pub fn fix_axi_sram_erratum() {
    let idcode = read(DBGMCU_IDCODE);
    let revision_id = (idcode >> 16) as u16;
    let device_id = (idcode & 0xFFF) as u16;
    let axi_sram_fix = if revision_id >= REV_V {
        ErratumFix::NotNeeded
    } else {
        write(AXI_TARG7_FN_MOD, READ_ISS_OVERRIDE);
        cortex_m::asm::dsb();
        if read(AXI_TARG7_FN_MOD) & READ_ISS_OVERRIDE != 0 {
            ErratumFix::Applied
        } else {
            ErratumFix::Failed
        }
    };
    let silicon = Silicon {
        device_id,
        revision_id,
        axi_sram_fix,
    };
    cortex_m::interrupt::free(|cs| SILICON.borrow(cs).set(Some(silicon)));
}

// --- clocks -------------------------------------------------------------------

/// RCC (base 0x5802_4400; RM0433, RCC registers).
const RCC_CR: usize = 0x5802_4400; // HSIDIV bits 4:3
const RCC_CFGR: usize = 0x5802_4410; // SWS bits 5:3 (0 HSI, 1 CSI, 2 HSE, 3 PLL1)
const RCC_D1CFGR: usize = 0x5802_4418; // D1CPRE bits 11:8
const RCC_PLLCKSELR: usize = 0x5802_4428; // PLLSRC bits 1:0, DIVM1 bits 9:4
const RCC_PLLCFGR: usize = 0x5802_442C; // PLL1FRACEN bit 0
const RCC_PLL1DIVR: usize = 0x5802_4430; // DIVN1 bits 8:0 (N-1), DIVP1 bits 15:9 (P-1)
const RCC_PLL1FRACR: usize = 0x5802_4434; // FRACN1 bits 15:3
/// PWR_D3CR (base 0x5802_4800 + 0x18): VOS bits 15:14 (1 scale 3, 2 scale 2, 3
/// scale 1), VOSRDY bit 13.
const PWR_D3CR: usize = 0x5802_4818;
/// SYSCFG_PWRCR (0x5800_0400 + 0x2C): ODEN bit 0 (VOS 3 + ODEN = scale 0).
const SYSCFG_PWRCR: usize = 0x5800_042C;

const RCC_APB1HENR: usize = 0x5802_44EC;

const HSI_HZ: u64 = 64_000_000;
const CSI_HZ: u64 = 4_000_000;

/// The CPU clock worked out from the RCC registers as they are (0 for an
/// HSE source: the board has none configured).
pub fn cpu_clock_read_hz() -> u32 {
    let hsi = HSI_HZ >> ((read(RCC_CR) >> 3) & 0b11);
    let sys = match (read(RCC_CFGR) >> 3) & 0b111 {
        0 => hsi,
        1 => CSI_HZ,
        3 => {
            let sel = read(RCC_PLLCKSELR);
            let reference = match sel & 0b11 {
                0 => hsi,
                1 => CSI_HZ,
                _ => 0,
            };
            let m = u64::from((sel >> 4) & 0x3F);
            let div = read(RCC_PLL1DIVR);
            let n = u64::from(div & 0x1FF) + 1;
            let p = u64::from((div >> 9) & 0x7F) + 1;
            let frac = if read(RCC_PLLCFGR) & 1 != 0 {
                u64::from((read(RCC_PLL1FRACR) >> 3) & 0x1FFF)
            } else {
                0
            };
            // VCO = ref / M * (N + FRACN / 2^13), in 1/8192 Hz steps; M = 0
            // is "prescaler disabled".
            (reference * (n * 8192 + frac))
                .checked_div(m)
                .map_or(0, |vco| vco / p / 8192)
        }
        _ => 0,
    };
    let d1cpre = (read(RCC_D1CFGR) >> 8) & 0xF;
    let shift = match d1cpre {
        0..=7 => 0,
        8..=11 => d1cpre - 7, // /2, /4, /8, /16
        _ => d1cpre - 6,      // /64 .. /512
    };
    (sys >> shift) as u32
}

fn clocks() -> Clocks {
    let d3cr = read(PWR_D3CR);
    let vos = (d3cr >> 14) & 0b11;
    let scale = match vos {
        3 if read(SYSCFG_PWRCR) & 1 != 0 => 0,
        0 => 0xFF, // reserved
        v => 4 - v as u8,
    };
    Clocks {
        sysclk_configured_hz: SYSCLK_HZ,
        sysclk_read_hz: cpu_clock_read_hz(),
        voltage_scale_configured: VOLTAGE_SCALE,
        voltage_scale_read: scale,
        voltage_ready: d3cr & (1 << 13) != 0,
    }
}

// --- HSI48 trimming by the CRS ---------------------------------------------------

/// CRS (base 0x4000_8400; RM0433, CRS registers).
const CRS_CR: usize = 0x4000_8400; // CEN bit 5, AUTOTRIMEN bit 6, TRIM bits 13:8
const CRS_CFGR: usize = 0x4000_8404; // RELOAD 15:0, FELIM 23:16, SYNCDIV 26:24, SYNCSRC 29:28
const CRS_ISR: usize = 0x4000_8408; // SYNCOKF 0, ERRF 2, SYNCERR 8, SYNCMISS 9, TRIMOVF 10
const CRS_ICR: usize = 0x4000_840C; // SYNCOKC 0, SYNCWARNC 1, ERRC 2, ESYNCC 3
/// RELOAD = 48 MHz / 1 kHz SOF - 1, FELIM 34: the reset values, meant for
/// USB SOF.
const RELOAD: u32 = 47_999;
const FELIM: u32 = 34;

/// (a SYNC OK event seen since start, errors counted since start).
static CRS: Mutex<Cell<(bool, u32)>> = Mutex::new(Cell::new((false, 0)));

/// Starts the CRS trimming HSI48 from OTG_FS's start-of-frame (every 1 ms
/// once the host has configured the device). Turns the CRS's clock on
/// (RCC_APB1HENR 0x5802_44EC, CRSEN bit 1); CFGR is written while CEN = 0
/// (CRS_CFGR is read-only while the counter runs).
pub fn start_usb_clock_trimming() {
    write(RCC_APB1HENR, read(RCC_APB1HENR) | (1 << 1));
    cortex_m::asm::dsb();
    write(CRS_CR, read(CRS_CR) & !((1 << 5) | (1 << 6)));
    // USB2 (OTG_FS, the NUCLEO's user USB) start-of-frame, whose SYNCSRC
    // code depends on the revision (0b10, USB1 = OTG_HS, is what embassy's
    // `sync_from_usb` selects).
    let revision_id = (read(DBGMCU_IDCODE) >> 16) as u16;
    let source = crs_sync_source_usb2(revision_id);
    write(CRS_CFGR, (u32::from(source) << 28) | (FELIM << 16) | RELOAD);
    write(CRS_ICR, 0b1111);
    write(CRS_CR, read(CRS_CR) | (1 << 6) | (1 << 5));
}

/// Reads and clears the CRS flags: SYNCOKF since the last call makes
/// `synced` (sticky), errors are counted.
fn usb_clock() -> UsbClockSync {
    let isr = read(CRS_ISR);
    write(CRS_ICR, 0b1111);
    // SYNCERR, SYNCMISS, TRIMOVF (each also sets ERRF).
    let errors = [8, 9, 10]
        .iter()
        .filter(|&&bit| isr & (1 << bit) != 0)
        .count() as u32;
    let (synced, total) = cortex_m::interrupt::free(|cs| {
        let cell = CRS.borrow(cs);
        let (synced, total) = cell.get();
        let now = (synced || isr & 1 != 0, total.saturating_add(errors));
        cell.set(now);
        now
    });
    UsbClockSync {
        sync_source: ((read(CRS_CFGR) >> 28) & 0b11) as u8,
        synced,
        trim: ((read(CRS_CR) >> 8) & 0x3F) as u8,
        sync_errors: total,
    }
}

/// Whether the CRS has locked to the SOF since start (for the log).
pub fn usb_clock_synced() -> bool {
    usb_clock().synced
}

// --- CPU idle time ----------------------------------------------------------------

/// (time in µs, idle cycles) at the previous `Status`.
static IDLE_MARK: Mutex<Cell<(u64, u64)>> = Mutex::new(Cell::new((0, 0)));

fn idle_permille() -> u16 {
    let now_us = embassy_time::Instant::now().as_micros();
    let idle = brightpix_board_common::executor::idle_cycles();
    let (then_us, idle_then) =
        cortex_m::interrupt::free(|cs| IDLE_MARK.borrow(cs).replace((now_us, idle)));
    let elapsed_cycles = (now_us - then_us) * u64::from(SYSCLK_HZ / 1_000_000);
    if elapsed_cycles == 0 {
        return 1000;
    }
    ((idle - idle_then) * 1000 / elapsed_cycles).min(1000) as u16
}

// --- everything ------------------------------------------------------------------

/// `Status.health` of this board (`Device::set_health`).
pub fn health() -> Health {
    let (overruns, sync_errors, dma_transfer_errors, dma_fifo_errors, fifo_not_drained) =
        crate::dcmi::hardware_events();
    let stack: StackUsage = brightpix_board_common::stack::usage();
    Health {
        silicon: cortex_m::interrupt::free(|cs| SILICON.borrow(cs).get()),
        clocks: Some(clocks()),
        usb_clock: Some(usb_clock()),
        stack: Some(stack),
        camera_interface: Some(CameraInterface {
            overruns,
            sync_errors,
            dma_transfer_errors,
            dma_fifo_errors,
            fifo_not_drained,
        }),
        idle_permille: Some(idle_permille()),
        faults: Some(brightpix_board_common::fault::log()),
    }
}
