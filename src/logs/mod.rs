//! The log streams' text formats, compatible with the original's columns (spec 1.6 and 8.6).
//!
//! Readers accept `\n`, `\r\n` and `\n\r` line ends and skip blank pieces; fields are separated
//! by tabs (any whitespace is accepted). Writers produce the original's exact layout.

pub mod format;

pub use format::*;
