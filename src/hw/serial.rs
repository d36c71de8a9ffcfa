//! The serial ports: the IMU's, 115200 8N1, raw (spec 1.1); the RC receiver's (SBUS, CRSF).

use anyhow::Context;
use std::path::Path;
use tokio_serial::{DataBits, FlowControl, Parity, SerialPortBuilderExt, SerialStream, StopBits};

/// The RC receiver's UART: SBUS at 100 000 baud, 8E2 (the line inverted before it: the
/// board's inverter); CRSF at 420 000 baud, 8N1.
pub fn open_rc(path: &Path, protocol: crate::core::rc::RcProtocol) -> anyhow::Result<SerialStream> {
    use crate::core::rc::RcProtocol;
    let (baud, parity, stop) = match protocol {
        RcProtocol::Sbus => (100_000, Parity::Even, StopBits::Two),
        RcProtocol::Crsf => (420_000, Parity::None, StopBits::One),
        RcProtocol::None => anyhow::bail!("rc.protocol is \"none\": no receiver to open"),
    };
    let name = path.to_string_lossy();
    tokio_serial::new(name.as_ref(), baud)
        .data_bits(DataBits::Eight)
        .parity(parity)
        .stop_bits(stop)
        .flow_control(FlowControl::None)
        .open_native_async()
        .with_context(|| format!("cannot open the RC receiver rc.device = {}", path.display()))
}

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
