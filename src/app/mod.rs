//! Composition roots: each mode wires the pure core to its edges.

pub mod flight;
pub mod fly;
pub mod gps;
pub mod lqr;
pub mod plot;
pub mod replay;
pub mod report;
pub mod run_dir;
pub mod sim;
pub mod sim_fast;
pub mod sim_realtime;
