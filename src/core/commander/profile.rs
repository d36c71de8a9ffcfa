//! The vertical set point's profile of a takeoff, a hold to another height and a landing:
//! speed and acceleration limited, never past its target. Not in the original's spec (its set
//! point was a step, spec 5.1).

/// The share of the acceleration limit the profile brakes with.
pub(super) const BRAKE_SHARE: f64 = 0.9;

/// The vertical set point's profile: speed and acceleration limited, ends at rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Profile {
    pub(super) z_m: f64,
    pub(super) vz_m_s: f64,
}

impl Profile {
    /// Moves toward `target_m` by `dt_s` with speed ≤ `v_max`, acceleration ≤ `a_max`, braking
    /// in time to stop at the target.
    pub(super) fn advance(&mut self, target_m: f64, v_max: f64, a_max: f64, dt_s: f64) {
        let dist = target_m - self.z_m;
        // Braking on a curve a little gentler than the limit, so that the limited
        // deceleration can follow it.
        let v_brake = (2.0 * BRAKE_SHARE * a_max * dist.abs()).sqrt();
        let v_want = dist.signum() * v_max.min(v_brake);
        let dv_max = a_max * dt_s;
        self.vz_m_s += (v_want - self.vz_m_s).clamp(-dv_max, dv_max);
        let step = self.vz_m_s * dt_s;
        // Never past the target: there, the last of the speed decays within the limit.
        if (dist - step) * dist <= 0.0 {
            self.z_m = target_m;
        } else {
            self.z_m += step;
        }
    }
}
