//! The magnetometer's three axes as the attitude's reference where the accelerometer is none
//! (`ekf.r_field`; 0 leaves it out, as the 2012 flights).
//!
//! In the air a multirotor's accelerometer reads its thrust axis and the drag, not the
//! vertical: the IMU's roll and pitch then say "level" whatever the tilt. With fixes their
//! velocity shows a tilt within a second; without them (lost, or never had), or with the gyro
//! lost, nothing does, and a tilt learnt late (a gyro's bias stepping) is flown off for good.
//! The Earth's field read in the body's axes turns with the body whatever it accelerates: its
//! direction is a reference for every rotation but the one about the field itself. PX4's EKF2
//! and ArduPilot's EKF3 fuse the three axes the same way (EKF2_MAG_TYPE 3-axis). Used only
//! where nothing else holds the tilt, so the motors' currents that bend a real field cannot
//! move an attitude the fixes already hold. Not in the original's spec (its filter, spec 3,
//! uses the magnetometer through the IMU's yaw only).
//!
//! The field's direction in the Earth's frame is taken once, at the filter's start (at
//! rest, from the attitude the IMU's angles gave it).

use crate::core::ekf::{Ekf, N_STATES, idx};
use crate::core::math::rotation_portable;
use nalgebra::{SMatrix, SVector};

/// The angle step of the field rows' numerical Jacobian, rad.
const JACOBIAN_STEP_RAD: f64 = 1e-6;

/// The field's direction, unit; `None` for a vector without a length (a dead magnetometer).
fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (n.is_finite() && n > 0.0).then(|| v.map(|c| c / n))
}

/// The Earth's field direction `m_earth` read in the body's axes at roll, pitch, yaw.
fn in_body(m_earth: &[f64; 3], att: [f64; 3]) -> [f64; 3] {
    let r = rotation_portable(att[0], att[1], att[2]);
    // Rᵀ·m: the rotation takes the body's axes to the Earth's.
    std::array::from_fn(|c| (0..3).map(|row| r[row][c] * m_earth[row]).sum())
}

impl Ekf {
    /// Takes the field's direction in the Earth's frame from a sample read at the estimate's
    /// attitude (the filter's start).
    pub(crate) fn anchor_field(&mut self, magn: [f64; 3]) {
        let att = [self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]];
        self.field_earth = unit(magn).map(|m| {
            let r = rotation_portable(att[0], att[1], att[2]);
            std::array::from_fn(|row| (0..3).map(|c| r[row][c] * m[c]).sum())
        });
    }

    /// The field holds the attitude this step: on in the profile, and nothing else holds the
    /// tilt (no fix in the air, or no gyro).
    pub(crate) fn field_holds_tilt(&self) -> bool {
        self.params.r_field > 0.0
            && self.field_earth.is_some()
            && (self.gyro_lost || self.drag_active())
    }

    /// Fuses a new reading of the field (the magnetometer holds each for several frames):
    /// its direction against the estimate's attitude, into every state.
    pub(crate) fn fuse_field(&mut self, magn: [f64; 3]) {
        if !self.field_holds_tilt() || magn == self.field_last {
            return;
        }
        self.field_last = magn;
        let (Some(m_earth), Some(measured)) = (self.field_earth, unit(magn)) else {
            return;
        };
        let att = [self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]];
        let predicted = in_body(&m_earth, att);
        let mut h = SMatrix::<f64, 3, N_STATES>::zeros();
        for (k, state) in [idx::PSI, idx::PHI, idx::THETA].into_iter().enumerate() {
            let mut moved = att;
            moved[k] += JACOBIAN_STEP_RAD;
            let m = in_body(&m_earth, moved);
            for row in 0..3 {
                h[(row, state)] = (m[row] - predicted[row]) / JACOBIAN_STEP_RAD;
            }
        }
        let y = SVector::<f64, 3>::from_fn(|i, _| measured[i] - predicted[i]);
        let r = [self.params.r_field; 3];
        let all: [usize; N_STATES] = std::array::from_fn(|i| i);
        self.fuse_masked(&h, &y, &r, &all);
    }
}

#[cfg(test)]
mod tests {
    use super::{in_body, unit};
    use crate::core::ekf::{Ekf, EkfParams, GpsFusion, StepInput, idx};
    use crate::core::imu::calib::ImuSample;
    use crate::core::model::GRAVITY_M_S2;

    /// A field pointing north and down, as the simulator's (arbitrary unit).
    const FIELD: [f64; 3] = [0.98, 0.17, -0.8];

    /// A filter on the default profile's kind of values, started level with `r_field`.
    fn level_filter(r_field: f64) -> (Ekf, ImuSample) {
        let mut p = EkfParams::flight_2012();
        p.original_model = false;
        p.gps_fusion = GpsFusion::PositionVelocity;
        p.angle_period_s = 1.0;
        p.r_imu_diag[..3].fill(3e-5);
        for i in [idx::PSI, idx::PHI, idx::THETA] {
            p.q_diag[i] = 1e-7;
        }
        // The rates as the default profile's: the gyro's rows hold them to 0.01 rad/s.
        for i in [idx::WQX, idx::WQY, idx::WQZ] {
            p.q_diag[i] = 0.01;
        }
        p.r_imu_diag[6..9].fill(1e-4);
        p.drag_per_s = 0.065;
        p.r_field = r_field;
        let level = ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            magn: FIELD,
            ..ImuSample::default()
        };
        (Ekf::new(p, &level), level)
    }

    #[test]
    fn the_field_reads_back_the_attitude_it_was_anchored_at() {
        let (mut ekf, _) = level_filter(1e-4);
        ekf.x[idx::PSI] = 0.2;
        ekf.x[idx::PHI] = -0.1;
        ekf.x[idx::THETA] = 1.3;
        ekf.anchor_field(FIELD);
        let m_earth = ekf.field_earth.expect("a field with a length");
        let back = in_body(&m_earth, [0.2, -0.1, 1.3]);
        let want = unit(FIELD).expect("a field with a length");
        for i in 0..3 {
            assert!(
                (back[i] - want[i]).abs() < 1e-12,
                "{back:?} against {want:?}"
            );
        }
        ekf.anchor_field([0.0; 3]);
        assert!(
            ekf.field_earth.is_none(),
            "a dead magnetometer anchors nothing"
        );
    }

    /// Flies 10 s at hover thrust without a fix, the body pitched 0.1 rad (about an axis
    /// across the field: a turn about the field itself is not seen) while the accelerometer
    /// reads its thrust axis (the IMU's angles say level); the estimate's pitch.
    fn pitched_without_fixes(r_field: f64) -> f64 {
        let (mut ekf, level) = level_filter(r_field);
        let m_earth = ekf.field_earth.expect("a field with a length");
        let pitched = in_body(&m_earth, [0.0, 0.1, 0.0]);
        let input = StepInput::hover_10ms();
        for step in 0..1000 {
            // A new reading each step, as a real one's noise makes it.
            let sample = ImuSample {
                magn: pitched.map(|c| c * (1.0 + 1e-9 * f64::from(step % 2))),
                ..level
            };
            ekf.step(&sample, &input).1.expect("a finite step");
            // Fixes may still come for 1.5 s: the field is not yet the tilt's reference.
            if step == 100 {
                assert!(!ekf.field_holds_tilt());
            }
        }
        assert_eq!(ekf.field_holds_tilt(), r_field > 0.0);
        ekf.x[idx::PHI]
    }

    #[test]
    fn without_fixes_in_the_air_the_field_shows_a_tilt_the_accelerometer_cannot() {
        let pitch_rad = pitched_without_fixes(1e-4);
        assert!((pitch_rad - 0.1).abs() < 0.02, "pitch {pitch_rad}");
        let unused_rad = pitched_without_fixes(0.0);
        assert!(
            unused_rad.abs() < 0.01,
            "pitch {unused_rad} with the field off"
        );
    }

    #[test]
    fn a_gyro_found_stuck_puts_the_rates_in_doubt_where_the_field_can_correct_them() {
        for (r_field, doubt) in [(1e-4, true), (0.0, false)] {
            let (mut ekf, level) = level_filter(r_field);
            let input = StepInput::hover_10ms();
            ekf.step(&level, &input).1.expect("a finite step");
            let stuck = ImuSample {
                gyro_rad_s: [f64::NAN; 3],
                ..level
            };
            ekf.step(&stuck, &input).1.expect("a finite step");
            // The stuck frames' rates owe nothing to the attitude's error: no correlation.
            let tied = ekf.p[(idx::WQX, idx::PSI)];
            assert_eq!(tied == 0.0, doubt, "r_field {r_field}: {tied}");
            if doubt {
                assert!((ekf.p[(idx::WQX, idx::WQX)] - 0.01).abs() < 1e-3);
            }
        }
    }
}
