//! What a board's results cost on its link to the host, against what the
//! link carries: a rig needs enough boards for the links as well as for
//! the cores.
//!
//! A board sends its results as the device does (PROTOCOL.md §8): a
//! `Slopes` message at the end of every camera row that finished some of
//! its sub-apertures (and whenever 32 are waiting), then `FrameDone`, and
//! with shared rows an `EdgeRows` (§9). Postcard writes the numbers as
//! varints, so a result's size follows its values: [`ResultBounds`] takes
//! each sub-aperture's at the largest slopes and flux its configuration
//! allows, and [`frame_bytes`] encodes those messages with the protocol's
//! own encoder (CRC, COBS, delimiter). The figure is therefore a bound on
//! what the board sends for any frame whose weights are not negative
//! (SPEC.md §5: every subtracting rule with a level); the `threshold` rule,
//! no selection or a level that is none on a background-subtracted frame can
//! weigh pixels below 0 and move a slope outside its window, up to
//! [`SLOPE_ENTRY_MAX_BYTES`] a result.

use brightpix_protocol::wire::{
    encode, unstuff, DeviceMessage, SlopeEntry, SlopeList, CRC_LEN, MAX_FRAME_LEN,
    SLOPES_PER_MESSAGE,
};
use brightpix_protocol::SelectionRule;

use crate::config_file::ProcessingConfig;
use crate::reference::Reference;

/// A `SlopeEntry` at its longest on the wire (postcard varints: index 3,
/// two slopes 5 each, flux 10, valid 1), framed as one of several in a
/// message.
pub const SLOPE_ENTRY_MAX_BYTES: usize = 24;

/// A board's link to the host.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Link {
    pub name: &'static str,
    /// What it carries from the device, bytes per second.
    pub bytes_per_s: f64,
}

/// The USB link of an STM32H743 board without an external PHY: full speed,
/// 12 Mbit/s on the wire; CDC-ACM bulk transfers carry about 1 MB/s.
pub const USB_FULL_SPEED: Link = Link {
    name: "USB full speed",
    bytes_per_s: 1.0e6,
};

/// Each sub-aperture's result at its longest for its configuration:
/// the largest slopes and flux it can report (see the module's
/// documentation for the frames it covers).
#[derive(Clone, Debug, PartialEq)]
pub struct ResultBounds {
    /// Per whole-camera sub-aperture: the largest `|slope_x|`, `|slope_y|`
    /// (2^-16 pixel) and `|flux|` (1/16 count).
    largest: Vec<([i32; 2], i64)>,
}

impl ResultBounds {
    /// The bounds of `config`'s sub-apertures: a window of width `w`
    /// weighing no pixel below 0 has its centre of gravity inside it, so
    /// `|qx| <= (w - 1) 2^15` (SPEC.md §5), and its slope at most that
    /// plus its reference slope; its flux is at most its kept pixels (N
    /// for `subtract-next`, which keeps no ties; every pixel for the rules
    /// that keep ties with `v(N)` or without a selection) times the largest
    /// weight, the spread of the window's calibrated values or the largest
    /// of them in size. Calibration (SPEC.md §2) does not decrease with the
    /// raw value, so a window's calibrated values lie between those of the
    /// frames of raw 0 and of the bit depth's largest value (and 0, with a
    /// threshold); the reference calibrates both.
    ///
    /// # Panics
    /// If `config` is not valid (every loaded configuration is).
    pub fn of(config: &ProcessingConfig) -> ResultBounds {
        let view = config.view();
        let reference = Reference::new(&view).expect("a rig's configuration was validated");
        let pixels = config.camera.pixel_count();
        let dark = vec![0u16; pixels];
        let bright = vec![config.camera.max_raw(); pixels];
        let largest = config
            .windows
            .iter()
            .enumerate()
            .map(|(s, w)| {
                let values = reference
                    .calibrated(&dark, s)
                    .into_iter()
                    .chain(reference.calibrated(&bright, s))
                    .chain(config.threshold.map(|_| 0));
                let (low, high) =
                    values.fold((i128::MAX, i128::MIN), |(l, h), p| (l.min(p), h.max(p)));
                let weight = (high - low).max(high.abs()).max(low.abs());
                let n = w.pixel_count();
                let count = view.pixel_count(s) as usize;
                let kept = if config.rule == SelectionRule::SubtractNext && count < n {
                    count
                } else {
                    n
                };
                let flux = (kept as i128 * weight).min(i64::MAX as i128) as i64;
                let reference_slope = config.reference_slopes.as_ref().map_or([0, 0], |r| r[s]);
                let slope = |size: u16, r: i32| {
                    ((size as i64 - 1) * (1 << 15) + (r as i64).abs()).min(i32::MAX as i64) as i32
                };
                (
                    [
                        slope(w.width, reference_slope[0]),
                        slope(w.height, reference_slope[1]),
                    ],
                    flux,
                )
            })
            .collect();
        ResultBounds { largest }
    }

    /// Sub-aperture `s`'s result at its longest, as the board numbers it
    /// (`index`). Positive values: a zigzag varint of `m` is never shorter
    /// than one of `-m`.
    fn longest(&self, s: usize, index: usize) -> SlopeEntry {
        let ([slope_x, slope_y], flux) = self.largest[s];
        SlopeEntry {
            index: index as u16,
            slope_x,
            slope_y,
            flux,
            valid: true,
        }
    }
}

/// Bytes on the link for one frame of a board that computes `windows`
/// (whole-camera indices, ascending: the board numbers them in this
/// order), each result at its bound, as the device sends them: per camera
/// row that finishes some, `Slopes` messages of up to 32; then `FrameDone`;
/// and `EdgeRows` with shared rows. Frame numbers at their longest, and
/// each frame's COBS at its longest for its length.
pub fn frame_bytes(
    config: &ProcessingConfig,
    bounds: &ResultBounds,
    windows: &[usize],
    edge_rows: bool,
) -> usize {
    let mut buffer = [0u8; MAX_FRAME_LEN];
    // The frame at its longest for its body (PROTOCOL.md §2: COBS of `n`
    // bytes takes at most `n + ceil(n / 254)`, then the delimiter), whatever
    // zero bytes the real values put where.
    let mut size = |message: &DeviceMessage<'_>| {
        let frame = encode(message, &mut buffer).expect("a device message fits a frame");
        let len = frame.len();
        let body = unstuff(&mut frame[..len - 1]).expect("a frame just encoded");
        let n = body.len() + CRC_LEN;
        n + n.div_ceil(254) + 1
    };
    // Board-local indices, grouped by the camera row that finishes them.
    let mut by_row: Vec<(u16, usize, usize)> = windows
        .iter()
        .enumerate()
        .map(|(index, &s)| (config.windows[s].last_row(), s, index))
        .collect();
    by_row.sort_unstable();
    let mut total = 0;
    for row in by_row.chunk_by(|a, b| a.0 == b.0) {
        for chunk in row.chunks(SLOPES_PER_MESSAGE) {
            let results: SlopeList = chunk
                .iter()
                .map(|&(_, s, index)| bounds.longest(s, index))
                .collect();
            total += size(&DeviceMessage::Slopes {
                frame: u32::MAX,
                results,
            });
        }
    }
    total += size(&DeviceMessage::FrameDone {
        frame: u32::MAX,
        count: windows.len() as u32,
    });
    if edge_rows {
        total += size(&DeviceMessage::EdgeRows {
            frame: u32::MAX,
            first: u32::MAX,
            last: u32::MAX,
        });
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::SubapertureOutput;
    use brightpix_protocol::{Camera, LevelFilter, RegularGrid};

    /// A worst-case result's bytes on the wire, from the encoder itself.
    #[test]
    fn slope_entry_at_its_longest() {
        let worst = SlopeEntry {
            index: u16::MAX,
            slope_x: i32::MIN,
            slope_y: i32::MIN,
            flux: i64::MIN,
            valid: true,
        };
        let size = |n: usize| {
            let mut results = SlopeList::new();
            for _ in 0..n {
                results.push(worst).unwrap();
            }
            let mut buf = [0u8; 512];
            encode(&DeviceMessage::Slopes { frame: 0, results }, &mut buf)
                .unwrap()
                .len()
        };
        // COBS adds a byte per 254 at most: none between one and two entries.
        assert_eq!(size(2) - size(1), SLOPE_ENTRY_MAX_BYTES);
    }

    /// Configurations whose weights are never negative: CANARY (16 bits, a
    /// background map), and 12-bit cameras with a gain map up to 16x,
    /// reference slopes up to the spec's 2^22 and each subtracting rule,
    /// one with the level filter.
    fn configs() -> Vec<ProcessingConfig> {
        let mut out = vec![crate::sil::canary_config()];
        let camera = Camera {
            width: 60,
            height: 40,
            bit_depth: 12,
        };
        let grid = RegularGrid {
            x: 2,
            y: 1,
            columns: 5,
            rows: 3,
            width: 11,
            height: 12,
            pitch_x: 11,
            pitch_y: 13,
        };
        for (k, rule) in [
            SelectionRule::SubtractNext,
            SelectionRule::SubtractNextDistinct,
            SelectionRule::SubtractMean { count: 4 },
        ]
        .into_iter()
        .enumerate()
        {
            let mut config = ProcessingConfig::from_grid(camera, grid, &[]);
            let pixels = camera.pixel_count();
            config.rule = rule;
            config.background = Some((0..pixels).map(|p| (p % 97) as i32 * 16).collect());
            config.gain = Some((0..pixels).map(|p| (p * 7919 % 65536) as u16).collect());
            config.reference_slopes = Some(
                (0..config.windows.len() as i32)
                    .map(|s| [(s - 7) * 299_593, (7 - s) * 599_186])
                    .collect(),
            );
            config.level_filter = (k == 1).then_some(LevelFilter { gain_shift: 2 });
            out.push(config);
        }
        out
    }

    /// Frames that reach the bounds: dark, saturated, a lone saturated
    /// pixel in each window's corner (a centre of gravity as far from the
    /// centre as a window allows), uniform noise and simulated spots.
    fn frames(config: &ProcessingConfig) -> Vec<Vec<u16>> {
        let camera = config.camera;
        let (pixels, max) = (camera.pixel_count(), camera.max_raw());
        let mut corners = vec![0u16; pixels];
        for w in &config.windows {
            corners[w.last_row() as usize * camera.width as usize + (w.x + w.width - 1) as usize] =
                max;
        }
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let noise = (0..pixels)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state % (max as u64 + 1)) as u16
            })
            .collect();
        let spots = crate::bench::workloads::spot_frames(config, 3, 0x2545_f491_4f6c_dd1d);
        let mut out = vec![vec![0; pixels], vec![max; pixels], corners, noise];
        out.extend(spots.chunks_exact(pixels).map(<[u16]>::to_vec));
        out
    }

    fn entry(o: &SubapertureOutput) -> SlopeEntry {
        SlopeEntry {
            index: o.index as u16,
            slope_x: o.slope_x,
            slope_y: o.slope_y,
            flux: o.flux,
            valid: o.valid,
        }
    }

    /// A one-result message's frame: its length differs from another's by
    /// their results' (below 254 bytes COBS adds exactly one).
    fn one(e: SlopeEntry) -> usize {
        let mut buf = [0u8; 256];
        let results = SlopeList::from_slice(&[e]).unwrap();
        encode(&DeviceMessage::Slopes { frame: 0, results }, &mut buf)
            .unwrap()
            .len()
    }

    /// Every result the reference computes is no longer on the wire than
    /// its bound, and the frames that reach a bound reach it exactly (the
    /// corner pixel's slopes with no reference slope): neither loose nor
    /// short. The frame's bytes as the device sends them stay within
    /// [`frame_bytes`].
    #[test]
    fn results_stay_within_their_bounds() {
        for config in configs() {
            let bounds = ResultBounds::of(&config);
            let all: Vec<usize> = (0..config.windows.len()).collect();
            let bound = frame_bytes(&config, &bounds, &all, false);
            let mut reference = Reference::new(&config.view()).unwrap();
            let mut reached = false;
            for frame in frames(&config) {
                let outputs = reference.process_frame(&frame).unwrap();
                let mut sent = 0;
                let mut rows: Vec<(u16, SlopeEntry)> = outputs
                    .iter()
                    .map(|o| (config.windows[o.index].last_row(), entry(o)))
                    .collect();
                rows.sort_by_key(|r| (r.0, r.1.index));
                for row in rows.chunk_by(|a, b| a.0 == b.0) {
                    for chunk in row.chunks(SLOPES_PER_MESSAGE) {
                        let results = chunk.iter().map(|r| r.1).collect();
                        let mut buf = [0u8; MAX_FRAME_LEN];
                        sent += encode(&DeviceMessage::Slopes { frame: 0, results }, &mut buf)
                            .unwrap()
                            .len();
                    }
                }
                assert!(sent < bound, "{sent} bytes sent, bound {bound}");
                for o in &outputs {
                    let longest = bounds.longest(o.index, o.index);
                    assert!(one(entry(o)) <= one(longest), "{o:?} over {longest:?}");
                    let ([x, y], flux) = bounds.largest[o.index];
                    assert!(o.slope_x.abs() <= x && o.slope_y.abs() <= y && o.flux.abs() <= flux);
                    if config.reference_slopes.is_none() && o.valid {
                        reached |= o.slope_x == x && o.slope_y == y;
                    }
                }
            }
            assert_eq!(reached, config.reference_slopes.is_none());
        }
    }

    /// A board's bytes: one message per row of windows it finishes (up to
    /// 32 results each), the frame's end, and with shared rows their
    /// checksums.
    #[test]
    fn frame_bytes_follow_the_rows_a_board_finishes() {
        let config = crate::sil::canary_config();
        let bounds = ResultBounds::of(&config);
        let row: Vec<usize> = (0..7).collect();
        let two_rows: Vec<usize> = (0..14).collect();
        let one_row = frame_bytes(&config, &bounds, &row, false);
        let done = frame_bytes(&config, &bounds, &[], false);
        // 7 results of 12 bytes (index 1, slopes 3 + 3, flux 4: 20 pixels
        // of up to 16 x 65535 + 800, valid 1) and the message's 13
        // (variant, frame 5, length, CRC 4, COBS, delimiter).
        assert_eq!(one_row - done, 7 * 12 + 13);
        assert_eq!(
            frame_bytes(&config, &bounds, &two_rows, false) - done,
            2 * (7 * 12 + 13)
        );
        assert!(frame_bytes(&config, &bounds, &row, true) > one_row);
    }
}
