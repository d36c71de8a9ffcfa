//! The IMU's serial port: 115200 8N1, raw (spec 1.1).

use anyhow::Context;
use std::path::Path;
use tokio_serial::{DataBits, FlowControl, Parity, SerialPortBuilderExt, SerialStream, StopBits};

/// Opens the IMU port in raw 8N1 mode at `baud`.
pub fn open_imu(path: &Path, baud: u32) -> anyhow::Result<SerialStream> {
    let name = path.to_string_lossy();
    tokio_serial::new(name.as_ref(), baud)
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::None)
        .open_native_async()
        .with_context(|| format!("cannot open the IMU serial port {}", path.display()))
}
