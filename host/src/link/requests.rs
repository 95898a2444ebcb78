//! Requests that get exactly one reply: status, the configuration upload
//! (chunked, committed atomically), level-filter reset, upload abort; and
//! the raw request of tests that damage a frame on purpose.

use std::time::{Duration, Instant};

use brightpix_protocol::wire::{
    Ack, DeviceError, HostMessage, MessageKind, Status, UploadPlan, MAX_CHUNK_BYTES,
};
use brightpix_protocol::Config;

use super::errors::unexpected;
use super::{fresh_id, Client, DeviceInfo, LinkError};

/// A successful configuration upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Configured {
    /// The device's id of the configuration now active (the upload id).
    pub config_id: u32,
    pub open_windows: u32,
    pub pool_entries: u32,
    /// Messages and table bytes sent.
    pub messages: usize,
    pub table_bytes: usize,
    pub elapsed: Duration,
}

/// A reply to a request. [`Client::request`] returns an `Error` reply as
/// [`LinkError::Device`], so it never returns `Reply::Error`.
#[derive(Clone, Debug)]
pub enum Reply {
    Hello(DeviceInfo),
    Ack(Ack),
    Error(DeviceError),
    Status(Status),
    /// One workload of a `Bench` request.
    Bench(super::bench::BenchRow),
}

impl Client {
    /// `StatusRequest`: the device's counters.
    pub fn status(&mut self) -> Result<Status, LinkError> {
        match self.request(&HostMessage::StatusRequest)? {
            Reply::Status(s) => Ok(s),
            other => Err(unexpected("StatusRequest", &other)),
        }
    }

    /// Uploads `config` (ConfigBegin, chunks, ConfigCommit; one reply each)
    /// under a fresh upload id. On any error the device keeps its previous
    /// configuration.
    pub fn configure(&mut self, config: &Config<'_>) -> Result<Configured, LinkError> {
        let started = Instant::now();
        let upload_id = self.fresh_upload_id();
        let chunk = MAX_CHUNK_BYTES.min((self.info.max_frame_bytes as usize).saturating_sub(64));
        let mut plan = UploadPlan::new(*config, upload_id, chunk);
        let total = plan.message_count();
        let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
        let mut messages = 0;
        let mut table_bytes = 0;
        while let Some(message) = plan.next(&mut scratch) {
            messages += 1;
            let what = describe_upload_message(&message, messages, total);
            if let HostMessage::ConfigChunk { bytes, .. } = &message {
                table_bytes += bytes.len();
            }
            let reply = self.request(&message).map_err(|e| match e {
                LinkError::Device { error, .. } => LinkError::Device {
                    request: format!("the configuration upload at {what}"),
                    error,
                },
                other => other,
            })?;
            match (&message, reply) {
                (
                    HostMessage::ConfigBegin { .. },
                    Reply::Ack(Ack::UploadStarted { upload_id: id }),
                )
                | (
                    HostMessage::ConfigChunk { .. },
                    Reply::Ack(Ack::ChunkStored { upload_id: id, .. }),
                ) if id == upload_id => {}
                (
                    HostMessage::ConfigCommit { .. },
                    Reply::Ack(Ack::ConfigApplied {
                        config_id,
                        open_windows,
                        pool_entries,
                    }),
                ) if config_id == upload_id => {
                    // The device dropped any frame in progress: results of
                    // earlier frames can no longer complete.
                    self.stale_outcomes += (self.open_frames.len() + self.finished.len()) as u64;
                    self.open_frames.clear();
                    self.finished.clear();
                    self.camera = Some(config.camera);
                    self.subapertures = config.windows.len();
                    return Ok(Configured {
                        config_id,
                        open_windows,
                        pool_entries,
                        messages,
                        table_bytes,
                        elapsed: started.elapsed(),
                    });
                }
                (_, other) => return Err(unexpected(&what, &other)),
            }
        }
        Err(LinkError::Usage(
            "the upload plan ended without a commit".into(),
        ))
    }

    /// Tells the client the device's active configuration without
    /// uploading it (e.g. for streaming to a device configured earlier).
    pub fn assume_configured(&mut self, config: &Config<'_>) {
        self.camera = Some(config.camera);
        self.subapertures = config.windows.len();
    }

    fn fresh_upload_id(&mut self) -> u32 {
        self.upload_counter = self.upload_counter.wrapping_add(1);
        fresh_id(self.upload_counter)
    }

    /// `ResetLevelFilters`.
    pub fn reset_level_filters(&mut self) -> Result<(), LinkError> {
        self.expect_ack(&HostMessage::ResetLevelFilters, "ResetLevelFilters")
            .map(|_| ())
    }

    /// `ConfigAbort`: discards an upload in progress; returns its id.
    pub fn abort_upload(&mut self) -> Result<Option<u32>, LinkError> {
        match self.expect_ack(&HostMessage::ConfigAbort, "ConfigAbort")? {
            Ack::UploadAborted { upload_id } => Ok(upload_id),
            other => Err(unexpected("ConfigAbort", &Reply::Ack(other))),
        }
    }

    fn expect_ack(&mut self, message: &HostMessage<'_>, what: &str) -> Result<Ack, LinkError> {
        match self.request(message)? {
            Reply::Ack(a) => Ok(a),
            other => Err(unexpected(what, &other)),
        }
    }

    /// Sends one request and waits for its reply (results of frames that
    /// arrive meanwhile are kept for [`Client::next_outcome`]). An `Error`
    /// reply becomes [`LinkError::Device`].
    pub fn request(&mut self, message: &HostMessage<'_>) -> Result<Reply, LinkError> {
        let kind = message.kind();
        let frame = self.encode(message)?.to_vec();
        self.request_raw(&frame, kind)
    }

    /// Sends `frame` (an encoded message, perhaps deliberately damaged) and
    /// waits for the reply that a request of `kind` gets.
    pub fn request_raw(&mut self, frame: &[u8], kind: MessageKind) -> Result<Reply, LinkError> {
        // Anything still queued is unrequested.
        self.move_replies_to_notices();
        self.close_pixel_fifo();
        let what = format!("{kind:?}");
        self.write_raw(frame, &what)?;
        let reply = self.wait(&format!("the reply to {what}"), |c| {
            while let Some(reply) = c.replies.pop_front() {
                match (&reply, kind) {
                    (Reply::Hello(_), MessageKind::Hello) => return Some(reply),
                    (Reply::Hello(_), _) => {} // late answer to an earlier Hello
                    _ => return Some(reply),
                }
            }
            None
        })?;
        match reply {
            Reply::Error(error) => Err(LinkError::Device {
                request: what,
                error,
            }),
            other => Ok(other),
        }
    }

    pub(super) fn move_replies_to_notices(&mut self) {
        while let Some(r) = self.replies.pop_front() {
            if let Reply::Error(e) = r {
                self.notices.push(e);
            }
        }
    }
}

fn describe_upload_message(message: &HostMessage<'_>, k: usize, total: usize) -> String {
    match message {
        HostMessage::ConfigChunk {
            table,
            offset,
            bytes,
            ..
        } => format!(
            "ConfigChunk {k} of {total} ({table} table, bytes {offset}..{})",
            *offset as usize + bytes.len()
        ),
        other => format!("{:?} (message {k} of {total})", other.kind()),
    }
}
