//! The messages the view's server sends the page over its WebSocket.
//!
//! Results and pixels are binary (little-endian, arrays 4-byte aligned so
//! that the page reads them with typed-array views, without parsing):
//! 80x80 sub-apertures are 83 KB a sample, which JSON would make several
//! times larger and slower to read. The rest (the geometry, the health
//! counters, the banner) is JSON text: small and rare.
//!
//! Results, kind 1 (`40 + 13 n` bytes):
//!
//! | offset | type | what |
//! |---|---|---|
//! | 0 | u8 | 1 |
//! | 4 | u32 | n, sub-apertures |
//! | 8 | f64 | frame number |
//! | 16 | f64 | frames seen by the host (every frame, not just sampled ones) |
//! | 24 | f64 | of them, dropped or incomplete |
//! | 32 | f64 | frames per second (host side, over the last second or so) |
//! | 40 | f32 x n | slope x, pixels |
//! | 40 + 4n | f32 x n | slope y, pixels |
//! | 40 + 8n | f32 x n | flux, counts |
//! | 40 + 12n | u8 x n | 0: no result, 1: invalid, 2: valid |
//!
//! Pixels, kind 2 (`24 + 3 w h` bytes):
//!
//! | offset | type | what |
//! |---|---|---|
//! | 0 | u8 | 2 |
//! | 4 | u32 | width |
//! | 8 | u32 | height |
//! | 16 | f64 | frame number |
//! | 24 | u16 x w h | raw pixels, row-major |
//! | 24 + 2 w h | u8 x w h | 1 where the pixel is in its window's kept set (the host's reference), else 0 |

use serde_json::json;

use crate::reference::Reference;

use super::hub::{Health, PixelSample, Sample, Setup};

pub const KIND_RESULTS: u8 = 1;
pub const KIND_PIXELS: u8 = 2;
const RESULTS_HEADER: usize = 40;
const PIXELS_HEADER: usize = 24;

/// Host-side totals sent with each results sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Totals {
    pub frames_seen: u64,
    pub frames_dropped: u64,
    pub frames_per_second: f64,
}

/// A results message (see the module docs); sub-apertures beyond `n` in
/// the sample are left out, missing ones sent as "no result".
pub fn results_message(sample: &Sample, n: usize, totals: Totals) -> Vec<u8> {
    let mut out = vec![0u8; RESULTS_HEADER + 13 * n];
    out[0] = KIND_RESULTS;
    out[4..8].copy_from_slice(&(n as u32).to_le_bytes());
    out[8..16].copy_from_slice(&(sample.frame as f64).to_le_bytes());
    out[16..24].copy_from_slice(&(totals.frames_seen as f64).to_le_bytes());
    out[24..32].copy_from_slice(&(totals.frames_dropped as f64).to_le_bytes());
    out[32..40].copy_from_slice(&totals.frames_per_second.to_le_bytes());
    let (sx, rest) = out[RESULTS_HEADER..].split_at_mut(4 * n);
    let (sy, rest) = rest.split_at_mut(4 * n);
    let (flux, state) = rest.split_at_mut(4 * n);
    for s in 0..n {
        let Some(Some(e)) = sample.results.get(s) else {
            continue;
        };
        let put = |to: &mut [u8], v: f32| to[4 * s..4 * s + 4].copy_from_slice(&v.to_le_bytes());
        // 2^-16 pixel and 1/16 count (SPEC.md §6) to pixels and counts.
        put(sx, e.slope_x as f32 / 65536.0);
        put(sy, e.slope_y as f32 / 65536.0);
        put(flux, e.flux as f32 / 16.0);
        state[s] = if e.valid { 2 } else { 1 };
    }
    out
}

/// A pixels message (see the module docs), each window's kept pixels
/// computed by `reference` (built from the setup's configuration). `None`
/// when the frame is not the configured camera's size.
pub fn pixels_message(
    reference: &Reference,
    setup: &Setup,
    sample: &PixelSample,
) -> Option<Vec<u8>> {
    let camera = setup.camera();
    let (width, height) = (camera.width as usize, camera.height as usize);
    if sample.pixels.len() != width * height {
        return None;
    }
    let area = width * height;
    let mut out = vec![0u8; PIXELS_HEADER + 3 * area];
    out[0] = KIND_PIXELS;
    out[4..8].copy_from_slice(&(width as u32).to_le_bytes());
    out[8..12].copy_from_slice(&(height as u32).to_le_bytes());
    out[16..24].copy_from_slice(&(sample.frame as f64).to_le_bytes());
    let (pixels, mask) = out[PIXELS_HEADER..].split_at_mut(2 * area);
    for (to, p) in pixels.chunks_exact_mut(2).zip(&sample.pixels) {
        to.copy_from_slice(&p.to_le_bytes());
    }
    for (s, w) in setup.windows().iter().enumerate() {
        let kept = reference.kept_pixels(&sample.pixels, s)?;
        for (k, &keep) in kept.iter().enumerate() {
            let (i, j) = (k % w.width as usize, k / w.width as usize);
            if keep {
                mask[(w.y as usize + j) * width + w.x as usize + i] = 1;
            }
        }
    }
    Some(out)
}

/// The geometry and what does not change from frame to frame.
pub fn setup_message(setup: &Setup) -> String {
    let c = &setup.config;
    let n: Vec<u16> = (0..c.windows.len())
        .map(|s| c.view().pixel_count(s))
        .collect();
    json!({
        "type": "setup",
        "source": setup.source,
        "config": setup.config_name,
        "digest": format!("{:#010x}", setup.digest),
        "rule": format!("{:?}", c.rule),
        "camera": {"width": c.camera.width, "height": c.camera.height, "bit_depth": c.camera.bit_depth},
        "windows": c.windows.iter().map(|w| [w.x, w.y, w.width, w.height]).collect::<Vec<_>>(),
        "n": n,
        "boards": setup.boards.iter().map(|(name, subs)| json!({"name": name, "subapertures": subs})).collect::<Vec<_>>(),
        "pixels": setup.pixels,
    })
    .to_string()
}

/// The device's (or the rig's) counters.
pub fn health_message(health: &Health) -> String {
    let mut value = serde_json::to_value(health).unwrap_or_default();
    value["type"] = json!("health");
    value["config_digest"] = match health.config_digest {
        Some(d) => json!(format!("{d:#010x}")),
        None => json!(null),
    };
    value.to_string()
}

/// The banner: what is wrong (`None`: nothing, the banner goes).
pub fn message_message(text: Option<&str>) -> String {
    json!({"type": "message", "text": text}).to_string()
}

/// Before any source has a configuration (a device still connecting).
pub fn waiting_message() -> String {
    json!({"type": "waiting"}).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use brightpix_protocol::wire::SlopeEntry;

    fn f32_at(b: &[u8], at: usize) -> f32 {
        f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
    }
    fn f64_at(b: &[u8], at: usize) -> f64 {
        f64::from_le_bytes(b[at..at + 8].try_into().unwrap())
    }

    #[test]
    fn results_are_laid_out_as_the_page_reads_them() {
        let e = |index, valid| SlopeEntry {
            index,
            slope_x: 3 << 15, // 1.5 px
            slope_y: -(1 << 14),
            flux: 16 * 250,
            valid,
        };
        let sample = Sample {
            frame: 41,
            results: vec![Some(e(0, true)), None, Some(e(2, false))],
        };
        let totals = Totals {
            frames_seen: 42,
            frames_dropped: 3,
            frames_per_second: 99.5,
        };
        let m = results_message(&sample, 3, totals);
        assert_eq!(m.len(), 40 + 13 * 3);
        assert_eq!(m[0], KIND_RESULTS);
        assert_eq!(u32::from_le_bytes(m[4..8].try_into().unwrap()), 3);
        assert_eq!(
            [
                f64_at(&m, 8),
                f64_at(&m, 16),
                f64_at(&m, 24),
                f64_at(&m, 32)
            ],
            [41.0, 42.0, 3.0, 99.5]
        );
        assert_eq!([f32_at(&m, 40), f32_at(&m, 44)], [1.5, 0.0]);
        assert_eq!(f32_at(&m, 40 + 12), -0.25);
        assert_eq!(f32_at(&m, 40 + 24), 250.0);
        assert_eq!(&m[40 + 36..], &[2, 0, 1]);
        // Typed arrays need their offsets aligned to the element size.
        assert_eq!((40 + 4 * 3) % 4, 0);
    }

    #[test]
    fn pixels_carry_the_references_selection() {
        let config = crate::sil::canary_config();
        let reference = Reference::new(&config.view()).unwrap();
        let mut setup = Setup::new("test".into(), "canary".into(), config);
        setup.pixels = true;
        let mut pixels = vec![50u16; 112 * 112];
        // One bright block of 25 in window 0: N = 20, subtract-next keeps
        // the pixels above the 21st brightest value.
        for (k, p) in (0..25).zip([1000u16; 25]) {
            pixels[(k / 5) * 112 + k % 5] = p + k as u16;
        }
        let sample = PixelSample { frame: 5, pixels };
        let m = pixels_message(&reference, &setup, &sample).unwrap();
        let area = 112 * 112;
        assert_eq!(m.len(), 24 + 3 * area);
        assert_eq!(m[0], KIND_PIXELS);
        assert_eq!(f64_at(&m, 16), 5.0);
        assert_eq!(u16::from_le_bytes([m[24 + 2], m[25 + 2]]), 1001);
        let mask = &m[24 + 2 * area..];
        let kept: Vec<usize> = (0..area).filter(|&k| mask[k] == 1).collect();
        // Window 0: the 20 brightest (values 1005..1024: k = 5..24); the
        // other windows are flat (all equal: nothing above v(N+1)).
        let expected: Vec<usize> = (5..25).map(|k| (k / 5) * 112 + k % 5).collect();
        assert_eq!(kept, expected);
        // A frame of another camera size is not shown.
        let wrong = PixelSample {
            frame: 0,
            pixels: vec![0; 10],
        };
        assert!(pixels_message(&reference, &setup, &wrong).is_none());
    }

    #[test]
    fn json_messages_name_their_type() {
        let setup = Setup::new("sim".into(), "canary".into(), crate::sil::canary_config());
        let v: serde_json::Value = serde_json::from_str(&setup_message(&setup)).unwrap();
        assert_eq!(v["type"], "setup");
        assert_eq!(v["windows"].as_array().unwrap().len(), 49);
        assert_eq!(v["n"][0], 20);
        assert_eq!(v["windows"][8], json!([16, 16, 16, 16]));
        let health = Health {
            frames_processed: Some(7),
            config_digest: Some(0xabc),
            ..Health::default()
        };
        let v: serde_json::Value = serde_json::from_str(&health_message(&health)).unwrap();
        assert_eq!(
            (
                v["type"].clone(),
                v["frames_processed"].clone(),
                v["config_digest"].clone()
            ),
            (json!("health"), json!(7), json!("0x00000abc"))
        );
        let v: serde_json::Value =
            serde_json::from_str(&message_message(Some("port in use"))).unwrap();
        assert_eq!(v["text"], "port in use");
    }
}
