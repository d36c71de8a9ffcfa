//! Composition roots: each mode wires the pure core to its edges.

pub mod fly;
pub mod gps;
pub mod lqr;
pub mod plot;
pub mod replay;
