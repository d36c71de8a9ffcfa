//! Edges to the hardware: the ESC bus (Linux I2C behind a small trait) and the IMU serial port.

pub mod esc_bus;
pub mod notify;
pub mod serial;
