//! The pre-arm checks: what the driver observed, and the first failing check named; the
//! calibration's plausibility, checked as the IMU calibration ends; the running estimate's
//! health before arming. Not in the original's spec.

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
    /// Why the estimate running before arming (`imu.calibrate = "before-arm"`) cannot be
    /// flown yet, if it cannot ([`estimator_problem`]); `None` where none runs yet.
    pub estimator: Option<String>,
}

/// The estimate as the `estimator` pre-arm check sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorHealth {
    /// Why there is no estimate yet: calibrating, or a calibration refused and taken again.
    pub not_running: Option<String>,
    /// The gyro is stuck (`core::imu::health`).
    pub gyro_lost: bool,
    /// The largest standard deviation of roll and pitch, rad.
    pub tilt_sigma_rad: f64,
    /// The largest of the body velocities', m/s.
    pub velocity_sigma_m_s: f64,
    /// The horizontal position's in the frame the fixes are in (the receiver's bias doubt left
    /// out: `Ekf::fix_frame_sigma_m`), m, where fixes are expected (`None`: no receiver).
    pub position_sigma_m: Option<f64>,
    /// A fix has been fused (where fixes are expected).
    pub fix_fused: bool,
    /// The newest step's innovation test ratios.
    pub ratios: crate::core::ekf::TestRatios,
}

/// The `estimator` check's limits: a tilt known to 3 degrees, a velocity to 0.5 m/s and a
/// position to 3 m in the fixes' frame (a few fixes fused with the bias whole in a fix's
/// noise, 2 m for one NEO-M8N fix; the first fix with the receiver's bias states, 1.2 m). PX4 asks for its
/// EKF2's test ratios under its gates and its velocity and position accuracy likewise
/// (COM_ARM_EKF_*); a filter that has not converged flies its start-up transient.
pub const ARM_TILT_SIGMA_MAX_RAD: f64 = 0.05;
pub const ARM_VELOCITY_SIGMA_MAX_M_S: f64 = 0.5;
pub const ARM_POSITION_SIGMA_MAX_M: f64 = 3.0;

/// Why the estimate cannot be flown yet, if it cannot: not running, not converged, or a
/// group outside its gate.
pub fn estimator_problem(h: &EstimatorHealth) -> Option<String> {
    if let Some(why) = &h.not_running {
        return Some(why.clone());
    }
    if h.gyro_lost {
        return Some("gyro stuck (its counts repeat)".into());
    }
    // Not a number is over every limit.
    let over = |v: f64, max: f64| v.is_nan() || v > max;
    if over(h.tilt_sigma_rad, ARM_TILT_SIGMA_MAX_RAD) {
        return Some(format!(
            "tilt not converged: sigma {:.3} rad above {ARM_TILT_SIGMA_MAX_RAD}",
            h.tilt_sigma_rad
        ));
    }
    if over(h.velocity_sigma_m_s, ARM_VELOCITY_SIGMA_MAX_M_S) {
        return Some(format!(
            "velocity not converged: sigma {:.2} m/s above {ARM_VELOCITY_SIGMA_MAX_M_S}",
            h.velocity_sigma_m_s
        ));
    }
    if let Some(sigma_m) = h.position_sigma_m {
        if !h.fix_fused {
            return Some("position: no fix fused yet".into());
        }
        if over(sigma_m, ARM_POSITION_SIGMA_MAX_M) {
            return Some(format!(
                "position not converged: sigma {sigma_m:.1} m above {ARM_POSITION_SIGMA_MAX_M}"
            ));
        }
    }
    let r = &h.ratios;
    if super::outside_gate(r) {
        return Some(format!(
            "innovation test ratios outside the gate (attitude {:.2}, altitude {:.2}, gps {:?})",
            r.attitude, r.altitude, r.gps
        ));
    }
    None
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
        if let Some(e) = &self.estimator {
            return Err(format!("estimator: {e}"));
        }
        self.esc_verdict()
    }

    /// The `esc` check alone: every ESC acknowledged the last probe.
    pub fn esc_verdict(&self) -> Result<(), String> {
        if self.esc_silent.is_empty() {
            return Ok(());
        }
        let a: Vec<String> = self
            .esc_silent
            .iter()
            .map(|a| format!("0x{a:02x}"))
            .collect();
        Err(format!("esc: no acknowledgement from {}", a.join(", ")))
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
    if gyro_rad_s.iter().any(|w| w.is_nan()) {
        // The front end's mark of a stuck gyro (`core::imu::health`).
        return Some("calibration: the gyro gives no rates (stuck)".into());
    }
    let worst = gyro_rad_s.iter().map(|w| w.abs()).fold(0.0, f64::max);
    if worst > CALIB_GYRO_MAX_RAD_S {
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
    fn the_estimator_check_names_what_has_not_converged() {
        let good = EstimatorHealth {
            not_running: None,
            gyro_lost: false,
            tilt_sigma_rad: 0.01,
            velocity_sigma_m_s: 0.05,
            position_sigma_m: Some(0.8),
            fix_fused: true,
            ratios: crate::core::ekf::TestRatios::default(),
        };
        assert_eq!(estimator_problem(&good), None);
        let no_receiver = EstimatorHealth {
            position_sigma_m: None,
            fix_fused: false,
            ..good.clone()
        };
        assert_eq!(estimator_problem(&no_receiver), None);
        let why = |h: EstimatorHealth| estimator_problem(&h).unwrap_or_default();
        assert_eq!(
            why(EstimatorHealth {
                not_running: Some("IMU calibrating at rest".into()),
                ..good.clone()
            }),
            "IMU calibrating at rest"
        );
        let stuck = why(EstimatorHealth {
            gyro_lost: true,
            ..good.clone()
        });
        assert_eq!(stuck, "gyro stuck (its counts repeat)");
        let tilt = why(EstimatorHealth {
            tilt_sigma_rad: f64::NAN,
            ..good.clone()
        });
        assert!(tilt.starts_with("tilt not converged"), "{tilt}");
        let v = why(EstimatorHealth {
            velocity_sigma_m_s: 0.6,
            ..good.clone()
        });
        assert!(v.starts_with("velocity not converged: sigma 0.60"), "{v}");
        let fix = why(EstimatorHealth {
            fix_fused: false,
            ..good.clone()
        });
        assert_eq!(fix, "position: no fix fused yet");
        let pos = why(EstimatorHealth {
            position_sigma_m: Some(4.0),
            ..good.clone()
        });
        assert!(
            pos.starts_with("position not converged: sigma 4.0"),
            "{pos}"
        );
        let mut ratios = good.ratios;
        ratios.gps = Some(1.5);
        let gate = why(EstimatorHealth { ratios, ..good });
        assert!(
            gate.starts_with("innovation test ratios outside the gate"),
            "{gate}"
        );
    }

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
        let e = calibration_problem(&[0.0, 0.0, 9.8], &[f64::NAN; 3]).unwrap();
        assert!(e.contains("stuck"), "{e}");
    }
}
