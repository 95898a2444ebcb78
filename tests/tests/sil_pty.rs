//! Simulation in the loop, in-process: the firmware's device loop on a
//! thread, over a pseudo-terminal pair (`TTYPort::pair()`), driven through
//! the host tool's client (`brightpix::link`), every result checked bit for
//! bit against the reference.

use std::time::Instant;

use brightpix::link::Client;
use brightpix::sil::{canary_config, canary_frames, stream_and_verify};
use brightpix::sim_device::InProcessDevice;

#[test]
fn canary_default_spots() {
    let t = Instant::now();
    let frames = canary_frames(100, 1);
    eprintln!("frames: {:?}", t.elapsed());
    let device = InProcessDevice::start_pty().unwrap();
    let mut client = Client::open(device.port()).unwrap();
    let config = canary_config();
    let configured = client.configure(&config.view()).unwrap();
    eprintln!("configured: {configured:?}");
    let run = stream_and_verify(&mut client, &config.view(), &frames, 0, 10);
    assert!(run.error.is_none(), "{:?}", run.error);
    eprintln!(
        "{:?} {:.0} fps, verified {} mismatches {:?}",
        run.report,
        run.frames_per_second(),
        run.verifier.frames_verified,
        run.verifier.mismatches
    );
    assert!(run.verifier.all_match());
    assert_eq!(run.verifier.frames_verified, 100);
    eprintln!("{:?}", client.status().unwrap());
}
