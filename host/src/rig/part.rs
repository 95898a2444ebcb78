//! One board's part of a camera: the rectangle of the sensor it captures
//! and the board configuration derived from the whole camera's.
//!
//! A board that sees only a rectangle runs an ordinary configuration whose
//! camera is that rectangle: windows moved by the rectangle's origin, maps
//! cut to it, per-window values (N, reference slopes) taken in the board's
//! window order, and the rectangle's place on the sensor as its `crop`
//! (PROTOCOL.md §4), which the board's camera interface crops. Slopes are measured from each window's centre and every
//! rule of SPEC.md works inside one window, so the board's results are the
//! whole camera's, bit for bit, for the windows it holds.

use brightpix_protocol::{Camera, Crop, SubapertureWindow};
use serde::{Deserialize, Serialize};

use crate::config_file::{PixelCounts, ProcessingConfig};

/// A rectangle of the sensor, in camera pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rectangle {
    pub x: u16,
    pub y: u16,
    pub width: u16,
    pub height: u16,
}

impl Rectangle {
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    fn right(&self) -> u32 {
        self.x as u32 + self.width as u32
    }

    fn bottom(&self) -> u32 {
        self.y as u32 + self.height as u32
    }

    /// Whether `w` lies wholly inside.
    pub fn holds(&self, w: &SubapertureWindow) -> bool {
        w.x >= self.x
            && w.y >= self.y
            && w.x as u32 + w.width as u32 <= self.right()
            && w.y as u32 + w.height as u32 <= self.bottom()
    }

    /// Whether the rectangle lies inside `camera`'s sensor.
    pub fn inside(&self, camera: &Camera) -> bool {
        self.width > 0
            && self.height > 0
            && self.right() <= camera.width as u32
            && self.bottom() <= camera.height as u32
    }

    /// `[x, y, width, height]` as text, for messages.
    pub fn describe(&self) -> String {
        format!("{}x{} at ({}, {})", self.width, self.height, self.x, self.y)
    }

    /// The rows `y .. y + height`, columns `x .. x + width` of `data`, a
    /// whole-camera frame or map of `camera_width` columns, appended to `out`.
    pub fn crop_into<T: Copy>(&self, data: &[T], camera_width: usize, out: &mut Vec<T>) {
        let (x, w) = (self.x as usize, self.width as usize);
        for row in self.y as usize..self.bottom() as usize {
            let start = row * camera_width + x;
            out.extend_from_slice(&data[start..start + w]);
        }
    }

    /// [`Rectangle::crop_into`] into a new vector.
    pub fn crop<T: Copy>(&self, data: &[T], camera_width: usize) -> Vec<T> {
        let mut out = Vec::with_capacity(self.pixels());
        self.crop_into(data, camera_width, &mut out);
        out
    }
}

/// The configuration of a board that captures `rect` of `whole`'s camera
/// and computes `windows` (indices into `whole.windows`, in the board's
/// output order). The caller has checked that `rect` lies inside the
/// camera and holds every one of the windows.
pub fn board_config(
    whole: &ProcessingConfig,
    rect: &Rectangle,
    windows: &[usize],
) -> ProcessingConfig {
    let camera = Camera {
        width: rect.width,
        height: rect.height,
        bit_depth: whole.camera.bit_depth,
    };
    let moved: Vec<SubapertureWindow> = windows
        .iter()
        .map(|&k| {
            let w = whole.windows[k];
            SubapertureWindow {
                x: w.x - rect.x,
                y: w.y - rect.y,
                ..w
            }
        })
        .collect();
    let columns = whole.camera.width as usize;
    let mut config = ProcessingConfig::new(camera, moved);
    config.background = whole.background.as_ref().map(|m| rect.crop(m, columns));
    config.gain = whole.gain.as_ref().map(|m| rect.crop(m, columns));
    config.threshold = whole.threshold;
    config.rule = whole.rule;
    config.pixels = match &whole.pixels {
        PixelCounts::All(n) => PixelCounts::All(*n),
        PixelCounts::PerSubaperture(list) => {
            PixelCounts::PerSubaperture(windows.iter().map(|&k| list[k]).collect())
        }
    };
    config.level_filter = whole.level_filter;
    config.reference_slopes = whole
        .reference_slopes
        .as_ref()
        .map(|r| windows.iter().map(|&k| r[k]).collect());
    config.min_flux = whole.min_flux;
    // On the wire: the board's camera interface crops the rectangle from
    // the sensor its camera's bus carries.
    config.crop = Some(Crop {
        x: rect.x,
        y: rect.y,
        sensor_width: whole.camera.width,
        sensor_height: whole.camera.height,
    });
    config
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::Reference;
    use brightpix_protocol::{RegularGrid, SelectionRule};

    /// A board's results for its windows equal the whole camera's, with
    /// maps, per-window N and reference slopes that differ window by window.
    #[test]
    fn board_results_equal_the_whole_cameras() {
        let camera = Camera {
            width: 40,
            height: 30,
            bit_depth: 12,
        };
        let grid = RegularGrid {
            x: 2,
            y: 1,
            columns: 4,
            rows: 3,
            width: 8,
            height: 8,
            pitch_x: 9,
            pitch_y: 9,
        };
        let mut whole = ProcessingConfig::from_grid(camera, grid, &[]);
        let n = camera.pixel_count();
        whole.background = Some((0..n).map(|k| (k % 7) as i32 * 16).collect());
        whole.gain = Some((0..n).map(|k| 3900 + (k % 11) as u16 * 40).collect());
        whole.pixels = PixelCounts::PerSubaperture((0..12).map(|k| 3 + k as u16).collect());
        whole.reference_slopes = Some((0..12).map(|k| [k * 1000, -k * 700]).collect());
        whole.rule = SelectionRule::SubtractNext;
        whole.validate().unwrap();
        let frame: Vec<u16> = (0..n as u32)
            .map(|k| (k.wrapping_mul(2654435761) >> 20) as u16 & 0xfff)
            .collect();
        let expected = Reference::new(&whole.view())
            .unwrap()
            .process_frame(&frame)
            .unwrap();
        let rect = Rectangle {
            x: 11,
            y: 10,
            width: 26,
            height: 17,
        };
        let windows: Vec<usize> = (0..12).filter(|&k| rect.holds(&whole.windows[k])).collect();
        assert_eq!(windows, [5, 6, 7, 9, 10, 11]);
        let board = board_config(&whole, &rect, &windows);
        board.validate().unwrap();
        let got = Reference::new(&board.view())
            .unwrap()
            .process_frame(&rect.crop(&frame, 40))
            .unwrap();
        for (local, &k) in windows.iter().enumerate() {
            let (g, e) = (got[local], expected[k]);
            assert_eq!(
                (g.slope_x, g.slope_y, g.flux, g.valid),
                (e.slope_x, e.slope_y, e.flux, e.valid),
                "window {k}"
            );
        }
    }
}
