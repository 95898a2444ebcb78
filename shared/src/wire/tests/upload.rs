//! Tables and the upload plan; the pixel rows plan.

use super::*;

struct Owned {
    windows: Vec<SubapertureWindow>,
    counts: Vec<u16>,
    background: Vec<i32>,
    gain: Vec<u16>,
    references: Vec<[i32; 2]>,
}

impl Owned {
    fn new() -> Self {
        let windows: Vec<_> = (0..50u16)
            .map(|k| SubapertureWindow {
                x: (k % 10) * 6,
                y: (k / 10) * 6,
                width: 6,
                height: 6,
            })
            .collect();
        Owned {
            counts: (0..50).map(|k| 1 + k % 7).collect(),
            background: (0..60 * 30).map(|k| k * 37 - 20_000).collect(),
            gain: (0..60 * 30).map(|k| (k * 13 % 65536) as u16).collect(),
            references: (0..50).map(|k| [k * 1000 - 7, -k * 999]).collect(),
            windows,
        }
    }
    fn config(&self) -> Config<'_> {
        Config {
            camera: Camera {
                width: 60,
                height: 30,
                bit_depth: 12,
            },
            windows: &self.windows,
            calibration: Calibration {
                background: Some(&self.background),
                gain: Some(&self.gain),
                threshold: Some(-5),
            },
            selection: Selection {
                rule: SelectionRule::SubtractNextDistinct,
                count: PixelCount::PerSubaperture(&self.counts),
                level_filter: Some(LevelFilter { gain_shift: 3 }),
            },
            centroid: Centroid {
                reference_slopes: Some(&self.references),
                min_flux: 12,
            },
            crop: None,
        }
    }
}

#[test]
fn upload_plan_rebuilds_the_configuration() {
    let owned = Owned::new();
    let config = owned.config();
    for chunk in [8, 100, 960, 5000] {
        let mut plan = UploadPlan::new(config, 77, chunk);
        let expected_count = plan.message_count();
        let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
        let mut header = None;
        let mut tables: [Vec<u8>; 5] = Default::default();
        let mut commit = None;
        let mut count = 0;
        let mut last = (0usize, 0u32);
        while let Some(message) = plan.next(&mut scratch) {
            count += 1;
            // Through the wire and back.
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let len = encode(&message, &mut buf).unwrap().len() - 1;
            match decode::<HostMessage>(&mut buf[..len]).unwrap() {
                HostMessage::ConfigBegin {
                    upload_id,
                    header: h,
                } => {
                    assert_eq!(upload_id, 77);
                    header = Some(h);
                }
                HostMessage::ConfigChunk {
                    upload_id,
                    table,
                    offset,
                    bytes,
                } => {
                    assert_eq!(upload_id, 77);
                    assert!(bytes.len() <= MAX_CHUNK_BYTES);
                    assert_eq!(bytes.len() % table.element_size(), 0);
                    assert!((table.position(), offset) >= last, "chunks in order");
                    last = (table.position(), offset);
                    assert_eq!(offset as usize, tables[table.position()].len());
                    tables[table.position()].extend_from_slice(bytes);
                }
                HostMessage::ConfigCommit { upload_id, crc32 } => {
                    assert_eq!(upload_id, 77);
                    commit = Some(crc32);
                }
                other => panic!("unexpected {other:?}"),
            }
        }
        assert_eq!(count, expected_count);
        let header = header.unwrap();
        assert_eq!(header, ConfigHeader::of(&config));
        let mut encoded = [0u8; ConfigHeader::MAX_ENCODED_LEN];
        let mut all: Vec<u8> = header.encode(&mut encoded).to_vec();
        all.extend(tables.concat());
        assert_eq!(commit, Some(CRC32.checksum(&all)));
        assert_eq!(commit, Some(config_digest(&config)));
        let windows: Vec<_> = tables[0].chunks(8).map(read_window).collect();
        let counts: Vec<u16> = tables[1]
            .chunks(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        let background: Vec<i32> = tables[2]
            .chunks(4)
            .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let mut gain = vec![0u16; tables[3].len() / 2];
        pixels_from_le(&tables[3], &mut gain);
        let references: Vec<_> = tables[4].chunks(8).map(read_reference_slope).collect();
        let rebuilt = header
            .config(TableSlices {
                windows: &windows,
                pixel_counts: &counts,
                background: &background,
                gain: &gain,
                reference_slopes: &references,
            })
            .unwrap();
        assert_eq!(rebuilt, config);
    }
}

#[test]
fn pixel_rows_plan_covers_the_frame() {
    let pixels: Vec<u16> = (0..1000u32).map(|k| (k * 977 % 65536) as u16).collect();
    let mut plan = PixelRowsPlan::new(5, &pixels, 300);
    let mut scratch = [0u8; MAX_PIXEL_BYTES];
    let mut out = Vec::new();
    while let Some(HostMessage::PixelRows {
        frame,
        first_pixel,
        pixels,
    }) = plan.next(&mut scratch)
    {
        assert_eq!(frame, 5);
        assert_eq!(first_pixel as usize, out.len());
        let mut decoded = vec![0u16; pixels.len() / 2];
        pixels_from_le(pixels, &mut decoded);
        out.extend(decoded);
    }
    assert_eq!(out, pixels);
}
