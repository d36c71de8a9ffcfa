//! The pure core: everything that decides something, with no clock, no I/O and no tasks.
//! Time and data come in as arguments; decisions come out as return values. Each file names the
//! section of `../shared/spec/uquad-original.md` it follows.

pub mod allan;
pub mod commander;
pub mod control;
pub mod ekf;
mod ekf_angles;
pub mod ekf_drag;
mod ekf_field;
pub mod ekf_fix;
mod ekf_gps_bias;
mod ekf_gyro_bias;
pub mod ekf_kernels;
pub mod esc;
pub mod flight;
pub mod gps;
pub mod imu;
pub mod lqr;
pub mod math;
pub mod mission;
pub mod model;
pub mod motor;
pub mod numfile;
pub mod path;
pub mod rc;
pub mod status;
pub mod torque;
pub mod trim;
pub mod watchdog;
