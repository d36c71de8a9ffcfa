//! The `rc` section: the pilot's radio receiver on a UART (`core::rc`): its protocol and
//! device, which channel carries each function and how each channel's travel is read, and
//! how far the sticks may push the vehicle.

pub use crate::core::rc::RcProtocol;
pub use crate::core::rc::link::RcMode;
/// One function's channel and how its travel is read (PX4's RCn_MIN, TRIM, MAX, REV, DZ).
pub use crate::core::rc::sticks::ChannelCal as RcChannel;
use crate::core::rc::sticks::RcMap;
use serde::{Deserialize, Deserializer, Serialize};
use std::path::PathBuf;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RcConfig {
    pub protocol: RcProtocol,
    /// The UART the receiver is wired to (SBUS needs an inverter, or a UART that inverts).
    pub device: PathBuf,
    /// The stick modes' limits (a ground station's joystick too): in `position` the
    /// horizontal speed of a stick at its end, m/s; the climb rate of the throttle stick at
    /// its end (both modes; its centre holds the height), m/s; the yaw rate of the yaw
    /// stick, rad/s.
    pub max_speed_m_s: f64,
    pub max_climb_m_s: f64,
    pub max_yaw_rate_rad_s: f64,
    /// What each position of the mode switch selects, from its low end (1 to 6 positions:
    /// its travel split into as many equal bands).
    pub modes: Vec<RcMode>,
    /// Each function's channel (AETR: roll 1, pitch 2, throttle 3, yaw 4; then the arm
    /// switch 5, the kill switch 6, the mode switch 7). A table that gives some of its keys
    /// keeps its function's defaults for the others.
    #[serde(deserialize_with = "roll")]
    pub roll: RcChannel,
    #[serde(deserialize_with = "pitch")]
    pub pitch: RcChannel,
    #[serde(deserialize_with = "throttle")]
    pub throttle: RcChannel,
    #[serde(deserialize_with = "yaw")]
    pub yaw: RcChannel,
    #[serde(deserialize_with = "arm")]
    pub arm: RcChannel,
    #[serde(deserialize_with = "kill")]
    pub kill: RcChannel,
    #[serde(deserialize_with = "mode")]
    pub mode: RcChannel,
}

/// A function's table as written: the keys it gives.
#[derive(Deserialize)]
struct Given {
    channel: Option<u8>,
    min: Option<u16>,
    center: Option<u16>,
    max: Option<u16>,
    reversed: Option<bool>,
    deadband: Option<f64>,
}

impl Given {
    fn over(self, d: RcChannel) -> RcChannel {
        RcChannel {
            channel: self.channel.unwrap_or(d.channel),
            min: self.min.unwrap_or(d.min),
            center: self.center.unwrap_or(d.center),
            max: self.max.unwrap_or(d.max),
            reversed: self.reversed.unwrap_or(d.reversed),
            deadband: self.deadband.unwrap_or(d.deadband),
        }
    }
}

/// Reads a function's table over its defaults (`defaults` is `RcConfig::default()`'s).
fn function<'de, D: Deserializer<'de>>(
    d: D,
    defaults: fn(&RcConfig) -> RcChannel,
) -> Result<RcChannel, D::Error> {
    Ok(Given::deserialize(d)?.over(defaults(&RcConfig::default())))
}

fn roll<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.roll)
}
fn pitch<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.pitch)
}
fn throttle<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.throttle)
}
fn yaw<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.yaw)
}
fn arm<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.arm)
}
fn kill<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.kill)
}
fn mode<'de, D: Deserializer<'de>>(d: D) -> Result<RcChannel, D::Error> {
    function(d, |c| c.mode)
}

impl Default for RcConfig {
    fn default() -> Self {
        RcConfig {
            protocol: RcProtocol::None,
            device: PathBuf::new(),
            max_speed_m_s: 3.0,
            max_climb_m_s: 1.0,
            max_yaw_rate_rad_s: 1.0,
            // A three-position switch, the commonest.
            modes: vec![RcMode::Position, RcMode::Hold, RcMode::Land],
            roll: RcChannel::nominal(1, 0.05),
            pitch: RcChannel::nominal(2, 0.05),
            throttle: RcChannel::nominal(3, 0.05),
            yaw: RcChannel::nominal(4, 0.05),
            arm: RcChannel::nominal(5, 0.0),
            kill: RcChannel::nominal(6, 0.0),
            mode: RcChannel::nominal(7, 0.0),
        }
    }
}

impl RcConfig {
    /// The functions by name, in the order the checks name them.
    pub fn functions(&self) -> [(&'static str, &RcChannel); 7] {
        [
            ("roll", &self.roll),
            ("pitch", &self.pitch),
            ("throttle", &self.throttle),
            ("yaw", &self.yaw),
            ("arm", &self.arm),
            ("kill", &self.kill),
            ("mode", &self.mode),
        ]
    }

    /// How the core reads the channels.
    pub fn map(&self) -> RcMap {
        RcMap {
            roll: self.roll,
            pitch: self.pitch,
            yaw: self.yaw,
            throttle: self.throttle,
            arm: self.arm,
            kill: self.kill,
            mode: self.mode,
            mode_positions: self.modes.len().max(1),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_function_table_keeps_its_own_defaults_for_the_keys_it_leaves_out() {
        let rc: RcConfig = toml::from_str("[kill]\nreversed = true\n[yaw]\nchannel = 9\n").unwrap();
        assert_eq!((rc.kill.channel, rc.kill.reversed), (6, true));
        assert_eq!((rc.yaw.channel, rc.yaw.deadband), (9, 0.05));
        assert_eq!(rc.roll, RcConfig::default().roll);
        let back: RcConfig = toml::from_str(&toml::to_string(&rc).unwrap()).unwrap();
        assert_eq!(back, rc);
    }
}
