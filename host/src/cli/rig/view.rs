//! `brightpix view --rig`: a rig's boards fed recorded frames over and
//! over, their merged results in the live view.

use std::path::Path;

use anyhow::{bail, Result};

use super::open_clients;
use crate::io::FrameSource;
use crate::link::Client;
use crate::rig::{self, Rig, RigStream};

/// `view --rig`: the rig's boards fed `frames` over and over (as `rig
/// stream` feeds them, batch by batch), their merged results into the
/// view, until `stop()`.
pub(in crate::cli) fn view_rig(
    rig_path: &Path,
    ports: &[String],
    frames: &Path,
    hdu: Option<&str>,
    hub: &crate::view::Hub,
    stop: &dyn Fn() -> bool,
) -> Result<()> {
    let rig = Rig::load(rig_path)?;
    let mut source = FrameSource::open_hdu(frames, hdu)?;
    source.set_camera(&rig.whole.camera)?;
    let total = source.len();
    if total == 0 {
        bail!("{} holds no frames", frames.display());
    }
    let mut clients = open_clients(&rig, ports)?;
    rig::configure(&rig, &mut clients)?;
    hub.set_setup(rig_view_setup(
        &rig,
        format!(
            "rig of {} boards, frames of {} over and over",
            rig.boards.len(),
            frames.display()
        ),
        rig_path.display().to_string(),
    ));
    let live = std::cell::RefCell::new(LiveBoards::new(&rig));
    let mut stream = RigStream::new(&rig, false);
    let mut on_frame = |m: &rig::MergedFrame| {
        live.borrow_mut().count(m);
        hub.offer(
            u64::from(m.frame),
            !m.missing_boards.is_empty(),
            || m.results.clone(),
            None,
        );
    };
    // Short batches: the view's health is read between two.
    const VIEW_BATCH: usize = 16;
    let mut next = 0u64;
    while !stop() {
        let first = (next % total as u64) as usize;
        let count = VIEW_BATCH.min(total - first);
        let mut batch = vec![Vec::new(); count];
        for (k, frame) in batch.iter_mut().enumerate() {
            source.read_frame_into(first + k, frame)?;
        }
        if hub.pixels_due() {
            hub.offer_pixels(next, batch[0].clone());
        }
        stream.run(&mut clients, &batch, next as u32, &mut on_frame);
        let health = live.borrow().health(&rig, &mut clients);
        let failed: Vec<String> = health
            .boards
            .iter()
            .filter_map(|b| b.error.as_ref().map(|e| format!("{}: {e}", b.name)))
            .collect();
        hub.set_message(
            (!failed.is_empty()).then(|| format!("boards not answering: {}", failed.join("; "))),
        );
        hub.set_health(health);
        next += count as u64;
    }
    stream.finish(&mut on_frame);
    Ok(())
}

/// Per board, for the view: frames merged with and without its results,
/// and its predicted load.
pub(super) struct LiveBoards {
    done: Vec<u64>,
    dropped: Vec<u64>,
    loads: Vec<Option<f64>>,
}

impl LiveBoards {
    pub(super) fn new(rig: &Rig) -> LiveBoards {
        let model = rig.cost_model();
        let loads = rig::loads(
            &rig.whole,
            &rig.shares(),
            rig.kind,
            &model,
            rig.camera_rate_hz,
            !rig.shared_rows().is_empty(),
        );
        LiveBoards {
            done: vec![0; rig.boards.len()],
            dropped: vec![0; rig.boards.len()],
            loads: loads.iter().map(|l| l.load).collect(),
        }
    }

    pub(super) fn count(&mut self, m: &rig::MergedFrame) {
        for b in 0..self.done.len() {
            if m.missing_boards.contains(&b) {
                self.dropped[b] += 1;
            } else {
                self.done[b] += 1;
            }
        }
    }

    /// The boards' counters summed, and each board's line.
    pub(super) fn health(&self, rig: &Rig, clients: &mut [Client]) -> crate::view::Health {
        let mut health = crate::view::Health::default();
        for (b, (board, client)) in rig.boards.iter().zip(clients.iter_mut()).enumerate() {
            let status = client.status();
            if let Ok(s) = &status {
                let add = |to: &mut Option<u64>, v: u64| *to = Some(to.unwrap_or(0) + v);
                add(&mut health.frames_processed, s.frames_processed);
                add(&mut health.frames_dropped, s.frames_dropped);
                let add32 =
                    |to: &mut Option<u32>, v: u32| *to = Some(to.unwrap_or(0).saturating_add(v));
                add32(&mut health.crc_errors, s.crc_errors);
                add32(&mut health.decode_errors, s.decode_errors);
                add32(&mut health.overruns, s.overruns);
                add32(&mut health.pixel_errors, s.pixel_errors);
            }
            health.boards.push(crate::view::BoardHealth {
                name: board.name.clone(),
                load: self.loads.get(b).copied().flatten(),
                frames_done: self.done[b],
                frames_dropped: self.dropped[b],
                error: status.err().map(|e| e.to_string()),
            });
        }
        // The whole camera's digest: each board runs its own part.
        health.config_digest = Some(brightpix_protocol::wire::tables::config_digest(
            &rig.whole.view(),
        ));
        health
    }
}

/// The live view's set-up for a rig: the whole camera, pixels shown, each
/// board's name and sub-apertures.
pub(super) fn rig_view_setup(rig: &Rig, title: String, source: String) -> crate::view::Setup {
    let mut setup = crate::view::Setup::new(title, source, rig.whole.clone());
    setup.pixels = true;
    setup.boards = rig
        .boards
        .iter()
        .map(|b| (b.name.clone(), b.windows.clone()))
        .collect();
    setup
}
