//! A configuration upload into the staging slot (PROTOCOL.md §7): begun with
//! its header, tables in chunks in order, committed against its digest.

use brightpix_protocol::wire::{
    tables, Ack, Background, CapacityKind, ConfigHeader, Crc32Digest, DeviceError, Table,
    TablePosition, CRC32, MAX_CHUNK_BYTES,
};
use embedded_io_async::{Read, Write};

use super::fmt::log_debug;
use super::{saturate, vet, ConfigSlot, Core, Watchdog};

/// A configuration upload in progress.
pub(super) struct Upload {
    pub(super) id: u32,
    header: ConfigHeader,
    /// Where the next chunk must start; `None` when all tables are complete.
    next: Option<TablePosition>,
    digest: Crc32Digest,
}

impl<T: Read + Write, W: Watchdog> Core<'_, T, W> {
    /// `crop`: the pixel source's verdict on the header's crop rectangle.
    pub(super) fn begin(
        &mut self,
        upload_id: u32,
        header: ConfigHeader,
        crop: Result<(), DeviceError>,
        staging: &mut ConfigSlot<'_>,
    ) -> Result<u32, DeviceError> {
        // A new upload always discards the one in progress, even if refused.
        self.upload = None;
        staging.header = None;
        vet::check_header(&header, &self.capabilities)?;
        crop?;
        // The digest covers the header too (PROTOCOL.md §7).
        let mut digest = CRC32.digest();
        let mut encoded = [0u8; ConfigHeader::MAX_ENCODED_LEN];
        digest.update(header.encode(&mut encoded));
        self.upload = Some(Upload {
            id: upload_id,
            header,
            next: header
                .next_table(0)
                .map(|table| TablePosition { table, offset: 0 }),
            digest,
        });
        log_debug!("device: upload {=u32} started", upload_id);
        Ok(upload_id)
    }

    /// The upload in progress, if `upload_id` is its id.
    pub(super) fn upload_for(&mut self, upload_id: u32) -> Result<&mut Upload, DeviceError> {
        match &mut self.upload {
            None => Err(DeviceError::NoUpload),
            Some(u) if u.id != upload_id => Err(DeviceError::UploadMismatch {
                expected: u.id,
                found: upload_id,
            }),
            Some(u) => Ok(u),
        }
    }

    pub(super) fn chunk(
        &mut self,
        upload_id: u32,
        table: Table,
        offset: u32,
        bytes: &[u8],
        staging: &mut ConfigSlot<'_>,
    ) -> Result<Ack, DeviceError> {
        let upload = self.upload_for(upload_id)?;
        let result = store_chunk(upload, table, offset, bytes, staging);
        if result.is_err() {
            // A chunk out of place means lost data: start again.
            self.upload = None;
        }
        result
    }

    pub(super) fn commit(
        &mut self,
        upload_id: u32,
        claimed: u32,
        staging: &mut ConfigSlot<'_>,
    ) -> Result<(), DeviceError> {
        self.upload_for(upload_id)?;
        let Some(upload) = self.upload.take() else {
            return Err(DeviceError::NoUpload);
        };
        let header = upload.header;
        if let Some(position) = upload.next {
            return Err(DeviceError::UploadIncomplete {
                table: position.table,
                received: position.offset,
                expected: header.table_len(position.table).map_or(0, saturate),
            });
        }
        let computed = upload.digest.finalize();
        if computed != claimed {
            return Err(DeviceError::UploadCrc { computed, claimed });
        }
        if let Background::Constant(value) = header.background {
            // A constant background arrives as one value: the engine reads a map.
            if let Some(map) = staging.background.get_mut(..header.camera.pixel_count()) {
                map.fill(value);
            }
        }
        let config = staging.config_with(&header).ok_or(DeviceError::Capacity {
            what: CapacityKind::Subapertures,
            needed: header.windows,
            available: self.capabilities.max_subapertures,
        })?;
        vet::check_config(&config, &self.capabilities, self.order, self.scratch)?;
        staging.header = Some(header);
        Ok(())
    }
}

/// Checks a chunk against the upload's position and stores its elements.
fn store_chunk(
    upload: &mut Upload,
    table: Table,
    offset: u32,
    bytes: &[u8],
    staging: &mut ConfigSlot<'_>,
) -> Result<Ack, DeviceError> {
    let found = TablePosition { table, offset };
    if upload.next != Some(found) {
        return Err(DeviceError::ChunkOutOfOrder {
            expected: upload.next,
            found,
        });
    }
    let size = table.element_size();
    let len = bytes.len();
    if len == 0 || len / size * size != len || len > MAX_CHUNK_BYTES {
        return Err(DeviceError::ChunkLength {
            table,
            len: saturate(len),
        });
    }
    let table_len = upload.header.table_len(table).unwrap_or(0);
    let end = offset as usize + len;
    if end > table_len {
        return Err(DeviceError::ChunkPastEnd {
            table,
            end: saturate(end),
            len: saturate(table_len),
        });
    }
    let first = offset as usize / size;
    let range = first..first + len / size;
    let stored = match table {
        Table::Windows => fill(staging.windows.get_mut(range), bytes, tables::read_window),
        Table::PixelCounts => fill(staging.pixel_counts.get_mut(range), bytes, |b| {
            u16::from_le_bytes([b[0], b[1]])
        }),
        Table::Background => fill(staging.background.get_mut(range), bytes, |b| {
            i32::from_le_bytes([b[0], b[1], b[2], b[3]])
        }),
        Table::Gain => fill(staging.gain.get_mut(range), bytes, |b| {
            u16::from_le_bytes([b[0], b[1]])
        }),
        Table::ReferenceSlopes => fill(
            staging.reference_slopes.get_mut(range),
            bytes,
            tables::read_reference_slope,
        ),
    };
    if !stored {
        // Capacity was checked at ConfigBegin; never here.
        return Err(DeviceError::ChunkPastEnd {
            table,
            end: saturate(end),
            len: saturate(table_len),
        });
    }
    upload.digest.update(bytes);
    upload.next = if end == table_len {
        upload
            .header
            .next_table(table.position() + 1)
            .map(|table| TablePosition { table, offset: 0 })
    } else {
        Some(TablePosition {
            table,
            offset: end as u32,
        })
    };
    Ok(Ack::ChunkStored {
        upload_id: upload.id,
        table,
        end: end as u32,
    })
}

fn fill<E>(target: Option<&mut [E]>, bytes: &[u8], read: impl Fn(&[u8]) -> E) -> bool {
    let Some(target) = target else {
        return false;
    };
    let size = bytes.len() / target.len().max(1);
    for (t, b) in target.iter_mut().zip(bytes.chunks_exact(size.max(1))) {
        *t = read(b);
    }
    true
}
