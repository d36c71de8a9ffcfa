//! The magnetometer's three axes as the attitude's reference where the accelerometer is none
//! (`ekf.r_field`; 0 leaves it out, as the 2012 flights).
//!
//! In the air a multirotor's accelerometer reads its thrust axis and the drag, not the
//! vertical: the IMU's roll and pitch then say "level" whatever the tilt. With fixes their
//! velocity shows a tilt within a second; without them (lost, or never had), or with the gyro
//! lost, nothing does, and a tilt learnt late (a gyro's bias stepping) is flown off for good.
//! The Earth's field read in the body's axes turns with the body whatever it accelerates: its
//! direction is a reference for every rotation but the one about the field itself. PX4's EKF2
//! and ArduPilot's EKF3 fuse the magnetometer's three axes too (they also estimate the field
//! and the body's own magnetism as states; here the field is taken once, at the start). Used
//! only where nothing else holds the tilt, so the motors' currents that bend a real field
//! cannot move an attitude the fixes already hold; and each reading is gated, on its
//! direction (`ekf.gate_sigma`) and on its strength against the start's (a field bent by
//! iron or currents reads stronger or weaker), and counted with the attitude's left out. Not
//! in the original's spec (its filter, spec 3, uses the magnetometer through the IMU's yaw
//! only).
//!
//! The field's direction in the Earth's frame is taken once, at the filter's start (at rest,
//! from the attitude the IMU's angles gave it). The reading comes through the IMU's FIR and
//! the board holds it for five frames: it is fused once every [`FIELD_EVERY_STEPS`], so one
//! reading is not counted as five.

use crate::core::ekf::{Ekf, N_STATES, idx};
use crate::core::ekf_drag::DRAG_AFTER_STEPS;
use crate::core::math::rotation_portable;
use nalgebra::{SMatrix, SVector};

/// The angle step of the field rows' numerical Jacobian, rad.
const JACOBIAN_STEP_RAD: f64 = 1e-6;

/// Steps between the field's fusions: the magnetometer's hold (five 10 ms frames).
pub(crate) const FIELD_EVERY_STEPS: u32 = 5;

/// A reading whose strength differs from the start's by more than this share is a field bent
/// by iron or the motors' currents, not the Earth's: left out.
const FIELD_STRENGTH_TOLERANCE: f64 = 0.2;

/// The states the field corrects: the attitude, the rates and the gyros' bias it reads, and
/// the horizontal velocity a tilt has been flying. Not the height, the vertical or the drag's
/// states: a field's error must not move what it does not observe.
const KEEP: [usize; 11] = [
    idx::PSI,
    idx::PHI,
    idx::THETA,
    idx::WQX,
    idx::WQY,
    idx::WQZ,
    idx::BGX,
    idx::BGY,
    idx::BGZ,
    idx::VQX,
    idx::VQY,
];

/// A vector's length and direction; `None` without a finite, non-zero length (a dead
/// magnetometer).
fn length_and_unit(v: [f64; 3]) -> Option<(f64, [f64; 3])> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (n.is_finite() && n > 0.0).then(|| (n, v.map(|c| c / n)))
}

/// The Earth's field direction `m_earth` read in the body's axes at roll, pitch, yaw.
fn in_body(m_earth: &[f64; 3], att: [f64; 3]) -> [f64; 3] {
    let r = rotation_portable(att[0], att[1], att[2]);
    // Rᵀ·m: the rotation takes the body's axes to the Earth's.
    std::array::from_fn(|c| (0..3).map(|row| r[row][c] * m_earth[row]).sum())
}

/// The field's rows at an attitude: the predicted direction and its Jacobian.
fn rows(m_earth: &[f64; 3], att: [f64; 3]) -> ([f64; 3], SMatrix<f64, 3, N_STATES>) {
    let predicted = in_body(m_earth, att);
    let mut h = SMatrix::<f64, 3, N_STATES>::zeros();
    for (k, state) in [idx::PSI, idx::PHI, idx::THETA].into_iter().enumerate() {
        let mut moved = att;
        moved[k] += JACOBIAN_STEP_RAD;
        let m = in_body(m_earth, moved);
        for row in 0..3 {
            h[(row, state)] = (m[row] - predicted[row]) / JACOBIAN_STEP_RAD;
        }
    }
    (predicted, h)
}

/// The field at the filter's start: its direction in the Earth's frame and its strength.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Field {
    pub(crate) earth: [f64; 3],
    pub(crate) strength: f64,
}

impl Ekf {
    /// Takes the field's direction in the Earth's frame, and its strength, from a sample read
    /// at the estimate's attitude (the filter's start); none from a dead magnetometer.
    pub(crate) fn anchor_field(&mut self, magn: [f64; 3]) {
        let att = [self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]];
        self.field = length_and_unit(magn).map(|(strength, m)| {
            let r = rotation_portable(att[0], att[1], att[2]);
            let earth = std::array::from_fn(|row| (0..3).map(|c| r[row][c] * m[c]).sum());
            Field { earth, strength }
        });
    }

    /// The profile asks for the field (`ekf.r_field` above 0) but the start's reading had none
    /// (a dead or unplugged magnetometer): the field will never hold the tilt in this run.
    pub fn field_unread(&self) -> bool {
        self.params.r_field > 0.0 && self.field.is_none()
    }

    /// The field holds the attitude this step: on in the profile, and nothing else holds the
    /// tilt (no fix for a while in the air, or no gyro).
    pub(crate) fn field_holds_tilt(&self) -> bool {
        let unaided = self.flying && self.steps_without_fix >= DRAG_AFTER_STEPS;
        self.params.r_field > 0.0 && self.field.is_some() && (self.gyro_lost || unaided)
    }

    /// Fuses the field's reading once every [`FIELD_EVERY_STEPS`] while it holds the tilt:
    /// its direction against the estimate's attitude. `false`: the reading was left out (a
    /// strength not the start's, or a direction outside the gate).
    pub(crate) fn fuse_field(&mut self, magn: [f64; 3]) -> bool {
        if !self.field_holds_tilt() {
            self.field_steps = 0;
            return true;
        }
        self.field_steps += 1;
        if self.field_steps < FIELD_EVERY_STEPS {
            return true;
        }
        self.field_steps = 0;
        let (Some(field), Some((strength, measured))) = (self.field, length_and_unit(magn)) else {
            return false;
        };
        if (strength / field.strength - 1.0).abs() > FIELD_STRENGTH_TOLERANCE {
            return false;
        }
        let att = [self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]];
        let (predicted, h) = rows(&field.earth, att);
        let y = SVector::<f64, 3>::from_fn(|i, _| measured[i] - predicted[i]);
        let r = self.params.r_field;
        // The gate, row by row as the IMU's rows are judged.
        let s = h * self.p * h.transpose();
        let gate_sq = self.params.gate_sigma * self.params.gate_sigma;
        // Not a number is outside too.
        let inside = |i: usize| y[i] * y[i] <= gate_sq * (s[(i, i)] + r);
        if !(0..3).all(inside) {
            return false;
        }
        self.fuse_masked(&h, &y, &[r; 3], &KEEP)
    }
}

#[cfg(test)]
mod tests {
    use super::{in_body, length_and_unit};
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
    fn a_start_without_a_field_is_said_only_when_the_profile_asks_for_one() {
        let (with, level) = level_filter(1e-4);
        assert!(!with.field_unread());
        let dead = ImuSample {
            magn: [0.0; 3],
            ..level
        };
        let p = with.params.clone();
        assert!(Ekf::new(p.clone(), &dead).field_unread());
        let nan = ImuSample {
            magn: [f64::NAN; 3],
            ..level
        };
        assert!(Ekf::new(p, &nan).field_unread());
        let (off, _) = level_filter(0.0);
        let off = Ekf::new(off.params.clone(), &dead);
        assert!(
            !off.field_unread(),
            "a profile without the field does not miss it"
        );
    }

    #[test]
    fn the_field_reads_back_the_attitude_it_was_anchored_at() {
        let (mut ekf, _) = level_filter(1e-4);
        ekf.x[idx::PSI] = 0.2;
        ekf.x[idx::PHI] = -0.1;
        ekf.x[idx::THETA] = 1.3;
        ekf.anchor_field(FIELD);
        let m_earth = ekf.field.expect("a field with a length").earth;
        let back = in_body(&m_earth, [0.2, -0.1, 1.3]);
        let (_, want) = length_and_unit(FIELD).expect("a field with a length");
        for i in 0..3 {
            assert!(
                (back[i] - want[i]).abs() < 1e-12,
                "{back:?} against {want:?}"
            );
        }
        ekf.anchor_field([0.0; 3]);
        assert!(ekf.field.is_none(), "a dead magnetometer anchors nothing");
    }

    /// Flies 10 s at hover thrust without a fix while the body pitches over to 0.1 rad, about
    /// an axis across the field (a turn about the field itself is not seen), slowly as a
    /// gyro's bias would tilt it, the gyros reading nothing and the accelerometer its thrust
    /// axis (the IMU's angles say level); the estimate's pitch.
    fn pitched_without_fixes(r_field: f64) -> f64 {
        let (mut ekf, level) = level_filter(r_field);
        let field = ekf.field.expect("a field with a length");
        let input = StepInput::hover_10ms();
        for step in 0..1000 {
            let pitch_rad = 1e-4 * f64::from(step);
            let sample = ImuSample {
                magn: in_body(&field.earth, [0.0, pitch_rad, 0.0]).map(|c| c * field.strength),
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

    /// Flies 4 s at hover thrust without a fix, the field reading `magn` times the start's
    /// strength `scale` at `pitch_rad`; the steps whose attitude was left out.
    fn left_out(scale: f64, pitch_rad: f64) -> usize {
        let (mut ekf, level) = level_filter(1e-4);
        let field = ekf.field.expect("a field with a length");
        let magn = in_body(&field.earth, [0.0, pitch_rad, 0.0]).map(|c| c * field.strength * scale);
        let input = StepInput::hover_10ms();
        (0..400)
            .filter(|_| {
                let sample = ImuSample { magn, ..level };
                ekf.step(&sample, &input).0.gated.attitude
            })
            .count()
    }

    #[test]
    fn a_field_bent_in_strength_or_turned_past_the_gate_is_left_out_and_counted() {
        // The field's turn comes after 1.5 s without fixes, then a reading every 5 steps.
        assert_eq!(left_out(1.0, 0.0), 0);
        assert!(left_out(1.5, 0.0) >= 45, "a field half as strong again");
        assert!(left_out(1.0, 0.5) >= 45, "a field turned 0.5 rad at once");
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
