//! Sizing an engine for a configuration: validation, the windows' raster
//! order, how many are open at once, and the memory that takes.

use super::memory::MemorySize;
use super::select::{least_capacity, preferred_capacity};
use brightpix_protocol::{Config, ConfigError, MemoryKind, SubapertureWindow};

/// Sizes of an engine for a configuration.
pub(super) struct Plan {
    /// Candidate entries per open window: each window's
    /// `preferred_capacity` if the pool holds that many for every open
    /// window, else as many as it holds (at least every window's
    /// `least_capacity`). A window's buffer is the smaller of its preferred
    /// capacity and the stride.
    pub(super) stride: usize,
    /// Rows of the history ring.
    pub(super) history_rows: usize,
    pub(super) needed: MemorySize,
}

/// Validates `config`, sorts its windows into `order` (by first row, then
/// column) and sizes the engine, using `heap` as scratch for counting open
/// windows; fails if it does not fit `available`.
pub(super) fn plan(
    config: &Config<'_>,
    available: MemorySize,
    order: &mut [u16],
    heap: &mut [u16],
) -> Result<Plan, ConfigError> {
    config.validate()?;
    let windows = config.windows;
    let count = windows.len();
    let subapertures = available.subapertures.min(order.len());
    if count > subapertures {
        return Err(ConfigError::MemoryBudget {
            needed: count,
            available: subapertures,
            what: MemoryKind::Subapertures,
        });
    }
    let order = &mut order[..count];
    for (k, o) in order.iter_mut().enumerate() {
        *o = k as u16;
    }
    order.sort_unstable_by_key(|&k| (windows[k as usize].y, windows[k as usize].x));
    let rule = config.selection.rule;
    let (mut least, mut preferred) = (0usize, 0usize);
    let (mut history_rows, mut scratch) = (0usize, 0usize);
    for (k, w) in windows.iter().enumerate() {
        let (n, pixels) = (config.pixel_count(k), w.pixel_count());
        let capacity = least_capacity(rule, n, pixels) as usize;
        if capacity > 0 {
            least = least.max(capacity);
            preferred = preferred.max(preferred_capacity(rule, n, pixels) as usize);
            history_rows = history_rows.max(w.height as usize);
            scratch = scratch.max(pixels);
        }
    }
    let open = match count_open_windows(windows, order, heap) {
        Some(open) if open <= available.open_windows => open,
        found => {
            return Err(ConfigError::MemoryBudget {
                needed: found.unwrap_or_else(|| count_open_windows_slowly(windows)),
                available: available.open_windows,
                what: MemoryKind::OpenWindows,
            })
        }
    };
    // The preferred stride if the pool holds it, else what it holds; at
    // least the least (if that does not fit, the check below says so).
    let stride = preferred
        .min(
            available
                .pool_entries
                .checked_div(open)
                .unwrap_or(preferred),
        )
        .max(least);
    let needed = MemorySize {
        subapertures: count,
        open_windows: open,
        pool_entries: open * stride,
        history_pixels: history_rows * config.camera.width as usize,
        scratch_entries: scratch,
    };
    let checks = [
        (
            needed.pool_entries,
            available.pool_entries,
            MemoryKind::SelectionEntries,
        ),
        (
            needed.history_pixels,
            available.history_pixels,
            MemoryKind::RowHistory,
        ),
        (
            needed.scratch_entries,
            available.scratch_entries,
            MemoryKind::ScratchEntries,
        ),
    ];
    for (needed, available, what) in checks {
        if needed > available {
            return Err(ConfigError::MemoryBudget {
                needed,
                available,
                what,
            });
        }
    }
    Ok(Plan {
        stride,
        history_rows,
        needed,
    })
}

/// The largest number of windows open at once over a frame, using `heap`
/// as a min-heap of last rows; `None` if more than `heap.len()`.
fn count_open_windows(
    windows: &[SubapertureWindow],
    order: &[u16],
    heap: &mut [u16],
) -> Option<usize> {
    let mut len = 0usize;
    let mut most = 0usize;
    for &k in order {
        let w = windows[k as usize];
        // Close the windows that ended before this one's first row.
        while len > 0 && heap[0] < w.y {
            len -= 1;
            heap[0] = heap[len];
            sift_down_rows(&mut heap[..len]);
        }
        if len == heap.len() {
            return None;
        }
        heap[len] = w.last_row();
        len += 1;
        sift_up_rows(&mut heap[..len]);
        most = most.max(len);
    }
    Some(most)
}

/// Exact count for the error message, without memory: O(windows^2).
fn count_open_windows_slowly(windows: &[SubapertureWindow]) -> usize {
    windows
        .iter()
        .map(|a| {
            windows
                .iter()
                .filter(|b| b.y <= a.y && a.y <= b.last_row())
                .count()
        })
        .max()
        .unwrap_or(0)
}

fn sift_up_rows(heap: &mut [u16]) {
    let mut i = heap.len() - 1;
    while i > 0 {
        let parent = (i - 1) / 2;
        if heap[parent] <= heap[i] {
            break;
        }
        heap.swap(i, parent);
        i = parent;
    }
}

fn sift_down_rows(heap: &mut [u16]) {
    let mut i = 0;
    loop {
        let left = 2 * i + 1;
        if left >= heap.len() {
            break;
        }
        let right = left + 1;
        let child = if right < heap.len() && heap[right] < heap[left] {
            right
        } else {
            left
        };
        if heap[child] >= heap[i] {
            break;
        }
        heap.swap(i, child);
        i = child;
    }
}
