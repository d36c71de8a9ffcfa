//! The pre-arm checks: what the driver observed, and the first failing check named; and the
//! calibration's plausibility, checked as the IMU calibration (after `arm`) ends. Not in the
//! original's spec.

/// The checks that must pass before arming, as the driver observed them; the first failing
/// one is named in the refusal.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ArmFacts {
    /// The IMU frames arrive at a stable period (settled).
    pub imu_stable: bool,
    /// GPS is required (gps.mode = "gpsd"); then the newest fix's horizontal error, m (None:
    /// no fix, or one without an error estimate).
    pub gps_required: bool,
    pub gps_eph_m: Option<f64>,
    pub gps_max_eph_m: f64,
    /// Why the log folder cannot be written, if it cannot.
    pub log_error: Option<String>,
    /// Real-time priority held, or waived (`--allow-no-rt`, the simulator).
    pub realtime: bool,
    /// The ESC addresses that did not acknowledge the last probe.
    pub esc_silent: Vec<u8>,
}

impl ArmFacts {
    /// The first failing check, named.
    pub fn verdict(&self) -> Result<(), String> {
        if !self.imu_stable {
            return Err("imu: frames are not arriving at a stable period yet".into());
        }
        if self.gps_required {
            match self.gps_eph_m {
                None => return Err("gps: no fix with a horizontal error estimate".into()),
                Some(e) if e > self.gps_max_eph_m => {
                    return Err(format!(
                        "gps: horizontal error {e:.1} m above commander.gps_max_eph_m = {} m",
                        self.gps_max_eph_m
                    ));
                }
                Some(_) => {}
            }
        }
        if let Some(e) = &self.log_error {
            return Err(format!("log: {e}"));
        }
        if !self.realtime {
            return Err(
                "realtime: SCHED_FIFO not held (run as the service or use --allow-no-rt)".into(),
            );
        }
        if !self.esc_silent.is_empty() {
            let a: Vec<String> = self
                .esc_silent
                .iter()
                .map(|a| format!("0x{a:02x}"))
                .collect();
            return Err(format!("esc: no acknowledgement from {}", a.join(", ")));
        }
        Ok(())
    }
}

/// The null estimate's acceleration may differ from g by this much: the vehicle stands still
/// on the ground while it is taken, m/s².
pub const CALIB_ACC_TOLERANCE_M_S2: f64 = 1.0;
/// Largest rate the null estimate may show on any axis (a gyro offset, or the vehicle moved
/// while it was taken), rad/s.
pub const CALIB_GYRO_MAX_RAD_S: f64 = 0.2;

/// Why the calibration's null sample is not plausible, if it is not: its acceleration norm not
/// g, its rates not near zero, or a value not a number.
pub fn calibration_problem(acc_m_s2: &[f64; 3], gyro_rad_s: &[f64; 3]) -> Option<String> {
    let norm = acc_m_s2.iter().map(|a| a * a).sum::<f64>().sqrt();
    let g = crate::core::model::GRAVITY_M_S2;
    // A norm that is not a number fails too: it is not within the tolerance.
    let plausible = (norm - g).abs() <= CALIB_ACC_TOLERANCE_M_S2;
    if !plausible {
        return Some(format!(
            "calibration: acceleration norm {norm:.2} m/s2, not within {CALIB_ACC_TOLERANCE_M_S2} of {g}"
        ));
    }
    let worst = gyro_rad_s.iter().map(|w| w.abs()).fold(0.0, f64::max);
    if worst > CALIB_GYRO_MAX_RAD_S || gyro_rad_s.iter().any(|w| w.is_nan()) {
        return Some(format!(
            "calibration: gyro offset {worst:.3} rad/s above {CALIB_GYRO_MAX_RAD_S}"
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_still_vehicle_calibrates_and_a_moving_or_broken_one_does_not() {
        assert_eq!(
            calibration_problem(&[0.01, -0.01, 9.77], &[0.01, -0.005, 0.002]),
            None
        );
        let e = calibration_problem(&[0.0, 0.0, 0.3], &[0.0; 3]).unwrap();
        assert!(e.starts_with("calibration: acceleration norm 0.30"), "{e}");
        let e = calibration_problem(&[0.0, 0.0, 9.8], &[0.0, 0.5, 0.0]).unwrap();
        assert!(e.starts_with("calibration: gyro offset 0.500"), "{e}");
        assert!(calibration_problem(&[f64::NAN, 0.0, 9.8], &[0.0; 3]).is_some());
        assert!(calibration_problem(&[0.0, 0.0, 9.8], &[f64::NAN; 3]).is_some());
    }
}
