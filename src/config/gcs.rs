//! The `gcs` section: the ground-station link (MAVLink 2 over UDP or a serial telemetry
//! radio, `tasks::gcs`), when it runs, and where the parameters a ground station sets are kept.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Which runs serve the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GcsEnabled {
    /// `sim --realtime` only (the default): a ground station can watch a simulated vehicle.
    SimRealtime,
    /// `fly` too.
    Always,
    Never,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GcsConfig {
    pub enabled: GcsEnabled,
    /// Where telemetry is sent over UDP (ground stations listen on 14550); a ground station
    /// that writes from elsewhere is answered there too.
    pub udp_remote: String,
    /// The vehicle's own UDP address ("127.0.0.1:0": loopback, any free port; "0.0.0.0:14551"
    /// to be reached from the network).
    pub udp_local: String,
    /// A serial telemetry radio instead of UDP (empty: UDP), and its speed.
    pub serial: PathBuf,
    pub baud: u32,
    /// MAVLink system id of the vehicle.
    pub system_id: u8,
    /// Default rate of ATTITUDE, LOCAL_POSITION_NED and GLOBAL_POSITION_INT
    /// (MAV_CMD_SET_MESSAGE_INTERVAL changes each while the link runs), Hz.
    pub telemetry_hz: f64,
    /// Frames taken from the link each second, and as many of the largest frame's bytes (280);
    /// beyond, they are dropped and counted.
    pub max_rx_per_s: u32,
    /// Where parameters set by a ground station are kept for the next start (empty: the
    /// file `params.toml` in the log folder).
    pub params_file: PathBuf,
    /// The system ids whose commands are obeyed, among the senders that announce themselves
    /// as a ground station (HEARTBEAT of type GCS); empty: any ground station.
    pub allowed_systems: Vec<u8>,
}

impl Default for GcsConfig {
    fn default() -> Self {
        GcsConfig {
            enabled: GcsEnabled::SimRealtime,
            udp_remote: "127.0.0.1:14550".into(),
            udp_local: "127.0.0.1:0".into(),
            serial: PathBuf::new(),
            baud: 57_600,
            system_id: 1,
            telemetry_hz: 10.0,
            max_rx_per_s: 200,
            params_file: PathBuf::new(),
            allowed_systems: Vec::new(),
        }
    }
}
