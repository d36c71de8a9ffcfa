//! Without fixes, the horizontal velocity from the air's drag. A multirotor's accelerometer
//! reads, across its thrust axis, only the drag: about −k·v of the body velocity through the
//! air (PX4's EKF2_MCOEF, `ekf.drag_per_s`). The filter's model carries that acceleration in
//! its bias states (bax, bay); once no fix has come for [`DRAG_AFTER_STEPS`], the
//! accelerometer's x and y are read as −k times the velocity, and bax + k·vqx = 0,
//! bay + k·vqy = 0 keep the model's drag with it: the velocity stays observed, so the
//! controller can damp it, instead of drifting as the integral of every tilt error. Not in
//! the original's spec (its filter, spec 3, models no drag).

use crate::core::ekf::{Ekf, N_STATES, StateMatrix, idx};
use nalgebra::{SMatrix, SVector};

/// Steps without a fix after which the drag holds the velocity: 1.5 s at 100 Hz, so one fix
/// missed at 1 Hz is not yet a loss.
pub(crate) const DRAG_AFTER_STEPS: u32 = 150;

/// The accelerometer's x and y read as drag, (m/s²)²: a frame's noise on the airframe,
/// vibration included (about 0.5 m/s²).
const R_AXY_DRAG: f64 = 0.25;

/// The states the drag corrects.
const HORIZONTAL: [usize; 4] = [idx::VQX, idx::VQY, idx::BAX, idx::BAY];

/// The drag constraint's noise, (m/s²)²: 0.05 m/s² for the wind and the coefficient's error.
const R_DRAG: f64 = 0.0025;

impl Ekf {
    /// The drag holds the horizontal velocity this step.
    pub(crate) fn drag_active(&self) -> bool {
        self.params.drag_per_s > 0.0 && self.steps_without_fix >= DRAG_AFTER_STEPS && self.flying
    }

    /// The vertical is observed: by the barometer, or without it by the fixes' vertical
    /// velocity (`core::ekf_fix`) while they come.
    pub fn vertical_observed(&self) -> bool {
        !self.baro_lost || self.steps_without_fix < DRAG_AFTER_STEPS
    }

    /// Fuses the accelerometer's x and y as the drag of the velocity (ax = −k·vqx,
    /// ay = −k·vqy), and ties the model's drag to it (bax + k·vqx = 0, bay + k·vqy = 0); each
    /// row gated, the gain kept to the horizontal velocity and the drag (Joseph form, right
    /// for the masked gain).
    pub(crate) fn fuse_drag(&mut self, acc_m_s2: [f64; 3]) {
        let k = self.params.drag_per_s;
        let mut h = SMatrix::<f64, 4, N_STATES>::zeros();
        h[(0, idx::VQX)] = -k;
        h[(1, idx::VQY)] = -k;
        (h[(2, idx::BAX)], h[(2, idx::VQX)]) = (1.0, k);
        (h[(3, idx::BAY)], h[(3, idx::VQY)]) = (1.0, k);
        let z = SVector::<f64, 4>::new(acc_m_s2[0], acc_m_s2[1], 0.0, 0.0);
        if !z.iter().all(|v| v.is_finite()) {
            return;
        }
        let r = [R_AXY_DRAG, R_AXY_DRAG, R_DRAG, R_DRAG];
        let mut y = z - h * self.x;
        let mut pht = self.p * h.transpose();
        let mut s = h * pht;
        for (i, ri) in r.iter().enumerate() {
            s[(i, i)] += ri;
        }
        // A push that is not the air's (a collision, a hand, the simulator's gust) reads on
        // the accelerometer as drag far beyond any airspeed the velocity allows: that axis
        // is left out until the drag agrees again.
        let gate_sq = self.params.gate_sigma * self.params.gate_sigma;
        // Judged on every row before any is left out: an axis goes whole.
        let outside = |i: usize| {
            let ratio = y[i] * y[i] / (gate_sq * s[(i, i)]);
            ratio > 1.0 || ratio.is_nan()
        };
        let axis_out = [outside(0) || outside(2), outside(1) || outside(3)];
        for row in 0..4 {
            if axis_out[row % 2] {
                y[row] = 0.0;
                pht.column_mut(row).fill(0.0);
                s.row_mut(row).fill(0.0);
                s.column_mut(row).fill(0.0);
                s[(row, row)] = 1.0;
                h.row_mut(row).fill(0.0);
            }
        }
        let Some(s_inv) = s.try_inverse() else {
            return;
        };
        let mut gain = pht * s_inv;
        // The 2012 noise values correlate every state: the vertical and the attitude must
        // not move with what the drag says.
        for st in (0..N_STATES).filter(|st| !HORIZONTAL.contains(st)) {
            gain.row_mut(st).fill(0.0);
        }
        self.x += gain * y;
        let i_kh = StateMatrix::identity() - gain * h;
        let mut krk = StateMatrix::zeros();
        for (c, rc) in r.iter().enumerate() {
            let col = gain.column(c);
            krk += col * col.transpose() * *rc;
        }
        self.p = i_kh * self.p * i_kh.transpose() + krk;
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
        };
        ekf.step(&sample, &input).1.unwrap();
        input.gps = None;
        for _ in 0..600 {
            ekf.step(&sample, &input).1.unwrap();
        }
        ekf
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
