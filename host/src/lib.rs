//! # brightpix (host)
pub mod cli;
pub mod config_file;
pub mod engine_runner;
pub mod io;
pub mod reference;
pub mod simulator;
