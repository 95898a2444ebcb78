//! Bit-for-bit verification of a device's results against the reference
//! implementation (`crate::reference`), frame by frame.

use std::fmt;

use brightpix_protocol::wire::SlopeEntry;
use brightpix_protocol::{Config, ConfigError};

use super::{FrameOutcome, FrameSlopes};
use crate::reference::{Reference, SubapertureOutput};

/// One disagreement.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mismatch {
    pub frame: u32,
    pub subaperture: usize,
    /// What the device sent (`None`: nothing for this sub-aperture).
    pub device: Option<SlopeEntry>,
    /// What the reference computed (`None`: the reference refused the frame).
    pub reference: Option<SubapertureOutput>,
}

impl fmt::Display for Mismatch {
    /// Raw integers with their units and, beside them, pixels and counts:
    /// slopes in 2^-16 pixel, flux in 1/16 count (shared/SPEC.md §6).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "frame {}, sub-aperture {}: device ",
            self.frame, self.subaperture
        )?;
        match &self.device {
            Some(d) => write_result(f, d.slope_x, d.slope_y, d.flux, d.valid)?,
            None => write!(f, "(no result)")?,
        }
        write!(f, "; reference ")?;
        match &self.reference {
            Some(r) => write_result(f, r.slope_x, r.slope_y, r.flux, r.valid),
            None => write!(f, "(frame refused)"),
        }
    }
}

fn write_result(
    f: &mut fmt::Formatter<'_>,
    x: i32,
    y: i32,
    flux: impl Into<i64>,
    valid: bool,
) -> fmt::Result {
    let flux = flux.into();
    write!(
        f,
        "x={x} y={y} (2^-16 px; {:+.6} {:+.6} px), flux={flux} (1/16 count; {} counts), valid={valid}",
        f64::from(x) / 65536.0,
        f64::from(y) / 65536.0,
        flux as f64 / 16.0
    )
}

/// Feeds the reference the same frames as the device, in the same order,
/// and compares every result (slopes, flux, validity) exactly.
pub struct Verifier {
    reference: Reference,
    subapertures: usize,
    /// The first mismatches (at most `keep`).
    pub mismatches: Vec<Mismatch>,
    /// All mismatches, counted.
    pub mismatch_count: u64,
    pub frames_verified: u64,
    pub frames_failed: u64,
    /// Frames the device dropped (not compared).
    pub frames_dropped: u64,
    /// Frames sent whose outcome never arrived (not compared).
    pub frames_missing: u64,
    pub slopes_compared: u64,
    keep: usize,
}

impl Verifier {
    /// Keeps the first `keep` mismatches.
    pub fn new(config: &Config<'_>, keep: usize) -> Result<Verifier, ConfigError> {
        Ok(Verifier {
            reference: Reference::new(config)?,
            subapertures: config.windows.len(),
            mismatches: Vec::new(),
            mismatch_count: 0,
            frames_verified: 0,
            frames_failed: 0,
            frames_dropped: 0,
            frames_missing: 0,
            slopes_compared: 0,
            keep,
        })
    }

    /// Compares the device's results for `pixels` with the reference's.
    /// Returns whether they agree exactly. A dropped or incomplete frame is a
    /// failure; the reference is not advanced for a dropped frame (its
    /// level filters follow the device's only while no frame is dropped).
    pub fn check(&mut self, pixels: &[u16], outcome: &FrameOutcome) -> bool {
        let slopes = match outcome {
            FrameOutcome::Done(s) => s,
            FrameOutcome::Dropped { .. } | FrameOutcome::Incomplete(_) => {
                self.frames_dropped += 1;
                self.frames_failed += 1;
                return false;
            }
        };
        let expected = self.reference.process_frame(pixels).ok();
        self.compare(slopes, expected.as_deref())
    }

    /// Compares `slopes` with `expected` (`None`: the reference refused the
    /// frame, which the device should have dropped).
    pub fn compare(
        &mut self,
        slopes: &FrameSlopes,
        expected: Option<&[SubapertureOutput]>,
    ) -> bool {
        let got = slopes.by_index(self.subapertures);
        let mut ok = slopes.slopes.len() == self.subapertures
            && slopes.done_count == Some(self.subapertures as u32);
        let bad = |m: Mismatch, v: &mut Self| {
            v.mismatch_count += 1;
            if v.mismatches.len() < v.keep {
                v.mismatches.push(m);
            }
        };
        for (s, device) in got.iter().enumerate() {
            let reference = expected.and_then(|e| e.get(s)).copied();
            self.slopes_compared += 1;
            let same = match (device, &reference) {
                (Some(d), Some(r)) => {
                    d.index as usize == r.index
                        && d.slope_x == r.slope_x
                        && d.slope_y == r.slope_y
                        && d.flux == r.flux
                        && d.valid == r.valid
                }
                _ => false,
            };
            if !same {
                ok = false;
                bad(
                    Mismatch {
                        frame: slopes.frame,
                        subaperture: s,
                        device: *device,
                        reference,
                    },
                    self,
                );
            }
        }
        if ok {
            self.frames_verified += 1;
        } else {
            self.frames_failed += 1;
        }
        ok
    }

    /// A frame that was sent but whose outcome never came: a failure. (A
    /// verification that checked fewer frames than were sent must not pass.)
    pub fn missing(&mut self) {
        self.frames_missing += 1;
        self.frames_failed += 1;
    }

    /// Frames checked so far: verified, failed, dropped or missing.
    pub fn frames_checked(&self) -> u64 {
        self.frames_verified + self.frames_failed
    }

    /// Every frame compared agreed, and none was dropped or missing.
    pub fn all_match(&self) -> bool {
        self.frames_failed == 0 && self.mismatch_count == 0
    }

    /// The reference (e.g. to reset its level filters with the device's).
    pub fn reference_mut(&mut self) -> &mut Reference {
        &mut self.reference
    }
}
