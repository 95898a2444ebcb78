//! The streaming brightest-pixel engine: pure, `no_std`, allocation-free.
//!
//! The data path, one module per stage, in the order pixels go through it:
//!
//! 1. [`stream`]: camera rows arrive in raster order, in chunks of any size;
//!    each run of pixels is routed to the windows it belongs to, where the
//!    [`prefilter`] rejects most of them on their raw values, and [`scan`]
//!    admits the rest into the window's candidates;
//! 2. [`calibrate`]: background, gain and threshold (SPEC.md §2), only for
//!    the pixels that can matter;
//! 3. [`select`]: the N brightest pixels with exact ties (SPEC.md §3) from a
//!    window's candidates, admitted above a threshold that starts at the
//!    sub-aperture's [`seed`]; and [`level_filter`] (SPEC.md §4);
//! 4. [`centroid`]: centre of gravity and slopes (SPEC.md §5), emitted as soon
//!    as a window's last pixel has arrived.
//!
//! [`window`] holds the state of open windows and of sub-apertures between
//! frames, [`memory`] the caller-provided storage and its budget, `plan` the
//! sizing of an engine for a configuration. The engine
//! knows nothing of boards, transports or files.

pub mod calibrate;
pub mod centroid;
pub mod level_filter;
pub mod memory;
mod plan;
pub mod prefilter;
pub mod scan;
pub mod seed;
pub mod select;
pub mod stream;
pub mod window;

pub use centroid::{Moments, SubapertureResult};
pub use level_filter::LevelFilterState;
pub use memory::{EngineMemory, MemorySize, StaticEngineMemory};
pub use stream::{Engine, EngineStats, FrameError, OutputSink};
pub use window::{OpenWindow, SubapertureState};
