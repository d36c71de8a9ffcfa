//! The ground-station link's protocol, apart from its I/O (`tasks::gcs`): MAVLink framing with
//! counted noise (`wire`), the parameters (`params`), the telemetry built from the flight's
//! state (`telemetry`), and the commands mapped onto the commander's (`commands`).

pub mod commands;
pub mod params;
pub mod telemetry;
pub mod wire;
