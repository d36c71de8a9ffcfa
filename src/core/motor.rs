//! Motor commands around the flight ramp.
//!
//! Spec section 8.3 step 11 (the 100-step flight ramp) and ERRATA 6 (what the filter uses as
//! its input u while ramping). Speeds in rad/s.

use crate::core::model::MotorLimits;

/// Kalman steps of the flight ramp (`STARTUP_SAMPLES`).
pub const FLIGHT_RAMP_STEPS: u32 = 100;

/// Offset the flight ramp adds to the controller output at Kalman step `step` (1-based):
/// `−(100 − step)·(w_hover − w_min)/100` for steps 1–99, 0 from step 100 on (the original's
/// linear branch, despite its `RAMP_LINEAR = 0` name).
pub fn flight_ramp_offset_rad_s(step: u32, limits: &MotorLimits) -> f64 {
    if step >= FLIGHT_RAMP_STEPS {
        return 0.0;
    }
    -f64::from(FLIGHT_RAMP_STEPS - step) * (limits.w_hover_rad_s - limits.w_min_rad_s)
        / f64::from(FLIGHT_RAMP_STEPS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_offset_is_linear_and_ends_at_step_100() {
        let l = MotorLimits::new(1.55, 368.0);
        let span = l.w_hover_rad_s - l.w_min_rad_s;
        assert!((flight_ramp_offset_rad_s(1, &l) + 0.99 * span).abs() < 1e-12);
        assert!((flight_ramp_offset_rad_s(99, &l) + 0.01 * span).abs() < 1e-12);
        assert_eq!(flight_ramp_offset_rad_s(100, &l), 0.0);
        assert_eq!(flight_ramp_offset_rad_s(5000, &l), 0.0);
    }
}
