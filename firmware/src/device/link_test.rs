//! The link test (PROTOCOL.md §15): fill bytes to the host as fast as the
//! link takes them, for the host to time. Nothing else changes: no engine,
//! table or counter is touched, and it needs no buffer (the fill is a
//! slice of a constant table, `wire::link_fill`).

use brightpix_protocol::wire::{
    link_fill, Ack, DeviceMessage, LinkTestFault, MAX_LINK_FILL, MAX_LINK_TEST_BYTES,
};
use embedded_io_async::{Read, Write};

use super::watchdog::Watchdog;
use super::{Core, LinkResult};

impl<T: Read + Write, W: Watchdog> Core<'_, T, W> {
    /// A link test's request, checked before anything is sent.
    pub(super) fn check_link_test(&self, bytes: u32, chunk: u16) -> Result<(), LinkTestFault> {
        if self.frame.is_some() || self.capture.is_some() {
            return Err(LinkTestFault::Streaming);
        }
        if bytes > MAX_LINK_TEST_BYTES {
            return Err(LinkTestFault::TooManyBytes {
                max: MAX_LINK_TEST_BYTES,
            });
        }
        if chunk == 0 || chunk > MAX_LINK_FILL {
            return Err(LinkTestFault::Chunk { max: MAX_LINK_FILL });
        }
        Ok(())
    }

    /// Sends a checked link test's `LinkFill` messages; its `Ack`.
    pub(super) async fn link_test(&mut self, bytes: u32, chunk: u16) -> LinkResult<Ack, T::Error> {
        let (mut offset, mut messages) = (0u32, 0u32);
        while offset < bytes {
            // Each message may wait on the host (`send` feeds the watchdog
            // meanwhile); 16 MiB is ~16 s on USB full speed.
            self.watchdog.feed();
            let len = (bytes - offset).min(chunk as u32);
            let fill = link_fill(offset, len as usize);
            self.send(&DeviceMessage::LinkFill { offset, fill }).await?;
            offset += len;
            messages += 1;
        }
        Ok(Ack::LinkTestDone { bytes, messages })
    }
}
