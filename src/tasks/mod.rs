//! Tasks of the flight runtime; each file's header says In / Out / rate / when it ends.

pub mod controller;
pub mod esc_writer;
pub mod estimator;
pub mod gps_client;
pub mod imu_reader;
pub mod logger;
pub mod watchdog;
