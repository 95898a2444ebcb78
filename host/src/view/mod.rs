//! `brightpix view`: a live page in the browser, served on loopback, of
//! what a device, a rig or a replay produces: slope arrows over the
//! sub-aperture grid, flux and N maps, the camera frame with each window's
//! selected pixels, chosen sub-apertures' slopes and the frame rate over
//! time, and the device's health.
//!
//! The data path knows nothing of the view: it calls [`Hub::offer`] (a
//! counter and, at most 60 times a second, a copy into a latest-value
//! slot) and goes on. The server's threads read the slots.
//!
//! | file | what |
//! |---|---|
//! | `hub.rs` | the latest-value slots between a data path and the server |
//! | `encode.rs` | the WebSocket messages (binary results and pixels, JSON setup and health) |
//! | `server.rs` | HTTP for the page's assets, a WebSocket per open page |
//! | `address.rs` | where to listen: loopback unless `--allow-remote` |
//! | `page.rs`, `page/` | the page (HTML, CSS, canvas JavaScript), built into the binary |
//! | `device.rs` | a device's own camera as a source (capture), with reconnection |
//! | `simulated.rs` | a simulated device fed by the host (stream), with drops on demand |
//! | `replay.rs` | recorded results (and frames) played back at a chosen rate |

pub mod address;
pub mod device;
pub mod encode;
pub mod hub;
mod page;
pub mod replay;
pub mod server;
pub mod simulated;

use std::sync::Arc;

pub use hub::{BoardHealth, Health, Hub, Setup};
pub use server::Server;

use crate::link::FrameOutcome;

/// Offers one frame's outcome to the view (see [`Hub::offer`]).
pub fn offer_outcome(
    hub: &Hub,
    outcome: &FrameOutcome,
    subapertures: usize,
    pixels: Option<&[u16]>,
) {
    hub.offer(
        u64::from(outcome.frame()),
        !matches!(outcome, FrameOutcome::Done(_)),
        || outcome.slopes().by_index(subapertures),
        pixels,
    );
}

/// A view opened beside another command's work (`--view`): its hub and
/// its server, which stops when this is dropped.
pub struct Attached {
    pub hub: Arc<Hub>,
    server: Server,
}

impl Attached {
    pub fn url(&self) -> String {
        self.server.url()
    }
}

/// Starts a view on `spec` (`PORT` or `ADDR:PORT`) for `--view`, and says
/// where on stderr.
pub fn attach(spec: &str, allow_remote: bool) -> anyhow::Result<Attached> {
    let addr = address::parse(spec)?;
    let listener = address::bind(addr, allow_remote)?;
    let hub = Hub::new();
    let server = Server::start(listener, hub.clone())?;
    eprintln!("brightpix: live view at {}", server.url());
    Ok(Attached { hub, server })
}
