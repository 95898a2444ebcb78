//! The warning that every sub-aperture of a frame is invalid (flux at or
//! below `min_flux`): usually a wrong background, a dark camera or a
//! `min_flux` too high, and worth saying before anyone reads the slopes.
//! Shared by the commands that produce results (`process`, `stream`,
//! `capture`).

use crate::io::Results;
use crate::link::FrameOutcome;

/// Counts frames, and those in which every sub-aperture is invalid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct InvalidFrames {
    frames: usize,
    all_invalid: usize,
}

impl InvalidFrames {
    /// Every frame of `results` (whole frames, as `process` computes them).
    pub(crate) fn of_results(results: &Results) -> Self {
        InvalidFrames {
            frames: results.frames(),
            all_invalid: results.frames_all_invalid(),
        }
    }

    /// One frame's validity, one entry per sub-aperture.
    pub(crate) fn frame(&mut self, valid: impl IntoIterator<Item = bool>) {
        let mut any = false;
        let mut all_invalid = true;
        for v in valid {
            any = true;
            all_invalid &= !v;
        }
        self.frames += 1;
        self.all_invalid += usize::from(any && all_invalid);
    }

    /// A device's frame: only a frame that completed counts (a dropped or
    /// incomplete one is reported as such, not as invalid).
    pub(crate) fn outcome(&mut self, outcome: &FrameOutcome, subapertures: usize) {
        if let FrameOutcome::Done(slopes) = outcome {
            self.frame(
                slopes
                    .by_index(subapertures)
                    .into_iter()
                    .map(|e| e.is_some_and(|e| e.valid)),
            );
        }
    }

    /// The warning, if any frame had every sub-aperture invalid.
    pub(crate) fn message(&self) -> Option<String> {
        (self.all_invalid > 0).then(|| {
            format!(
                "warning: in {} of {} frames every sub-aperture is invalid (flux at or below min_flux): check the frames, background and min_flux",
                self.all_invalid, self.frames
            )
        })
    }

    /// Prints [`InvalidFrames::message`] to stderr.
    pub(crate) fn warn(&self) {
        if let Some(message) = self.message() {
            eprintln!("brightpix: {message}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Raw;
    use crate::link::FrameSlopes;
    use brightpix_protocol::wire::SlopeEntry;

    #[test]
    fn only_frames_with_every_subaperture_invalid_count() {
        let mut count = InvalidFrames::default();
        count.frame([false, false]);
        count.frame([false, true]);
        count.frame([]);
        assert_eq!(count.message().unwrap().split(':').next(), Some("warning"));
        assert!(count.message().unwrap().contains("in 1 of 3 frames"));
        assert_eq!(InvalidFrames::default().message(), None);
    }

    #[test]
    fn results_count_as_process_writes_them() {
        let mut results = Results::new(2);
        for valid in [true, false, false, false] {
            results.push(Some(Raw {
                slope_x: 0,
                slope_y: 0,
                flux: 0,
                valid,
            }));
        }
        let count = InvalidFrames::of_results(&results);
        assert!(count.message().unwrap().contains("in 1 of 2 frames"));
    }

    #[test]
    fn a_dropped_frame_is_not_an_invalid_one() {
        let entry = |index, valid| SlopeEntry {
            index,
            slope_x: 0,
            slope_y: 0,
            flux: 0,
            valid,
        };
        let slopes = |entries: Vec<SlopeEntry>| FrameSlopes {
            frame: 0,
            slopes: entries,
            done_count: Some(2),
            edge_rows: None,
        };
        let mut count = InvalidFrames::default();
        count.outcome(&FrameOutcome::Done(slopes(vec![entry(0, false)])), 2);
        count.outcome(&FrameOutcome::Incomplete(slopes(vec![])), 2);
        count.outcome(
            &FrameOutcome::Done(slopes(vec![entry(0, true), entry(1, true)])),
            2,
        );
        assert!(count.message().unwrap().contains("in 1 of 2 frames"));
    }
}
