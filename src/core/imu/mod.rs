//! The IMU measurement path: frames (spec 1), calibration and conversion (spec 2), the FIR
//! pre-filter (2.3) and the start-up phases (8.3 steps 3–6).

pub mod calib;
pub mod filter;
pub mod frame;
pub mod health;
pub mod startup;
