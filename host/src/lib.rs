//! # brightpix (host)
pub mod reference;
