//! The pre-arm checks: what the driver observed, and the first failing check named. Not in
//! the original's spec.

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
