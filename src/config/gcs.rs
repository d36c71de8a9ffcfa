//! The `gcs` section: the ground-station link (MAVLink 2 over UDP or a serial telemetry
//! radio, `tasks::gcs`), when it runs, and where the parameters a ground station sets are kept.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Which runs serve the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GcsEnabled {
    /// `sim --realtime` and `sim --mode paced` only (the default): a ground station can
    /// watch and fly a simulated vehicle.
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
    /// MAVLink 2 signing (empty: off): a file holding the passphrase (or 64 hexadecimal
    /// digits) of the key; then only frames signed with it are taken, and every frame sent
    /// is signed.
    pub signing_key_file: PathBuf,
}

/// A MAVLink 2 signing key (`gcs.signing_key_file`'s); its debug print never shows it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct SigningKey(pub [u8; 32]);

impl std::fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SigningKey(secret)")
    }
}

/// The signing key in a key file's text: 64 hexadecimal digits as the key itself, else the
/// SHA-256 of the passphrase (the text without its line end), as MAVProxy's `signing setup
/// PASSPHRASE` derives it. An empty file is refused.
pub fn signing_key(text: &str) -> Result<[u8; 32], String> {
    use sha2::Digest;
    let pass = text.trim_end_matches(['\n', '\r']);
    if pass.is_empty() {
        return Err("empty: it must hold a passphrase or 64 hexadecimal digits".into());
    }
    if pass.len() == 64 && pass.bytes().all(|b| b.is_ascii_hexdigit()) {
        let mut key = [0u8; 32];
        for (k, pair) in key.iter_mut().zip(pass.as_bytes().chunks(2)) {
            let hex = std::str::from_utf8(pair).map_err(|e| e.to_string())?;
            *k = u8::from_str_radix(hex, 16).map_err(|e| e.to_string())?;
        }
        return Ok(key);
    }
    Ok(sha2::Sha256::digest(pass.as_bytes()).into())
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
            signing_key_file: PathBuf::new(),
        }
    }
}
