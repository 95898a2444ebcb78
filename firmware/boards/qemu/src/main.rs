//! brightpix on QEMU mps2-an386 (Cortex-M4F) or mps2-an500 (Cortex-M7):
//! the device.
//!
//! The board-independent device loop (`brightpix_firmware::device`) with
//! UART0 as the host link, speaking the brightpix protocol
//! (`shared/PROTOCOL.md`). Pixels arrive as `PixelRows` messages on UART0,
//! or, with `--pixels PATH` on the semihosting command line, also as
//! `PixelRows` frames in the host file or FIFO `PATH` (see `pixels.rs` for
//! how the semihosting reads share the CPU with the UART), or, with
//! `--camera DIR`, from the simulated camera (`camera.rs`: frames the host
//! generates, in the camera ring at the board's frame rate). defmt goes to
//! semihosting (QEMU's stdout). The contract with the host is in
//! firmware/boards/qemu/README.md, "Running the QEMU device"; the command line in
//! `args.rs`.
#![no_std]
#![no_main]

mod bench_request;
/// The QEMU bench's instruction meter (one source file for both binaries).
#[path = "bench/meter.rs"]
#[allow(dead_code)]
mod meter;
/// The counter trait the meter implements: here `brightpix-bench`'s own.
mod counter {
    pub use brightpix_bench::Counter;
}

use brightpix_board_common::{executor, fault, stack};
use brightpix_board_qemu::args::{Options, Selftest};
use brightpix_board_qemu::hostfs::{self, HostFile};
use brightpix_board_qemu::pixels::{BoardSource, HostPixels};
use brightpix_board_qemu::uart::{self, Uart0};
use brightpix_board_qemu::{board_name, camera, exit, exit_code, storage, time_driver};
use brightpix_firmware::device::{Device, LinkOnly, PixelRowsStream};
use cortex_m_rt::entry;
use embassy_executor::Spawner;
use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, Write};

/// The device task's type.
type BoardDevice = Device<'static, Uart0, BoardSource>;

/// End of transmission: the echo self-test exits QEMU when it receives it.
const EOT: u8 = 0x04;

#[entry]
fn main() -> ! {
    fault::take_at_boot();
    stack::paint();
    let mut cp = cortex_m::Peripherals::take().unwrap();
    stack::guard(&mut cp.MPU);
    time_driver::init(cp.SYST);
    defmt::info!("brightpix-qemu: {=str}", board_name());
    let options = Options::from_semihosting();
    if let Some(path) = &options.digest {
        digest(path);
    }
    brightpix_board_qemu::fault::reset_on_fault(options.reset_on_fault);
    if let Some(f) = fault::before_reset() {
        defmt::warn!(
            "reset by a HardFault: pc={=u32:#010x} lr={=u32:#010x} cfsr={=u32:#010x} hfsr={=u32:#010x}",
            f.pc,
            f.lr,
            f.cfsr,
            f.hfsr
        );
    }
    match options.selftest {
        Some(Selftest::Panic) => panic!("selftest"),
        Some(Selftest::Udf) => cortex_m::asm::udf(),
        Some(Selftest::FaultOnce) if fault::before_reset().is_none() => cortex_m::asm::udf(),
        Some(Selftest::FaultOnce) => {}
        Some(Selftest::Echo) => {
            let uart = Uart0::new().unwrap();
            executor::run(|spawner: Spawner| spawner.spawn(echo(uart).unwrap()))
        }
        None => {}
    }

    /// Frames per second of the simulated camera without `--camera-fps`.
    const CAMERA_FPS: u32 = 10;
    let source = match (&options.camera, &options.pixels) {
        (Some(_), _) => {
            if options.pixels.is_some() {
                defmt::warn!("pixels: --camera given: --pixels ignored");
            }
            BoardSource::Camera(camera::source())
        }
        (None, None) => BoardSource::Link(LinkOnly),
        (None, Some(path)) => {
            // For a FIFO, the open returns once the host has opened it for writing.
            defmt::info!("pixels: opening {=str}", path.as_str());
            match HostFile::open_str(path) {
                Ok(file) => {
                    defmt::info!(
                        "pixels: reading PixelRows frames from {=str}",
                        path.as_str()
                    );
                    let (frames, pixels) = storage::stream_buffers();
                    BoardSource::Stream(PixelRowsStream::new(HostPixels::new(file), frames, pixels))
                }
                Err(e) => {
                    defmt::error!(
                        "pixels: cannot open {=str} ({}): pixels on UART0 only",
                        path.as_str(),
                        defmt::Debug2Format(&e)
                    );
                    BoardSource::Link(LinkOnly)
                }
            }
        }
    };
    let uart = Uart0::new().unwrap();
    let mut device = Device::new(uart, source, storage::device_buffers(), board_name());
    device.set_health(brightpix_board_qemu::health);
    device.set_bench(bench_request::bench());
    let c = device.capabilities();
    defmt::info!(
        "device: {=u32} sub-apertures, maps of {=u32} pixels, {=u32} open windows, {=u32} pool entries, {=u32} results per row; buffers {=usize} bytes; pixel source {}",
        c.max_subapertures,
        c.max_camera_pixels,
        c.max_open_windows,
        c.pool_entries,
        c.max_results_per_row,
        storage::TOTAL_BYTES,
        defmt::Debug2Format(&c.pixel_source)
    );
    let camera = options
        .camera
        .map(|dir| (dir, options.camera_fps.unwrap_or(CAMERA_FPS)));
    if camera.is_some() {
        camera::RING.set_sync_line(options.camera_sync);
    }
    executor::run(|spawner: Spawner| {
        spawner.spawn(serve(device).unwrap());
        if let Some((dir, fps)) = camera {
            spawner.spawn(camera::feed(dir, fps).unwrap());
        }
    })
}

/// Runs the device for ever. UART0 cannot fail or close, so `run` returns
/// only if that changes; the device keeps its state across calls.
#[embassy_executor::task]
async fn serve(mut device: BoardDevice) {
    defmt::info!("device: serving UART0");
    loop {
        let e = device.run().await;
        defmt::warn!(
            "device: link ended ({}), serving again",
            defmt::Debug2Format(&e)
        );
    }
}

/// Board check: read a host file through semihosting, log length and hash.
fn digest(path: &str) {
    let mut chunk = [0u8; 512];
    match hostfs::digest(path, &mut chunk) {
        Ok((flen, len, hash)) => defmt::info!(
            "hostfs: {=str}: {=u64} bytes read (SYS_FLEN {=u64}), fnv1a32 {=u32:#010x}",
            path,
            len,
            flen,
            hash
        ),
        Err(e) => defmt::warn!("hostfs: {=str}: error {}", path, defmt::Debug2Format(&e)),
    }
}

/// Board check (`selftest=echo`): time a 10 ms timer, then echo every byte
/// received on UART0; exit QEMU (code 0) on EOT (0x04).
#[embassy_executor::task]
async fn echo(mut uart: Uart0) {
    let t0 = Instant::now();
    Timer::after_millis(10).await;
    defmt::info!("timer: 10 ms took {=u64} us", t0.elapsed().as_micros());
    defmt::info!("uart0: echo loop ready (send 0x04 to exit)");
    let mut buf = [0u8; 64];
    let mut total = 0usize;
    loop {
        let Ok(n) = uart.read(&mut buf).await;
        let data = &buf[..n];
        let (data, eot) = match data.iter().position(|&b| b == EOT) {
            Some(i) => (&data[..i], true),
            None => (data, false),
        };
        let Ok(()) = uart.write_all(data).await;
        total += data.len();
        if eot {
            let Ok(()) = uart.flush().await;
            defmt::info!(
                "uart0: EOT after {=usize} bytes echoed, {}; exiting",
                total,
                uart::stats()
            );
            exit(exit_code::OK);
        }
    }
}
