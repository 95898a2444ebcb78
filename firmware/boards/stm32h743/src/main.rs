//! brightpix on the STM32H743ZI (e.g. NUCLEO-H743ZI): the production board.
//!
//! The board-independent device loop (`brightpix_firmware::device`) with
//! - the host link: USB OTG FS (PA11/PA12) as a CDC-ACM serial port
//!   ([`usb_link`]); on a disconnect the loop ends and is run again at the
//!   next connection, keeping its configuration and counters;
//! - the camera: the DCMI parallel interface in continuous mode, streamed by
//!   circular DMA into a ring in AXI SRAM ([`dcmi`]) and cut into pixel runs
//!   by `brightpix_firmware::camera::DcmiSource`;
//! - storage across DTCM, AXI SRAM and D2 SRAM ([`storage`]);
//! - the independent watchdog, fed by the device loop, and the reset
//!   reason, both in `Status` ([`watchdog`]);
//! - the board's health in `Status.health` ([`health`]): silicon revision
//!   and the AXI SRAM erratum fix, clocks and voltage scale read back, the
//!   HSI48 trimming (CRS from OTG_FS's SOF), the stack's high-water mark
//!   (painted, MPU-guarded: `brightpix_board_common::stack`), DCMI/DMA
//!   error counters, CPU idle time;
//! - 400 MHz from HSI via PLL1, I- and D-cache on; defmt over RTT (the
//!   embassy drivers' logs too);
//! - the bench request ([`bench`]): the engine and its floor in DWT cycles
//!   on the board's own workloads.
//!
//! NOT RUN ON HARDWARE: it builds; the camera source's logic is tested on
//! the host (`tests/tests/camera_*.rs`); see firmware/boards/stm32h743/README.md.
#![no_std]
#![no_main]

mod bench;
mod dcmi;
mod fault;
mod health;
mod storage;
mod sync;
mod usb_link;
mod watchdog;

use brightpix_board_common::{executor, stack};
use brightpix_firmware::camera::{DataWidth, DcmiSource};
use brightpix_firmware::device::Device;
use cortex_m_rt::entry;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_futures::join::join;
use embassy_futures::select::{select, Either};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::{bind_interrupts, interrupt, peripherals};
use embassy_time::{Instant, Timer};
use embassy_usb::class::cdc_acm::{CdcAcmClass, State};
use embassy_usb::Builder;
use panic_probe as _;

use crate::usb_link::{UsbLink, PACKET};

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
    DCMI => dcmi::DcmiInterrupt;
    DMA1_STREAM0 => dcmi::DmaInterrupt;
    EXTI9_5 => sync::LeaderInterrupt;
    EXTI15_10 => sync::FollowerInterrupt;
});

defmt::timestamp!("{=u64:us}", Instant::now().as_micros());

/// What the DCMI samples: 12 bits per pixel, one pixel per 16-bit halfword
/// (pins D0-D11). Change for an 8-, 10- or 14-bit camera.
const DATA_WIDTH: DataWidth = DataWidth::Bits12;

/// Reported to the host in `HelloReply`.
const BOARD: &str = "stm32h743-nucleo";

#[entry]
fn main() -> ! {
    // The record a HardFault left before the reset (`Status.health.faults`).
    brightpix_board_common::fault::take_at_boot();
    stack::paint();
    // Before anything reads the AXI SRAM (storage::take zeroes it).
    health::fix_axi_sram_erratum();
    // Storage next: AXI and D2 SRAM are zeroed before the D-cache is on.
    let memory = storage::take();
    let mut cp = cortex_m::Peripherals::take().unwrap();
    stack::guard(&mut cp.MPU);
    // The cycle counter, for the CPU's idle time (DWT_LAR unlock on M7).
    cp.DCB.enable_trace();
    cortex_m::peripheral::DWT::unlock();
    cp.DWT.enable_cycle_counter();
    cp.SCB.enable_icache();
    cp.SCB.enable_dcache(&mut cp.CPUID);
    executor::run(move |spawner: Spawner| spawner.spawn(device_task(memory).unwrap()))
}

fn clocks() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.csi = true;
    // USB kernel clock. Not `sync_from_usb`: embassy then trims HSI48 from
    // USB1's (OTG_HS) SOF; this board's USB is OTG_FS = USB2, whose SOF
    // `health::start_usb_clock_trimming` selects after init.
    config.rcc.hsi48 = Some(Hsi48Config {
        sync_from_usb: false,
    });
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI, // 64 MHz
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL50,
        fracn: None,
        divp: Some(PllDiv::DIV2), // 400 MHz
        divq: None,
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2; // 200 MHz (DCMI, DMA, AXI)
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale1; // health::VOLTAGE_SCALE
    config.rcc.mux.usbsel = mux::Usbsel::HSI48;
    // DMA interrupts (the DCMI ring's half events among them) at the top.
    config.dma_interrupt_priority = Priority::P0;
    config
}

type Memory = (
    &'static mut storage::AxiSram,
    &'static mut storage::D2Sram,
    &'static mut storage::Dtcm,
);

/// The device: USB, camera, device loop. Everything lives in this task's
/// (static) future, so the USB descriptor buffers can be borrowed for the
/// lifetime of the USB stack.
#[embassy_executor::task]
async fn device_task(memory: Memory) {
    let (axi, d2, dtcm) = memory;
    let reset = watchdog::reset_reason();
    let p = embassy_stm32::init(clocks());
    health::start_usb_clock_trimming();
    let h = health::health();
    defmt::info!(
        "brightpix-stm32h743: hello (reset: {}); {}",
        defmt::Debug2Format(&reset),
        defmt::Debug2Format(&h)
    );
    // From here on the device loop (or the wait for a host below) must run.
    let iwdg = watchdog::Iwdg::start(p.IWDG1);

    // --- USB CDC-ACM ---------------------------------------------------------
    let mut ep_out_buffer = [0u8; 256];
    let mut usb_config = usb::Config::default();
    // Feature `vbus-sensing` (Cargo.toml): only where VBUS is wired to PA9,
    // or enumeration never starts.
    usb_config.vbus_detection = cfg!(feature = "vbus-sensing");
    let driver = Driver::new_fs(
        p.USB_OTG_FS,
        Irqs,
        p.PA12,
        p.PA11,
        &mut ep_out_buffer,
        usb_config,
    );
    // Below the DMA (P0) and the camera (P1).
    interrupt::OTG_FS.set_priority(Priority::P2);

    // pid.codes test VID/PID; replace before shipping.
    let mut config = embassy_usb::Config::new(0x1209, 0x0001);
    config.manufacturer = Some("brightpix");
    config.product = Some("brightpix wavefront sensor");
    config.serial_number = Some("0001");
    config.max_packet_size_0 = 64;

    let mut config_descriptor = [0; 256];
    let mut bos_descriptor = [0; 256];
    let mut control_buf = [0; 64];
    let mut state = State::new();
    let mut builder = Builder::new(
        driver,
        config,
        &mut config_descriptor,
        &mut bos_descriptor,
        &mut [], // no MS OS descriptors
        &mut control_buf,
    );
    let class = CdcAcmClass::new(&mut builder, &mut state, PACKET as u16);
    let mut usb = builder.build();

    // --- the camera ------------------------------------------------------------
    let pins = dcmi::DcmiPins::new(
        p.PA6, p.PA4, p.PG9, p.PC6, p.PC7, p.PC8, p.PC9, p.PC11, p.PD3, p.PE5, p.PE6, p.PC10,
        p.PC12, p.PD6, p.PD2, p.PF11, p.PG15,
    );
    let ring = dcmi::DcmiRing::new(p.DCMI, p.DMA1_CH0, pins, &mut axi.ring, DATA_WIDTH);
    // PF13, the rig's sync line (`sync.rs`); taken so nothing else uses it.
    let _sync_pin = p.PF13;
    sync::init();
    let (device_memory, run_words, run_pixels) = dtcm.split();
    let camera = DcmiSource::new(ring, DATA_WIDTH, run_words, run_pixels);

    // --- the device loop ---------------------------------------------------------
    let mut bench = bench::Bench::new(bench::Cycles::new(), &mut axi.bench);
    let buffers = storage::device_buffers(&mut axi.background, &mut axi.engine, d2, device_memory);
    let mut device = Device::new(UsbLink::new(class), camera, buffers, BOARD).with_watchdog(iwdg);
    device.set_reset_reason(reset);
    device.set_health(health::health);
    // `brightpix bench --port`: DWT cycles on the board's own workloads.
    device.set_bench(&mut bench);
    let capabilities = device.capabilities();
    defmt::info!(
        "device: {=u32} sub-apertures, {=u32} camera pixels of maps, {=u32} open windows, {=u32} pool entries",
        capabilities.max_subapertures,
        capabilities.max_camera_pixels,
        capabilities.max_open_windows,
        capabilities.pool_entries
    );

    let serve = async {
        loop {
            // Fed while no host is connected, too.
            while let Either::Second(()) = select(
                device.link().wait_connection(),
                Timer::after_millis(watchdog::FEED_EVERY_MS),
            )
            .await
            {
                brightpix_firmware::device::Watchdog::feed(device.watchdog());
            }
            defmt::info!(
                "usb: connected; HSI48 {}",
                if health::usb_clock_synced() {
                    "synchronised to OTG_FS SOF by the CRS"
                } else {
                    "NOT YET synchronised (CRS SYNCOKF clear)"
                }
            );
            let Err(e) = device.run().await;
            let (overruns, sync_errors, dma_errors, fifo_errors, undrained) =
                dcmi::hardware_events();
            defmt::info!(
                "usb: link ended ({}); camera {}; DCMI overruns {=u32}, sync errors {=u32}, DMA errors {=u32}, DMA FIFO errors {=u32}, FIFOs not drained {=u32}",
                defmt::Debug2Format(&e),
                device.source().stats(),
                overruns,
                sync_errors,
                dma_errors,
                fifo_errors,
                undrained
            );
        }
    };
    join(usb.run(), serve).await;
}
