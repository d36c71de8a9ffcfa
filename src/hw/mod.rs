//! Edges to the hardware and the kernel: the ESC bus (Linux I2C behind a small trait), the IMU
//! serial port, systemd's notifications and the threads' CPU clocks.

pub mod cpu_clock;
pub mod esc_bus;
pub mod notify;
pub mod serial;
