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

impl Reply {
    /// Whether this is a reply the device gives to a request of `kind`.
    /// An `Error` can answer any request.
    pub fn answers(&self, kind: MessageKind) -> bool {
        use MessageKind as K;
        match self {
            Reply::Error(_) => true,
            Reply::Hello(_) => kind == K::Hello,
            Reply::Status(_) => kind == K::StatusRequest,
            Reply::Bench(_) => kind == K::Bench,
            Reply::Ack(ack) => matches!(
                (kind, ack),
                (K::ConfigBegin, Ack::UploadStarted { .. })
                    | (K::ConfigChunk, Ack::ChunkStored { .. })
                    | (K::ConfigCommit, Ack::ConfigApplied { .. })
                    | (K::ConfigAbort, Ack::UploadAborted { .. })
                    | (K::ResetLevelFilters, Ack::LevelFiltersReset)
                    | (K::Capture, Ack::CaptureStarted { .. })
                    | (K::StopCapture, Ack::CaptureStopped { .. })
                    | (K::Bench, Ack::BenchDone { .. })
                    | (K::LinkTest, Ack::LinkTestDone { .. })
            ),
        }
    }
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
        // A reply that answers another kind of request is not ours: a late
        // answer to an earlier Hello (QEMU's pty, PROTOCOL.md §10), or the
        // answers to another program that writes to the port without its
        // lock. Taking it for ours would fail the request with a reply the
        // device never gave to it; the caller's own checks (the stream's
        // digest) find the other program. If nothing else comes, the
        // first one skipped is reported.
        let mut skipped = None;
        let waited = self.wait(&format!("the reply to {what}"), |c| {
            while let Some(reply) = c.replies.pop_front() {
                if reply.answers(kind) {
                    return Some(reply);
                }
                skipped.get_or_insert(reply);
            }
            None
        });
        let reply = match (waited, skipped) {
            (Err(LinkError::Timeout { .. }), Some(other)) => return Err(unexpected(&what, &other)),
            (waited, _) => waited?,
        };
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

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;
    use std::io::{self, Read, Write};

    use brightpix_protocol::wire::{
        decode, encode, Capabilities, DeviceMessage, HelloReply, PixelSourceKind, Status,
        MAX_FRAME_LEN,
    };

    use super::*;
    use crate::link::Port;

    /// What the scripted device says of itself in its `HelloReply`.
    fn scripted_capabilities() -> Capabilities<'static> {
        Capabilities {
            max_subapertures: 16,
            max_camera_pixels: 0,
            max_open_windows: 4,
            pool_entries: 64,
            history_pixels: 1024,
            scratch_entries: 64,
            max_results_per_row: 4,
            max_frame_bytes: MAX_FRAME_LEN as u32,
            pixel_source: PixelSourceKind::Link,
            board: "scripted",
        }
    }

    /// A device that answers Hello and StatusRequest, and puts `foreign`
    /// (another program's answer) before its reply to the first status.
    struct Scripted {
        written: Vec<u8>,
        to_host: VecDeque<u8>,
        foreign: Option<DeviceMessage<'static>>,
    }

    impl Scripted {
        fn send(&mut self, message: &DeviceMessage<'_>) {
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let n = encode(message, &mut buf).unwrap().len();
            self.to_host.extend(&buf[..n]);
        }

        fn answer(&mut self, mut frame: Vec<u8>) {
            match decode::<HostMessage>(&mut frame) {
                Ok(HostMessage::Hello { protocol, session }) => {
                    self.send(&DeviceMessage::HelloReply(HelloReply {
                        version: protocol.version,
                        schema: protocol.schema,
                        session,
                        capabilities: scripted_capabilities(),
                    }))
                }
                Ok(HostMessage::LinkTest { bytes, chunk }) => {
                    if let Some(foreign) = self.foreign.take() {
                        self.send(&foreign);
                    }
                    let mut messages = 0;
                    for offset in (0..bytes).step_by(chunk.into()) {
                        let len = (bytes - offset).min(chunk.into()) as usize;
                        let fill = brightpix_protocol::wire::link_fill(offset, len);
                        self.send(&DeviceMessage::LinkFill { offset, fill });
                        messages += 1;
                    }
                    self.send(&DeviceMessage::Ack(Ack::LinkTestDone { bytes, messages }));
                }
                Ok(HostMessage::StatusRequest) => {
                    if let Some(foreign) = self.foreign.take() {
                        self.send(&foreign);
                    }
                    self.send(&DeviceMessage::Status(Status {
                        config_id: Some(5),
                        ..Status::default()
                    }));
                }
                _ => {}
            }
        }
    }

    impl Read for Scripted {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            if self.to_host.is_empty() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            let n = buf.len().min(self.to_host.len());
            for (b, x) in buf.iter_mut().zip(self.to_host.drain(..n)) {
                *b = x;
            }
            Ok(n)
        }
    }

    impl Write for Scripted {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            for &b in buf {
                self.written.push(b);
                if b == 0 {
                    let frame = std::mem::take(&mut self.written);
                    if frame.len() > 1 {
                        self.answer(frame);
                    }
                }
            }
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl Port for Scripted {
        fn set_io_timeout(&mut self, _: Duration) -> io::Result<()> {
            Ok(())
        }
        fn describe(&self) -> String {
            "scripted".into()
        }
    }

    fn client(foreign: DeviceMessage<'static>) -> Client {
        let port = Scripted {
            written: Vec::new(),
            to_host: VecDeque::new(),
            foreign: Some(foreign),
        };
        Client::connect(Box::new(port)).unwrap()
    }

    /// Another program's upload answered mid-stream (issue 27 item 9: seen
    /// in CI as "unexpected reply to StatusRequest: Ack(ConfigApplied ..)"):
    /// the status request still gets the device's status.
    #[test]
    fn another_programs_acknowledgement_is_not_the_reply() {
        let applied = DeviceMessage::Ack(Ack::ConfigApplied {
            config_id: 77,
            open_windows: 2,
            pool_entries: 128,
        });
        let status = client(applied).status().unwrap();
        assert_eq!(status.config_id, Some(5));
    }

    /// A late answer to an earlier `Hello` (QEMU's pty, seen in CI as
    /// "unexpected reply to LinkTest: Hello(..)") before the fill is not the
    /// link test's reply: the test goes on to its `Ack`.
    #[test]
    fn a_late_hello_is_not_the_link_tests_reply() {
        let late = DeviceMessage::HelloReply(HelloReply {
            version: 8,
            schema: 1,
            session: 9,
            capabilities: scripted_capabilities(),
        });
        let mut c = client(late);
        let report = c.link_test(1_000, 300).unwrap();
        assert_eq!((report.bytes, report.messages), (1_000, 4));
    }

    /// An error can answer any request: it is not skipped.
    #[test]
    fn an_error_answers_any_request() {
        let error = DeviceMessage::Error(DeviceError::NoUpload);
        match client(error).status() {
            Err(LinkError::Device { error, .. }) => assert_eq!(error, DeviceError::NoUpload),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn each_acknowledgement_answers_its_request_only() {
        use MessageKind as K;
        let kinds = [
            K::Hello,
            K::ConfigBegin,
            K::ConfigChunk,
            K::ConfigCommit,
            K::ConfigAbort,
            K::StatusRequest,
            K::ResetLevelFilters,
            K::PixelRows,
            K::Capture,
            K::StopCapture,
            K::Bench,
            K::LinkTest,
        ];
        let acks = [
            (K::ConfigBegin, Ack::UploadStarted { upload_id: 1 }),
            (
                K::ConfigChunk,
                Ack::ChunkStored {
                    upload_id: 1,
                    table: brightpix_protocol::wire::Table::Windows,
                    end: 0,
                },
            ),
            (
                K::ConfigCommit,
                Ack::ConfigApplied {
                    config_id: 1,
                    open_windows: 1,
                    pool_entries: 1,
                },
            ),
            (K::ConfigAbort, Ack::UploadAborted { upload_id: None }),
            (K::ResetLevelFilters, Ack::LevelFiltersReset),
            (K::Capture, Ack::CaptureStarted { frames: 1 }),
            (K::StopCapture, Ack::CaptureStopped { frames: 1 }),
            (K::Bench, Ack::BenchDone { workloads: 1 }),
            (
                K::LinkTest,
                Ack::LinkTestDone {
                    bytes: 1,
                    messages: 1,
                },
            ),
        ];
        for (own, ack) in acks {
            for kind in kinds {
                assert_eq!(
                    Reply::Ack(ack).answers(kind),
                    kind == own,
                    "{ack:?} {kind:?}"
                );
            }
        }
        for kind in kinds {
            let status = Reply::Status(Status::default());
            assert_eq!(status.answers(kind), kind == K::StatusRequest);
        }
    }
}
