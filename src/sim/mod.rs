//! The software-in-the-loop simulator: a physics model of the uQuad, a simulated IMU that
//! emits the real 30-byte frames, simulated ESCs behind the same bus trait, and the two ways of
//! flying the real code against them (`--fast` lock-step, `--realtime` with fly's tasks).

pub mod esc;
pub mod imu;
pub mod physics;
pub mod realtime;
pub mod run;
