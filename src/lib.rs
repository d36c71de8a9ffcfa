//! uquad: flight software for the uQuad quadcopter.
//!
//! `core` is pure and deterministic; `logs` holds the text formats of the log streams;
//! `config` loads and validates profiles; `app` wires the core to the edges of each mode.

pub mod app;
pub mod config;
pub mod console;
pub mod core;
pub mod gcs;
pub mod hw;
pub mod logs;
pub mod sim;
pub mod tasks;
