//! The `commander`, `failsafe` and `fence` sections: how the vehicle arms, takes off, lands and
//! answers a lost link, a lost GPS, a fence breach or a failing estimator (`core::commander`).

use crate::core::commander::{Action, LinkSource, Params, Start};
use serde::{Deserialize, Serialize};

/// Arming, takeoff and landing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CommanderConfig {
    /// "disarmed": wait for `arm`; "flying": arm and take off at start (the original).
    pub start: Start,
    /// Climb speed of the takeoff (and of a `hold` to another height), m/s.
    pub climb_m_s: f64,
    /// Largest acceleration of the climb's set point, m/s².
    pub climb_acc_m_s2: f64,
    /// The takeoff becomes `hold` once the estimate is this close to the target, m.
    pub takeoff_tolerance_m: f64,
    /// Descent speed of a landing, m/s, and in its last metre.
    pub land_m_s: f64,
    pub land_slow_m_s: f64,
    /// Touchdown: vertical speed under this (m/s) and thrust under `touchdown_thrust` of the
    /// weight, for `touchdown_s`.
    pub touchdown_v_m_s: f64,
    pub touchdown_thrust: f64,
    pub touchdown_s: f64,
    /// Largest horizontal error of the GPS fix for arming (gps.mode = "gpsd"), m.
    pub gps_max_eph_m: f64,
    /// Armed and started up on the ground with no takeoff for this long → disarmed, s
    /// (PX4's COM_DISARM_PRFLT).
    pub disarm_ground_s: f64,
    /// Tilt beyond this for `crash_s` in any armed mode → halt `crash`, rad.
    pub crash_tilt_rad: f64,
    pub crash_s: f64,
    /// A takeoff that has not left the ground within this → halt `crash`, s.
    pub takeoff_timeout_s: f64,
    /// An operator's command not applied within this of its arrival (the IMU silent, the
    /// flight stalled) is refused, never applied later, s.
    pub input_expiry_s: f64,
}

impl Default for CommanderConfig {
    fn default() -> Self {
        CommanderConfig {
            start: Start::Disarmed,
            climb_m_s: 0.5,
            climb_acc_m_s2: 0.5,
            takeoff_tolerance_m: 0.1,
            land_m_s: 0.5,
            land_slow_m_s: 0.25,
            touchdown_v_m_s: 0.15,
            touchdown_thrust: 0.8,
            touchdown_s: 1.0,
            gps_max_eph_m: 5.0,
            disarm_ground_s: 10.0,
            crash_tilt_rad: 1.0,
            crash_s: 1.0,
            takeoff_timeout_s: 15.0,
            input_expiry_s: 1.0,
        }
    }
}

/// The graded failsafes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FailsafeConfig {
    /// Which operator links count: "terminal", "console", "gcs".
    pub link_sources: Vec<String>,
    /// The link silent this long after it was seen once → `link_action`, s.
    pub link_timeout_s: f64,
    pub link_action: Action,
    /// No GPS fix while holding position: attitude and altitude are held, then
    /// `gps_loss_action` after this long, s.
    pub gps_loss_land_s: f64,
    pub gps_loss_action: Action,
    /// An innovation test ratio above 1 for this long → `ekf_action`, s.
    pub ekf_bad_s: f64,
    pub ekf_action: Action,
    /// With an RC receiver (`rc.protocol`): the receiver silent (lost at most this long after
    /// its last frame), or its own failsafe → `rc_loss_action` ("land", "return" or "hold";
    /// a return needs a position, else the vehicle lands), s. PX4's COM_RC_LOSS_T; on the
    /// ground: disarmed.
    pub rc_timeout_s: f64,
    pub rc_loss_action: Action,
}

impl Default for FailsafeConfig {
    fn default() -> Self {
        FailsafeConfig {
            link_sources: vec!["terminal".into(), "console".into(), "gcs".into()],
            link_timeout_s: 2.0,
            link_action: Action::Land,
            gps_loss_land_s: 10.0,
            gps_loss_action: Action::Land,
            ekf_bad_s: 2.0,
            ekf_action: Action::Land,
            rc_timeout_s: 0.5,
            rc_loss_action: Action::Return,
        }
    }
}

/// A cylinder around the takeoff point; active while the position is observed (GPS).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Fence {
    pub radius_m: f64,
    /// Height above the takeoff point, m.
    pub alt_max_m: f64,
    pub action: Action,
}

impl Default for Fence {
    fn default() -> Self {
        Fence {
            radius_m: 50.0,
            alt_max_m: 20.0,
            action: Action::Land,
        }
    }
}

impl super::Config {
    /// The commander's parameters.
    pub fn commander_params(&self) -> Params {
        let (c, f) = (&self.commander, &self.failsafe);
        let counts = |l: LinkSource| f.link_sources.iter().any(|s| s == l.name());
        Params {
            start: c.start,
            hover_z_m: self.control.hover_z_m,
            climb_m_s: c.climb_m_s,
            climb_acc_m_s2: c.climb_acc_m_s2,
            takeoff_tolerance_m: c.takeoff_tolerance_m,
            land_m_s: c.land_m_s,
            land_slow_m_s: c.land_slow_m_s,
            touchdown_v_m_s: c.touchdown_v_m_s,
            touchdown_thrust: c.touchdown_thrust,
            touchdown_s: c.touchdown_s,
            link_sources: LinkSource::ALL.map(counts),
            link_timeout_s: f.link_timeout_s,
            link_action: f.link_action,
            gps_timeout_s: self.control.gps_hold_timeout_s,
            gps_loss_land_s: f.gps_loss_land_s,
            gps_loss_action: f.gps_loss_action,
            fence_radius_m: self.fence.radius_m,
            fence_alt_max_m: self.fence.alt_max_m,
            fence_action: self.fence.action,
            ekf_bad_s: f.ekf_bad_s,
            ekf_action: f.ekf_action,
            gps_live: self.gps.mode == super::GpsMode::Gpsd,
            disarm_ground_s: c.disarm_ground_s,
            crash_tilt_rad: c.crash_tilt_rad,
            crash_s: c.crash_s,
            takeoff_timeout_s: c.takeoff_timeout_s,
            input_expiry_s: c.input_expiry_s,
            rearm: self.calibrates_before_arm(),
            z_min_m: self.control.manual.z_min_m,
            z_max_m: self.control.manual.z_max_m,
            mission: self.mission.limits(),
            sticks: crate::core::commander::StickLimits {
                max_speed_m_s: self.rc.max_speed_m_s,
                max_climb_m_s: self.rc.max_climb_m_s,
                max_yaw_rate_rad_s: self.rc.max_yaw_rate_rad_s,
                max_tilt_rad: self.control.manual.max_tilt_rad,
            },
            rc: (self.rc.protocol != super::RcProtocol::None).then_some(
                crate::core::commander::RcLossParams {
                    timeout_s: f.rc_timeout_s,
                    action: f.rc_loss_action,
                },
            ),
        }
    }
}
