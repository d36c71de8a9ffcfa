//! The ground-station link's protocol, apart from its I/O (`tasks::gcs`): MAVLink framing with
//! counted noise (`wire`), the parameters (`params`), the telemetry built from the flight's
//! state (`telemetry`), the commands mapped onto the commander's (`commands`), and a
//! ground station's mission turned into a mission file (`mission`).

pub mod commands;
pub mod mission;
pub mod params;
pub mod signing;
pub mod telemetry;
pub mod wire;
