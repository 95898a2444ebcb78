//! Several boards on one camera: a rig splits a camera's sub-apertures over
//! boards that each capture a rectangle of the sensor, runs them together
//! and merges their results into the whole camera's, in the original
//! sub-aperture order, proved bit for bit against the whole-camera
//! reference. Host-side orchestration over ordinary devices: each board
//! runs the unchanged engine on an ordinary configuration whose camera is
//! its rectangle.
//!
//! | module  | holds                                                               |
//! |---------|---------------------------------------------------------------------|
//! | `part`  | [`Rectangle`] and a board's configuration cut from the whole camera's |
//! | `board` | board kinds (crop rules, clocks, links) and the bench's cost model |
//! | `plan`  | the split of a camera's windows over boards, and their loads       |
//! | `link`  | what a board's results take on its link to the host                 |
//! | `file`  | `rig.toml`: a rig people can read and edit, checked on load        |
//! | `merge` | the boards' outcomes put together by frame number                   |
//! | `run`   | configure, stream and verify K devices as one                       |

mod board;
mod file;
mod link;
mod merge;
mod part;
mod plan;
mod run;

pub use board::{BoardKind, CostModel, DCMI_MAX_PIXEL_CLOCK_HZ};
pub use file::{describe_load, Rig, RigBoard, RigError, RigSync};
pub use link::{frame_bytes, Link, ResultBounds, SLOPE_ENTRY_MAX_BYTES, USB_FULL_SPEED};
pub use merge::{BoardCounts, MergedFrame, Merger};
pub use part::{board_config, Rectangle};
pub use plan::{
    busiest, loads, plan, plan_keeping_up, BoardLoad, BoardShare, Cut, Plan, PlanError,
};
pub use run::{
    check_configurations, configure, stream, BoardRun, EdgeCheck, RigRun, RigStart, RigStartError,
    RigStream,
};
