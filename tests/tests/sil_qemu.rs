//! Simulation in the loop with the real firmware: the QEMU board's ELF in
//! `qemu-system-arm` (mps2-an386), UART0 on a pseudo-terminal, pixels
//! through a FIFO that the board reads by semihosting.

use std::time::Instant;

use brightpix::link::{Client, PixelSink};
use brightpix::sil::{canary_config, canary_frames, stream_and_verify};
use brightpix::sim_device::{QemuDevice, QemuOptions};

#[test]
fn qemu_canary_default_spots() {
    let frames = canary_frames(20, 1);
    let t = Instant::now();
    let device = QemuDevice::launch(QemuOptions {
        pixels_fifo: true,
        ..Default::default()
    })
    .unwrap();
    device
        .release_fifo(std::time::Duration::from_secs(5))
        .unwrap();
    eprintln!("launched {} in {:?}", device.port(), t.elapsed());
    let mut client = Client::open(device.port()).unwrap();
    eprintln!("connected {:?}: {}", t.elapsed(), client.info());
    let config = canary_config();
    let configured = client.configure(&config.view()).unwrap();
    eprintln!("configured: {configured:?}");
    client.set_pixel_sink(PixelSink::Fifo(device.pixels_fifo().unwrap().to_path_buf()));
    let run = stream_and_verify(&mut client, &config.view(), &frames, 0, 10);
    eprintln!(
        "{:?} {:.0} fps, verified {} mismatches {:?} err {:?}",
        run.report,
        run.frames_per_second(),
        run.verifier.frames_verified,
        run.verifier.mismatches,
        run.error
    );
    eprintln!("{:?}", client.status());
    assert!(run.error.is_none());
    assert!(run.verifier.all_match());
}
