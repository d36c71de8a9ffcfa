//! Without fixes, the horizontal velocity from the air's drag. A multirotor's accelerometer
//! reads, across its thrust axis, only the drag: about −k·v of the body velocity through the
//! air (PX4's EKF2_MCOEF, `ekf.drag_per_s`). The filter's model carries that acceleration in
//! its bias states (bax, bay); once no fix has been fused for [`DRAG_AFTER_STEPS`] (a fix's
//! velocity alone counts), the
//! accelerometer's x and y are read as −k times the velocity, and bax + k·vqx = 0,
//! bay + k·vqy = 0 keep the model's drag with it: the velocity stays observed, so the
//! controller can damp it, instead of drifting as the integral of every tilt error. A push
//! that is not the air's (a collision, a hand, the simulator's gust) would read as an
//! airspeed of acc/k the other way, and the controller would fly along the push to damp
//! it: a push is told from drag by its size on a 0.1 s mean, and flown as the outside
//! acceleration it is while it lasts. Not in the original's spec (its filter, spec 3,
//! models no drag).

use crate::core::ekf::{Ekf, N_STATES, idx};
use nalgebra::{SMatrix, SVector};

/// Steps without a fix after which the drag holds the velocity: 1.5 s at 100 Hz, so one fix
/// missed at 1 Hz is not yet a loss.
pub(crate) const DRAG_AFTER_STEPS: u32 = 150;

/// The drag is read on the accelerometer's mean over this many steps (0.1 s at 100 Hz): a
/// single frame's noise is an airspeed of 0.5/k ≈ 8 m/s, the mean's a third of it, so a push
/// (below) above about 0.8 m/s² stands out at once.
pub(crate) const DRAG_WINDOW_STEPS: u32 = 10;

/// A push is read on the IMU's angles' behalf for at most this many windows (5 s): longer,
/// the gyros alone would drift, and the angles are read again (a steady push then reads as a
/// tilt on them, slowly: the profile's angle noise). The push itself is still flown as the
/// outside acceleration it is, until the drag agrees with the velocity again: read as drag,
/// a push of 2 m/s² would be an airspeed of 30 m/s in one window.
const PUSH_MAX_WINDOWS: u32 = 50;

/// The accelerometer's x and y, one frame, (m/s²)²: a frame's noise on the airframe,
/// vibration included (about 0.5 m/s²). The window's mean has a tenth of it.
const R_AXY_DRAG: f64 = 0.25;

/// The states the drag corrects.
const HORIZONTAL: [usize; 4] = [idx::VQX, idx::VQY, idx::BAX, idx::BAY];

/// The drag constraint's noise, (m/s²)²: 0.05 m/s² for the wind and the coefficient's error.
const R_DRAG: f64 = 0.0025;

impl Ekf {
    /// The model's bax, bay are the drag (no fix for a while): they then wander only as the
    /// drag does.
    pub(crate) fn drag_modelled(&self) -> bool {
        self.params.drag_per_s > 0.0 && self.steps_without_fix >= DRAG_AFTER_STEPS
    }

    /// The drag holds the horizontal velocity this step: modelled, and in flight.
    pub(crate) fn drag_active(&self) -> bool {
        self.drag_modelled() && self.flying
    }

    /// The horizontal velocity is observed: by the drag's hold, or by fixes lately fused (a
    /// fix's velocity alone counts: a position glitch leaves it good).
    pub fn horizontal_velocity_observed(&self) -> bool {
        self.drag_active() || (self.fix_seen && self.steps_without_fix < DRAG_AFTER_STEPS)
    }

    /// The vertical is observed: by the barometer, or without it by the fixes' vertical
    /// velocity (`core::ekf_fix`) while they come.
    pub fn vertical_observed(&self) -> bool {
        !self.baro_lost || self.steps_without_fix < DRAG_AFTER_STEPS
    }

    /// Adds a frame's accelerometer to the window; a full window is fused as drag or, while
    /// it reads a push, measured as the push (both axes alike: a push has one heading).
    pub(crate) fn fuse_drag(&mut self, acc_m_s2: [f64; 3]) {
        if !(acc_m_s2[0].is_finite() && acc_m_s2[1].is_finite()) {
            return;
        }
        self.drag_sum_m_s2[0] += acc_m_s2[0];
        self.drag_sum_m_s2[1] += acc_m_s2[1];
        self.drag_samples += 1;
        if self.drag_samples < DRAG_WINDOW_STEPS {
            return;
        }
        let r_mean_m2_s4 = R_AXY_DRAG / f64::from(self.drag_samples);
        let mean_m_s2 = self.drag_sum_m_s2.map(|s| s / f64::from(self.drag_samples));
        (self.drag_sum_m_s2, self.drag_samples) = ([0.0; 2], 0);
        let was_pushed = self.push_windows > 0;
        let pushed = self.pushed(mean_m_s2, r_mean_m2_s4);
        // The model's drag is the push's still when a push ends: measured afresh, the tie
        // does not read the stale push as an airspeed.
        if pushed || was_pushed {
            for (axis, mean) in mean_m_s2.into_iter().enumerate() {
                self.push_measured(axis, mean, r_mean_m2_s4);
            }
        }
        if !pushed {
            self.fuse_drag_mean(mean_m_s2, r_mean_m2_s4);
        }
    }

    /// A push is being read, for at most [`PUSH_MAX_WINDOWS`]: the accelerometer does not
    /// hold the gravity's direction then, and the IMU's angles are left to the gyros.
    pub(crate) fn pushed_now(&self) -> bool {
        // Without the gyro the IMU's angles are all the attitude has: never set aside.
        !self.gyro_lost && self.drag_active() && (1..=PUSH_MAX_WINDOWS).contains(&self.push_windows)
    }

    /// This window reads a push: the accelerometer's mean lies further from the drag of the
    /// estimated velocity (−k·v) than its noise and the drag's allow (`ekf.gate_sigma` of
    /// them), judged on the horizontal vector: a push along any heading is seen whole, not
    /// its larger part alone with the rest read as an airspeed. The velocity's own variance
    /// is left out of the test on purpose: it widens the moment the push is flown, and
    /// would let the push back in as an airspeed of acc/k the other way. Pushes under the
    /// limit (about 1.3 N on a 1.55 kg airframe) are read as drag: as wind, which they
    /// cannot be told from.
    fn pushed(&mut self, mean_m_s2: [f64; 2], r_mean_m2_s4: f64) -> bool {
        let k = self.params.drag_per_s;
        let limit_m_s2 = self.params.gate_sigma * (r_mean_m2_s4 + R_DRAG).sqrt();
        let off_m_s2 =
            (mean_m_s2[0] + k * self.x[idx::VQX]).hypot(mean_m_s2[1] + k * self.x[idx::VQY]);
        // Not a number (a diverged velocity): not a push, the drag re-reads it.
        self.push_windows = if off_m_s2 > limit_m_s2 {
            self.push_windows.saturating_add(1)
        } else {
            0
        };
        self.push_windows > 0
    }

    /// Fuses the window's mean as the drag of the velocity (ax = −k·vqx, ay = −k·vqy), and
    /// ties the model's drag to it (bax + k·vqx = 0, bay + k·vqy = 0); the gain kept to the
    /// horizontal velocity and the drag (Joseph form, right for the masked gain).
    fn fuse_drag_mean(&mut self, mean_m_s2: [f64; 2], r_mean_m2_s4: f64) {
        let k = self.params.drag_per_s;
        let mut h = SMatrix::<f64, 4, N_STATES>::zeros();
        h[(0, idx::VQX)] = -k;
        h[(1, idx::VQY)] = -k;
        (h[(2, idx::BAX)], h[(2, idx::VQX)]) = (1.0, k);
        (h[(3, idx::BAY)], h[(3, idx::VQY)]) = (1.0, k);
        let z = SVector::<f64, 4>::new(mean_m_s2[0], mean_m_s2[1], 0.0, 0.0);
        let r = [r_mean_m2_s4, r_mean_m2_s4, R_DRAG, R_DRAG];
        let y = z - h * self.x;
        // The 2012 noise values correlate every state: the vertical and the attitude must
        // not move with what the drag says. A singular S leaves the estimate as it was.
        self.fuse_masked(&h, &y, &r, &HORIZONTAL);
    }

    /// A push, one axis (0: x, 1: y): the model's outside acceleration becomes what the
    /// accelerometer measured, untied from the velocity, so the model flies the push as the
    /// acceleration it is (instead of reading it as an airspeed of acc/k the other way). Its
    /// variance is the mean's, its correlations gone; the tie returns once the drag agrees
    /// with the velocity again.
    fn push_measured(&mut self, axis: usize, mean_m_s2: f64, r_mean_m2_s4: f64) {
        let b = [idx::BAX, idx::BAY][axis];
        self.x[b] = mean_m_s2;
        self.p.row_mut(b).fill(0.0);
        self.p.column_mut(b).fill(0.0);
        self.p[(b, b)] = r_mean_m2_s4;
    }
}

#[cfg(test)]
mod tests {
    use crate::core::ekf::{Ekf, EkfParams, GpsFusion, StepInput, idx};
    use crate::core::gps::GpsSample;
    use crate::core::imu::calib::ImuSample;
    use crate::core::model::{GRAVITY_M_S2, w_hover_rad_s};

    /// A level filter flying through the air at `v` m/s north (body x), whose accelerometer
    /// reads the drag −k·v; the estimate starts at rest after a fix.
    fn flying(drag_per_s: f64) -> Ekf {
        let mut p = EkfParams::flight_2012();
        p.original_model = false;
        p.gps_fusion = GpsFusion::PositionVelocity;
        p.drag_per_s = drag_per_s;
        let v = 2.0;
        let sample = ImuSample {
            acc_m_s2: [-0.065 * v, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        let mut ekf = Ekf::new(p, &sample);
        let mut input = StepInput {
            u_rad_s: [w_hover_rad_s(1.55); 4],
            mass_kg: 1.55,
            dt_us: 10_000,
            gps: Some(GpsSample::at([0.0; 3])),
            ground_m: None,
            at_rest: false,
        };
        ekf.step(&sample, &input).1.unwrap();
        input.gps = None;
        for _ in 0..600 {
            ekf.step(&sample, &input).1.unwrap();
        }
        ekf
    }

    #[test]
    fn a_push_is_flown_as_a_push_not_read_as_an_airspeed() {
        // Flying at 2 m/s on the drag, then pushed forward at 2 m/s² for a second (a gust,
        // a hand): read as drag, that would be an airspeed of 30 m/s backwards, and the
        // controller would fly along the push to damp it. Flown as the acceleration it is,
        // the velocity grows forward, as the vehicle's does.
        let mut ekf = flying(0.065);
        let v0 = ekf.x[idx::VQX];
        let pushed = ImuSample {
            acc_m_s2: [-0.065 * 2.0 + 2.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        let input = StepInput::hover_10ms();
        for _ in 0..100 {
            ekf.step(&pushed, &input).1.unwrap();
        }
        let v = ekf.x[idx::VQX];
        assert!(ekf.pushed_now(), "the push is seen");
        assert!(v > v0 + 1.0 && v < v0 + 3.0, "{v0} m/s -> {v} m/s");
    }

    #[test]
    fn without_fixes_the_drag_gives_the_velocity() {
        let ekf = flying(0.065);
        assert!(ekf.drag_active());
        let v = ekf.x[idx::VQX];
        assert!((v - 2.0).abs() < 0.3, "velocity {v} m/s, truly 2 m/s");
        assert!(ekf.x[idx::VQY].abs() < 0.1, "{}", ekf.x[idx::VQY]);
        // Off (the 2012 flights' profiles): the velocity is not observed.
        let off = flying(0.0);
        assert!(!off.drag_active());
        assert!((off.x[idx::VQX] - 2.0).abs() > 1.0, "{}", off.x[idx::VQX]);
    }
}
