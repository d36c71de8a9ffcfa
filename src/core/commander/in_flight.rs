//! Parameters a ground station may change in flight: the commander's speeds and heights and
//! the failsafes' timeouts. A change is an operator input of the flight sequence
//! ([`super::OperatorInput::Param`]), recorded in mode.log and applied between two steps, so a
//! replay applies it at the same step. Every other flight parameter is refused while armed.
//! Not in the original's spec (its gains and speeds were compiled in).

use super::{Commander, Params};

/// The keys that take effect in flight (dotted configuration keys).
pub const IN_FLIGHT: &[&str] = &[
    "control.hover_z_m",
    "commander.climb_m_s",
    "commander.climb_acc_m_s2",
    "commander.takeoff_tolerance_m",
    "commander.land_m_s",
    "commander.land_slow_m_s",
    "commander.disarm_ground_s",
    "failsafe.link_timeout_s",
    "failsafe.gps_loss_land_s",
    "failsafe.ekf_bad_s",
];

/// `key` as the one static name [`IN_FLIGHT`] holds; none when it does not take effect in
/// flight.
pub fn in_flight_key(key: &str) -> Option<&'static str> {
    IN_FLIGHT.iter().copied().find(|k| *k == key)
}

impl Params {
    /// The field `key` names set to `value` (already checked against the configuration's
    /// rules by whoever kept it); `false` for a key that does not take effect in flight.
    pub fn set_in_flight(&mut self, key: &str, value: f64) -> bool {
        let field = match key {
            "control.hover_z_m" => &mut self.hover_z_m,
            "commander.climb_m_s" => &mut self.climb_m_s,
            "commander.climb_acc_m_s2" => &mut self.climb_acc_m_s2,
            "commander.takeoff_tolerance_m" => &mut self.takeoff_tolerance_m,
            "commander.land_m_s" => &mut self.land_m_s,
            "commander.land_slow_m_s" => &mut self.land_slow_m_s,
            "commander.disarm_ground_s" => &mut self.disarm_ground_s,
            "failsafe.link_timeout_s" => &mut self.link_timeout_s,
            "failsafe.gps_loss_land_s" => &mut self.gps_loss_land_s,
            "failsafe.ekf_bad_s" => &mut self.ekf_bad_s,
            _ => return false,
        };
        *field = value;
        true
    }
}

impl Commander {
    /// A ground station's kept change of `key` to `value`, from the next step on; `false`
    /// when the key does not take effect in flight (nothing changes).
    pub fn set_param(&mut self, key: &str, value: f64) -> bool {
        // Each is a speed, a height or a time: a value at or below 0 (or not a number) is no
        // value for it, whoever wrote it.
        value.is_finite() && value > 0.0 && self.p.set_in_flight(key, value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_in_flight_key_sets_its_field_and_no_other_key_does() {
        let base = crate::core::commander::tests::params();
        for key in IN_FLIGHT {
            let mut p = base;
            assert!(p.set_in_flight(key, 0.123), "{key}");
            assert_ne!(p, base, "{key} changed nothing");
        }
        let mut p = base;
        assert!(!p.set_in_flight("commander.crash_tilt_rad", 0.1));
        assert!(!p.set_in_flight("fence.radius_m", 1.0));
        assert_eq!(p, base);
        let mut c = Commander::new(base);
        assert!(!c.set_param("commander.land_m_s", f64::NAN));
        assert!(!c.set_param("commander.land_m_s", 0.0));
        assert!(c.set_param("commander.land_m_s", 0.3));
        assert_eq!(c.params().land_m_s, 0.3);
    }
}
