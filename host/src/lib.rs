//! # brightpix (host)
pub mod bench;
pub mod cli;
pub mod config_file;
pub mod endtoend;
pub mod engine_runner;
pub mod evaluation;
pub mod io;
pub mod link;
pub mod parallel;
pub mod reference;
pub mod rig;
pub mod sil;
pub mod sim_device;
pub mod simulator;
pub mod view;
