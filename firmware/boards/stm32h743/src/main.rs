//! brightpix on the STM32H743ZI (e.g. NUCLEO-H743ZI): board bring-up.
//!
//! For now: 400 MHz from HSI via PLL1, USB OTG FS (PA11/PA12) as a CDC-ACM serial
//! port that echoes what it receives; defmt over RTT. The device loop and the
//! camera (DCMI) replace the echo later. NOT yet run on hardware.
#![no_std]
#![no_main]

use brightpix_board_common::executor;
use cortex_m_rt::entry;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_futures::join::join;
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::{bind_interrupts, peripherals};
use embassy_time::Instant;
use embassy_usb::class::cdc_acm::{CdcAcmClass, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::Builder;
use panic_probe as _;

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
});

defmt::timestamp!("{=u64:us}", Instant::now().as_micros());

/// Full-speed bulk endpoint size.
const MAX_PACKET: u16 = 64;

#[entry]
fn main() -> ! {
    executor::run(|spawner: Spawner| spawner.spawn(usb_echo().unwrap()))
}

fn clocks() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.csi = true;
    config.rcc.hsi48 = Some(Hsi48Config {
        sync_from_usb: true,
    }); // USB kernel clock
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
    config.rcc.ahb_pre = AHBPrescaler::DIV2; // 200 MHz
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale1;
    config.rcc.mux.usbsel = mux::Usbsel::HSI48;
    config
}

/// USB CDC-ACM echo. Everything lives in this task's (static) future, so the
/// descriptor buffers can be borrowed for the lifetime of the USB stack.
#[embassy_executor::task]
async fn usb_echo() {
    let p = embassy_stm32::init(clocks());
    defmt::info!("brightpix-stm32h743: hello");

    let mut ep_out_buffer = [0u8; 256];
    let mut usb_config = usb::Config::default();
    // NUCLEO-H743ZI: VBUS of the user USB connector is wired to PA9.
    usb_config.vbus_detection = true;
    let driver = Driver::new_fs(
        p.USB_OTG_FS,
        Irqs,
        p.PA12,
        p.PA11,
        &mut ep_out_buffer,
        usb_config,
    );

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
    let mut class = CdcAcmClass::new(&mut builder, &mut state, MAX_PACKET);
    let mut usb = builder.build();

    let echo = async {
        loop {
            class.wait_connection().await;
            defmt::info!("usb: connected");
            let _ = echo(&mut class).await;
            defmt::info!("usb: disconnected");
        }
    };
    join(usb.run(), echo).await;
}

struct Disconnected;

impl From<EndpointError> for Disconnected {
    fn from(e: EndpointError) -> Self {
        match e {
            EndpointError::BufferOverflow => defmt::panic!("usb: buffer overflow"),
            EndpointError::Disabled => Disconnected,
        }
    }
}

async fn echo<'d>(
    class: &mut CdcAcmClass<'d, Driver<'d, peripherals::USB_OTG_FS>>,
) -> Result<(), Disconnected> {
    let mut buf = [0; MAX_PACKET as usize];
    loop {
        let n = class.read_packet(&mut buf).await?;
        class.write_packet(&buf[..n]).await?;
    }
}
