//! The log streams' text formats, compatible with the original's columns (spec 1.6 and 8.6),
//! and the records a run writes into them.
//!
//! Readers accept `\n`, `\r\n` and `\n\r` line ends and skip blank pieces; fields are separated
//! by tabs (any whitespace is accepted). Writers produce the original's exact layout.
//! `ulog` writes PX4's binary log format, for the tools that read it (`uquad export`).

pub mod format;
pub mod mode_log;
pub mod numbers;
pub mod record;
pub mod ulog;

pub use format::*;
pub use record::{PerStream, Record, Stream, halt_line};
