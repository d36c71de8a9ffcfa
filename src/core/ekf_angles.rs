//! The IMU's angles (roll and pitch from its accelerometer, yaw from its magnetometer) fused
//! once every `ekf.angle_period_s` instead of every step (0: every step, as the 2012 flights).
//!
//! Their error in flight is not white noise. The accelerometer's angles read the specific
//! force, off the vertical by the vehicle's horizontal acceleration over g for as long as a
//! manoeuvre lasts (the simulated hover's error keeps 0.8 of its correlation over 0.1 s and
//! loses it within 1 s); the magnetometer's yaw is held over several frames. Fused every step
//! at their true noise they would count one error a hundred times and pull the estimate onto
//! the thrust axis; at a noise inflated to make up for it, their test ratios and NIS sit far
//! under their bounds and a drifting gyro stays unseen. Fused once a period, each fusion is
//! one reading at its own noise, and the ratios mean what they say. Their noise grows by the
//! horizontal acceleration the estimate flew (its prediction, not its corrections) in the
//! 0.25 s before the fusion, over g, squared - the yaw's too, the magnetometer's field being
//! levelled by the same angles: the original's norm-dependent R (spec, kalman module), on the
//! quantity the error is made of.
//!
//! Between fusions the angle rows are left out exactly, the attitude's test ratio holds its
//! last value (the failsafe times a group outside its gate across the steps between fusions,
//! as it does the fixes) and the step has no attitude NIS.

use crate::core::ekf::{Ekf, idx};
use crate::core::math::rotation_portable;
use crate::core::model::GRAVITY_M_S2;

/// How long before a fusion the acceleration its angles' noise is widened by is taken, s.
const ACCEL_WINDOW_S: f64 = 0.25;

/// The angles' noise per step while the gyro is lost, rad².
const R_ANGLES_NO_GYRO_RAD2: f64 = 0.11;

impl Ekf {
    /// A step of `dt_s` is about to be taken that may fall in the window before the next
    /// fusion (its velocities are then wanted by [`Ekf::tick_angles`]).
    pub(crate) fn angle_window_open(&self, dt_s: f64) -> bool {
        let period_s = self.params.angle_period_s;
        period_s > 0.0 && self.angles.since_s + dt_s + ACCEL_WINDOW_S + 1e-6 >= period_s
    }

    /// A step of `dt_s` has passed, with the estimate's horizontal velocity before it and
    /// after its prediction and the IMU's own corrections (not a fix's: those are the
    /// estimate's own error, and a fix's phase against the fusions would widen every fusion
    /// or none), when [`Ekf::angle_window_open`] asked for them: their change in the window
    /// before the next fusion is the acceleration flown.
    pub(crate) fn tick_angles(&mut self, dt_s: f64, velocities_m_s: Option<([f64; 2], [f64; 2])>) {
        let period_s = self.params.angle_period_s;
        if period_s <= 0.0 {
            return;
        }
        self.angles.since_s += dt_s;
        if self.angles.since_s + ACCEL_WINDOW_S + 1e-6 >= period_s
            && let Some((before, flown)) = velocities_m_s
        {
            for (sum, (after, before)) in self
                .angles
                .window_dv_m_s
                .iter_mut()
                .zip(flown.iter().zip(before))
            {
                *sum += after - before;
            }
            self.angles.window_s += dt_s;
        }
    }

    /// Whether this step fuses the IMU's angle rows (the first three of `r`), with their
    /// noise for this step written into `r`. The clock moves on only once the fusion is made
    /// ([`Ekf::angles_fused`]): a step refused whole leaves it due.
    pub(crate) fn angle_rows<const M: usize>(&mut self, r: &mut [f64; M]) -> bool {
        let period_s = self.params.angle_period_s;
        self.angles.due = true;
        if self.at_rest && self.params.r_angles_rest > 0.0 && !self.pushed_now() {
            // Resting, the accelerometer reads the gravity alone: the angles' own noise.
            r[..2].fill(self.params.r_angles_rest);
        }
        if period_s <= 0.0 {
            return true;
        }
        if self.gyro_lost {
            // The angles are then all the attitude has: every step, at a noise that levels
            // the estimate over seconds (the landing without a gyro is flown on it) and does
            // not pull it onto a touchdown's jolt.
            r[..3]
                .iter_mut()
                .for_each(|v| *v = v.max(R_ANGLES_NO_GYRO_RAD2));
            return true;
        }
        // Within a microsecond of the period: steps of 10 000 µs sum to 0.999 999 s.
        if self.angles.since_s + 1e-6 < period_s {
            self.angles.due = false;
            return false;
        }
        // The acceleration of the fusion's moment, not the period's mean (a manoeuvre's
        // start and stop cancel over a second).
        let dv = self.angles.window_dv_m_s;
        let accel_m_s2 = if self.angles.window_s > 0.0 {
            dv[0].hypot(dv[1]) / self.angles.window_s
        } else {
            0.0
        };
        let off_vertical = (accel_m_s2 / GRAVITY_M_S2).powi(2);
        // The yaw as well: the magnetometer's field is levelled by the same angles.
        r[..3].iter_mut().for_each(|v| *v += off_vertical);
        true
    }

    /// The step's update is done, `ratio` the attitude's test ratio: a fusion that was due
    /// and made (`made`: the update not refused) restarts the clock and is held as the
    /// attitude's ratio until the next one.
    pub(crate) fn angles_fused(&mut self, made: bool, ratio: f64) {
        if !self.angles.due || !made || !ratio.is_finite() {
            return;
        }
        self.angles.since_s = 0.0;
        self.angles.window_dv_m_s = [0.0; 2];
        self.angles.window_s = 0.0;
        self.angles.ratio = ratio;
    }

    /// The estimate's horizontal velocity, north and west, m/s.
    pub(crate) fn earth_velocity_xy_m_s(&self) -> [f64; 2] {
        let x = &self.x;
        let r = rotation_portable(x[idx::PSI], x[idx::PHI], x[idx::THETA]);
        let v = [x[idx::VQX], x[idx::VQY], x[idx::VQZ]];
        [0, 1].map(|row| (0..3).map(|c| r[row][c] * v[c]).sum())
    }
}

#[cfg(test)]
mod tests {
    use crate::core::ekf::{Ekf, EkfParams, StepInput, idx};
    use crate::core::imu::calib::ImuSample;
    use crate::core::model::GRAVITY_M_S2;

    fn filter(period_s: f64) -> (Ekf, ImuSample, StepInput) {
        let mut p = EkfParams::flight_2012();
        p.original_model = false;
        p.angle_period_s = period_s;
        p.r_imu_diag[..3].fill(1e-4);
        p.q_diag[idx::PSI] = 1e-7;
        p.q_diag[idx::PHI] = 1e-7;
        let still = ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        (Ekf::new(p, &still), still, StepInput::hover_10ms())
    }

    #[test]
    fn the_angles_are_fused_once_a_period_and_their_ratio_held_between() {
        let (mut ekf, mut tilted, input) = filter(1.0);
        // The IMU reads a roll of 0.02 rad the estimate does not have.
        tilted.euler_rad[0] = 0.02;
        let mut fused = Vec::new();
        for step in 1..=250 {
            let before = ekf.x[idx::PSI];
            let (rep, res) = ekf.step(&tilted, &input);
            res.unwrap();
            let moved = ekf.x[idx::PSI] - before;
            if rep.nis.attitude.is_some() {
                fused.push(step);
                // Towards the IMU's roll: most of the way at the first fusion.
                let least = if step == 1 { 1e-3 } else { 1e-7 };
                assert!(moved > least, "step {step}: {moved}");
            } else {
                assert!(moved.abs() < 1e-7, "step {step}: {moved}");
            }
            assert!(rep.ratios.attitude > 0.0, "a held ratio, step {step}");
        }
        // The first step, then the first after each second's prediction.
        assert_eq!(fused, vec![1, 101, 201], "fused at {fused:?}");
    }

    #[test]
    fn with_no_period_every_step_fuses_the_angles() {
        let (mut ekf, mut tilted, input) = filter(0.0);
        tilted.euler_rad[0] = 0.02;
        for _ in 0..5 {
            let before = ekf.x[idx::PSI];
            let (rep, res) = ekf.step(&tilted, &input);
            res.unwrap();
            assert!(ekf.x[idx::PSI] > before && rep.nis.attitude.is_some());
        }
    }

    #[test]
    fn resting_the_roll_and_pitch_take_their_own_noise_and_the_first_step_has_no_nis() {
        let (mut ekf, still, input) = filter(0.0);
        // The estimate began from `still`: its innovation is zero by construction.
        assert!(ekf.step(&still, &input).0.nis.attitude.is_none());
        assert!(ekf.step(&still, &input).0.nis.attitude.is_some());
        ekf.params.r_angles_rest = 1e-6;
        let mut r = [1e-4; 10];
        assert!(ekf.angle_rows(&mut r));
        assert_eq!(r[..3], [1e-4; 3], "in flight: the profile's");
        ekf.at_rest = true;
        assert!(ekf.angle_rows(&mut r));
        assert_eq!(
            r[..3],
            [1e-6, 1e-6, 1e-4],
            "at rest: roll and pitch their own"
        );
    }

    #[test]
    fn an_acceleration_predicted_before_the_fusion_widens_the_angles_noise() {
        let (mut ekf, _, _) = filter(1.0);
        let mut r = [1e-4; 10];
        assert!(ekf.angle_rows(&mut r));
        assert_eq!(r[0], 1e-4);
        ekf.angles_fused(true, 0.0);
        // A second of 10 ms steps. Every step flies a tenth of g north; every step of the
        // first half is also pulled by 0.5 m/s (a fix's correction, not flown): only the last
        // 0.25 s's flight counts, 0.01 rad² more on every angle.
        for k in 0..100 {
            if k < 50 {
                ekf.x[idx::VQX] += 0.5;
            }
            let before = ekf.earth_velocity_xy_m_s();
            ekf.x[idx::VQX] += 0.1 * GRAVITY_M_S2 * 0.01;
            let asked = ekf.angle_window_open(0.01);
            let flown = ekf.earth_velocity_xy_m_s();
            ekf.tick_angles(0.01, asked.then_some((before, flown)));
            if k == 98 {
                assert!(
                    !ekf.angle_rows(&mut [1e-4; 10]),
                    "not due before the second"
                );
            }
        }
        let mut r = [1e-4; 10];
        assert!(ekf.angle_rows(&mut r));
        assert!((r[0] - 1e-4 - 0.01).abs() < 1e-6, "{r:?}");
        // Pitch, and the yaw the magnetometer's field is levelled by, alike; the rest stay.
        assert!(r[1] == r[0] && r[2] == r[0] && r[3] == 1e-4, "{r:?}");
    }

    #[test]
    fn a_fusion_refused_by_a_bad_reading_stays_due_and_its_ratio_is_not_held() {
        let (mut ekf, still, input) = filter(1.0);
        for _ in 0..99 {
            ekf.step(&still, &input).1.unwrap();
        }
        let held = ekf.step(&still, &input).0.ratios.attitude;
        assert!(held.is_finite());
        // Steps 101 (a fusion) to 200.
        for _ in 0..100 {
            ekf.step(&still, &input).1.unwrap();
        }
        // The next fusion's step brings a roll that is not a number: the update is refused.
        let mut bad = still;
        bad.euler_rad[0] = f64::NAN;
        let (rep, res) = ekf.step(&bad, &input);
        assert!(res.is_err() && rep.ratios.attitude.is_nan());
        // The next step fuses instead, and no step after holds the NaN.
        let (rep, res) = ekf.step(&still, &input);
        res.unwrap();
        assert!(rep.nis.attitude.is_some());
        for _ in 0..50 {
            let (rep, _) = ekf.step(&still, &input);
            assert!(rep.ratios.attitude.is_finite() && rep.nis.attitude.is_none());
        }
    }
}
