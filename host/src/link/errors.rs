//! How a call on the link fails: [`LinkError`], and [`Interrupted`] for a
//! call that keeps what it had received.

use std::fmt;
use std::io;
use std::time::Duration;

use brightpix_protocol::wire::{DeviceError, FrameFault, VersionMismatch};

use super::Reply;

/// Why a call failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// Not a `source` field: the reason is in the message, and a chained
    /// source would print it twice (`cannot open X: reason: reason`).
    #[error("cannot open {port}: {error}")]
    Open { port: String, error: io::Error },
    #[error("{0}")]
    Version(VersionMismatch),
    #[error(
        "{port} does not answer like a brightpix device: no HelloReply within {:.1} s \
         (is the device running, and is this its port?)",
        .waited.as_secs_f64()
    )]
    NoHello { port: String, waited: Duration },
    #[error("the device refused {request}: {error} [DeviceError::{error:?}]")]
    Device { request: String, error: DeviceError },
    #[error(
        "the device stopped answering: nothing from {port} for {timeout:?} while waiting for {waiting}"
    )]
    Timeout {
        port: String,
        timeout: Duration,
        waiting: String,
    },
    #[error(
        "{port} was armed on the sync line but its capture never began within {timeout:?}: it saw no rising edge (is the sync line wired to it, and did the leader start?)"
    )]
    NoSyncEdge { port: String, timeout: Duration },
    #[error("the device did not take data on {port} for {timeout:?} (writing {what})")]
    WriteStalled {
        port: String,
        timeout: Duration,
        what: String,
    },
    #[error("{port} closed or disappeared ({source})")]
    Disconnected { port: String, source: io::Error },
    #[error("unexpected reply to {request}: {reply}")]
    Unexpected { request: String, reply: String },
    #[error("pixel FIFO {path}: {source}")]
    Fifo { path: String, source: io::Error },
    #[error("frame {frame} was dropped by the device: {fault}")]
    FrameDropped { frame: u32, fault: FrameFault },
    #[error("{0}")]
    Usage(String),
    #[error("interrupted (SIGINT or SIGTERM)")]
    Interrupted,
}

/// A call that failed part-way, with everything it had received.
#[derive(Debug)]
pub struct Interrupted<T> {
    pub error: LinkError,
    pub received: T,
}

impl<T> fmt::Display for Interrupted<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.error.fmt(f)
    }
}

impl<T: fmt::Debug> std::error::Error for Interrupted<T> {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(&self.error)
    }
}

impl<T> From<Interrupted<T>> for LinkError {
    fn from(i: Interrupted<T>) -> Self {
        i.error
    }
}

/// A reply that is not the one `request` gets.
pub(super) fn unexpected(request: &str, reply: &Reply) -> LinkError {
    LinkError::Unexpected {
        request: request.to_string(),
        reply: format!("{reply:?}"),
    }
}
