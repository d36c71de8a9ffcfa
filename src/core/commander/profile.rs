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
    /// The acceleration of the last step, m/s²: the thrust the set point needs beyond the
    /// weight (without it the vehicle lags the profile's speeding up and runs ahead of its
    /// braking, and the climb's first peak overshoots).
    pub(super) az_m_s2: f64,
}

impl Profile {
    /// At `z_m`, moving at `vz_m_s` and accelerating at `az_m_s2`.
    pub(super) fn at(z_m: f64, vz_m_s: f64, az_m_s2: f64) -> Profile {
        Profile {
            z_m,
            vz_m_s,
            az_m_s2,
        }
    }

    /// Moves toward `target_m` by `dt_s` with speed ≤ `v_max`, acceleration ≤ `a_max`, braking
    /// in time to stop at the target.
    pub(super) fn advance(&mut self, target_m: f64, v_max: f64, a_max: f64, dt_s: f64) {
        let dist = target_m - self.z_m;
        // Braking on a curve a little gentler than the limit, so that the limited
        // deceleration can follow it.
        let v_brake = (2.0 * BRAKE_SHARE * a_max * dist.abs()).sqrt();
        let v_want = dist.signum() * v_max.min(v_brake);
        let dv_max = a_max * dt_s;
        let dv = (v_want - self.vz_m_s).clamp(-dv_max, dv_max);
        self.vz_m_s += dv;
        self.az_m_s2 = if dt_s > 0.0 { dv / dt_s } else { 0.0 };
        let step = self.vz_m_s * dt_s;
        // Never past the target: there, the last of the speed decays within the limit.
        if (dist - step) * dist <= 0.0 {
            self.z_m = target_m;
        } else {
            self.z_m += step;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Profile;

    #[test]
    fn the_acceleration_is_the_speeds_change_and_ends_at_rest() {
        let mut p = Profile::at(0.0, 0.0, 0.0);
        let dt_s = 0.01;
        let (v_max, a_max) = (0.5, 0.2);
        let mut seen_up = false;
        for _ in 0..2000 {
            let v_before = p.vz_m_s;
            p.advance(1.0, v_max, a_max, dt_s);
            assert!(
                ((p.vz_m_s - v_before) / dt_s - p.az_m_s2).abs() < 1e-9,
                "{p:?}"
            );
            assert!(p.az_m_s2.abs() <= a_max + 1e-12, "{p:?}");
            seen_up |= p.az_m_s2 > 0.0;
        }
        assert!(seen_up);
        assert_eq!(p.z_m, 1.0);
        assert_eq!((p.vz_m_s, p.az_m_s2), (0.0, 0.0), "at rest on its target");
    }
}
