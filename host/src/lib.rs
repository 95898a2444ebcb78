//! # brightpix (host)
pub mod config_file;
pub mod io;
pub mod reference;
pub mod simulator;
