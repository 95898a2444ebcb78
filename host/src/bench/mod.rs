//! The speed figures of brightpix, measured the same way by
//! `cargo bench -p brightpix --bench engine` and `brightpix bench`.
//!
//! - [`host`]: the engine on the host, on all cores and on one
//!   ([`crate::parallel::ParallelEngine`]), against honest peers measured in
//!   the same run on the same frames ([`peers`]), each checked to agree with
//!   the engine before its time means anything, and against the
//!   no-selection baseline ([`baseline`]), which must equal the engine
//!   with no selection bit for bit;
//! - [`qemu`]: the firmware's bench in QEMU with exact instruction counts,
//!   on Cortex-M4 and Cortex-M7, run through
//!   `firmware/boards/qemu/scripts/run-bench`;
//! - [`workloads`]: the configurations and frames both use;
//! - [`timing`]: runs of at least 100 ms in interleaved rounds, min,
//!   median and max (these machines are noisy: the ratios of one run are
//!   what mean something, and no test asserts a time).

pub mod baseline;
pub mod host;
pub mod peers;
pub mod qemu;
pub mod timing;
pub mod workloads;

pub use host::{run_host, BaselineFigure, HostOptions, HostRow, PeerFigure};
pub use qemu::{QemuCore, QemuRow};
pub use timing::Stats;
pub use workloads::Workload;
