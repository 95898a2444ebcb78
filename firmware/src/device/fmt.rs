//! Logging: defmt with the `defmt` feature, nothing otherwise (arguments
//! are still type-checked, so both builds see the same code).
#![allow(unused_macros)]

#[cfg(feature = "defmt")]
macro_rules! log_info {
    ($($t:tt)*) => { ::defmt::info!($($t)*) };
}
#[cfg(feature = "defmt")]
macro_rules! log_warn {
    ($($t:tt)*) => { ::defmt::warn!($($t)*) };
}
#[cfg(feature = "defmt")]
macro_rules! log_debug {
    ($($t:tt)*) => { ::defmt::debug!($($t)*) };
}

#[cfg(not(feature = "defmt"))]
macro_rules! log_info {
    ($fmt:literal $(, $x:expr)* $(,)?) => {{ $( let _ = &$x; )* }};
}
#[cfg(not(feature = "defmt"))]
macro_rules! log_warn {
    ($fmt:literal $(, $x:expr)* $(,)?) => {{ $( let _ = &$x; )* }};
}
#[cfg(not(feature = "defmt"))]
macro_rules! log_debug {
    ($fmt:literal $(, $x:expr)* $(,)?) => {{ $( let _ = &$x; )* }};
}

pub(crate) use {log_debug, log_info, log_warn};
