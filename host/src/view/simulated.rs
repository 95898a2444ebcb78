//! `view --simulate`: the firmware's device loop in-process, fed by the
//! host with the simulated camera's frames (a short loop of them, made
//! once) at a chosen rate, as `stream` feeds a device. Every frame's
//! pixels are at hand, so the page shows the camera and the selection.
//!
//! `drop_every K` makes every K-th frame carry one pixel above the
//! camera's bit depth, as a glitch on a camera link would: the device
//! drops that frame (SPEC.md §8), and the page shows the drops.

use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

use super::hub::{Health, Hub, Setup};
use crate::config_file::ProcessingConfig;
use crate::link::Client;
use crate::sim_device::{CameraFrames, InProcessDevice};

/// Distinct frames made for the loop (the simulator makes ~60 CANARY
/// frames a second on the loaded build machine, a few in a debug build).
pub const LOOP_FRAMES: usize = 16;

/// What to simulate.
pub struct Simulated {
    pub config: ProcessingConfig,
    pub config_name: String,
    pub seed: u64,
    /// Frames per second fed to the device.
    pub rate: f64,
    pub drop_every: Option<u32>,
}

/// Starts the device, configures it and feeds it until `stop()`.
pub fn run(sim: &Simulated, hub: &Hub, stop: &dyn Fn() -> bool) -> Result<()> {
    if !(sim.rate.is_finite() && sim.rate > 0.0) {
        bail!(
            "--rate {}: must be a positive number of frames per second",
            sim.rate
        );
    }
    let camera = sim.config.camera;
    if sim.drop_every.is_some() && camera.bit_depth >= 16 {
        bail!(
            "--drop-every needs a camera of fewer than 16 bits ({} has {}): a dropped frame is made with a pixel above the bit depth, which a 16-bit pixel cannot be",
            sim.config_name,
            camera.bit_depth
        );
    }
    let device = InProcessDevice::start_pty().context("starting an in-process device")?;
    let mut client = Client::open(device.port())?;
    client.configure(&sim.config.view())?;
    let mut setup = Setup::new(
        format!(
            "simulated device (in-process, {}, camera sim:{} at {} frames/s)",
            device.port(),
            sim.seed,
            sim.rate
        ),
        sim.config_name.clone(),
        sim.config.clone(),
    );
    setup.pixels = true;
    hub.set_setup(setup);
    hub.set_message(Some(format!(
        "making {LOOP_FRAMES} simulated frames to loop over…"
    )));
    let frames = CameraFrames::new(camera, sim.seed).frames(0, LOOP_FRAMES);
    hub.set_message(None);
    // Frames per `stream_frames` call (the status is read between calls):
    // about 50 calls a second, since the results of one call arrive
    // together and the view samples one of them.
    let batch_len = ((sim.rate / 50.0).round() as usize).clamp(1, 8);
    let n = sim.config.windows.len();
    let period = Duration::from_secs_f64(1.0 / sim.rate);
    let started = Instant::now();
    let mut next = 0u64;
    let mut last_status = Instant::now() - Duration::from_secs(1);
    while !stop() {
        let batch: Vec<Vec<u16>> = (next..next + batch_len as u64)
            .map(|k| {
                let mut f = frames[k as usize % frames.len()].clone();
                if sim
                    .drop_every
                    .is_some_and(|d| (k + 1) % u64::from(d.max(1)) == 0)
                {
                    f[0] = camera.max_raw() + 1;
                }
                f
            })
            .collect();
        let first = next as u32;
        client.stream_frames(first, &batch, |o| {
            let k = o.frame().wrapping_sub(first) as usize;
            super::offer_outcome(hub, &o, n, batch.get(k).map(Vec::as_slice));
        })?;
        next += batch_len as u64;
        if last_status.elapsed() >= Duration::from_millis(250) {
            hub.set_health(Health::from_status(&client.status()?));
            last_status = Instant::now();
        }
        // Paced: frame k goes at k periods from the start; a late batch
        // does not catch up by bursting.
        let due = started + period.mul_f64(next as f64);
        if let Some(rest) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(rest);
        }
    }
    drop(device);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};

    #[test]
    fn drops_every_kth_frame_and_counts_them() {
        let mut config = crate::sil::canary_config();
        config.camera.bit_depth = 12;
        let sim = Simulated {
            config,
            config_name: "canary (12-bit)".into(),
            seed: 1,
            rate: 2000.0,
            drop_every: Some(4),
        };
        let hub = Hub::new();
        let stop = AtomicBool::new(false);
        std::thread::scope(|s| {
            let runner = s.spawn(|| run(&sim, &hub, &|| stop.load(Ordering::Relaxed)));
            let deadline = Instant::now() + Duration::from_secs(120);
            while hub.frames_seen() < 40 && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(20));
            }
            stop.store(true, Ordering::Relaxed);
            runner.join().unwrap().unwrap();
        });
        let (seen, dropped) = (hub.frames_seen(), hub.frames_dropped());
        assert!(seen >= 40, "{seen} frames");
        // Whole batches of 8 (at 2000 frames/s), one in four dropped.
        assert_eq!(dropped, seen / 4, "{dropped} of {seen} dropped");
    }

    #[test]
    fn a_16_bit_camera_cannot_drop_on_demand() {
        let sim = Simulated {
            config: crate::sil::canary_config(),
            config_name: "canary".into(),
            seed: 1,
            rate: 100.0,
            drop_every: Some(4),
        };
        let error = run(&sim, &Hub::new(), &|| true).unwrap_err().to_string();
        assert!(error.contains("fewer than 16 bits"), "{error}");
    }
}
