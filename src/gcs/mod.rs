//! The ground-station link's protocol, apart from its I/O (`tasks::gcs`): the protocol's state
//! machine (`connection`), MAVLink framing with counted noise (`wire`) and signing
//! (`signing`), the parameters (`params`), the telemetry built from the vehicle's status
//! (`telemetry`), the commands mapped onto the commander's (`commands`), and a ground
//! station's mission turned into a mission file (`mission`), and the modes as ground stations
//! name and set them (`modes`).

pub mod commands;
pub mod connection;
pub mod mission;
pub mod modes;
pub mod params;
pub mod signing;
pub mod telemetry;
pub mod wire;
