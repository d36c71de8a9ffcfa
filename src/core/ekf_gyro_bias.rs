//! The gyros' bias as three more filter states (`ekf.q_gyro_bias`, `ekf.p0_gyro_bias`; both 0
//! leave them out of everything, as the 2012 flights had them).
//!
//! The calibration at rest removes the gyros' offset, but a MEMS gyro's bias moves with
//! temperature and time, and can step (`--inject gyro-bias`). Not in the original's spec
//! (3.1 has fifteen states and no bias for the gyros): without a state for it, the
//! estimate's attitude runs off at the bias's rate between the IMU's angle fusions, the
//! controller flies that error as a tilt, and the fixes' velocity soon contradicts the
//! estimate. PX4's and ArduPilot's filters carry the same three states.
//!
//! The rate states stay what the gyro rows read (the gyro's frame, bias included), so the
//! rows stay selections; the model (attitude kinematics, torques, Coriolis terms) runs on the
//! body's rates, the rate states less the bias. The filter's Jacobian follows from the
//! model's by the chain rule: a bias column is minus the matching rate column, plus one on
//! that rate's own row (the rate state carries the bias through the step unchanged). The
//! angle fusions and the fixes' velocity teach the bias through the covariance that builds.

use crate::core::ekf::{Ekf, ModelMatrix, N_MODEL, State, StateMatrix, idx};

/// The rate states and their bias states, in body axis order.
const RATES: [usize; 3] = [idx::WQX, idx::WQY, idx::WQZ];
const BIAS: [usize; 3] = [idx::BGX, idx::BGY, idx::BGZ];

impl Ekf {
    /// The bias states take part: noise or an initial doubt was given them.
    pub(crate) fn gyro_bias_on(&self) -> bool {
        self.params.gyro_bias_q > 0.0 || self.params.gyro_bias_p0 > 0.0
    }

    /// The model's fifteen states, the rates the body's (the rate states less the bias).
    pub fn model_state(&self) -> State {
        let mut xm = State::from_fn(|i, _| self.x[i]);
        if self.gyro_bias_on() {
            for (r, b) in RATES.into_iter().zip(BIAS) {
                xm[r] -= self.x[b];
            }
        }
        xm
    }

    /// Writes the model's predicted states back, the rates into the gyro's frame.
    pub(crate) fn set_model_state(&mut self, xm: &State) {
        for i in 0..N_MODEL {
            self.x[i] = xm[i];
        }
        if self.gyro_bias_on() {
            for (r, b) in RATES.into_iter().zip(BIAS) {
                self.x[r] += self.x[b];
            }
        }
    }

    /// The filter's Jacobian from the model's `f` (at the model's states).
    pub fn filter_jacobian(&self, f: &ModelMatrix) -> StateMatrix {
        let mut out = StateMatrix::identity();
        out.fixed_view_mut::<N_MODEL, N_MODEL>(0, 0).copy_from(f);
        if self.gyro_bias_on() {
            for (r, b) in RATES.into_iter().zip(BIAS) {
                for i in 0..N_MODEL {
                    let own = if i == r { 1.0 } else { 0.0 };
                    out[(i, b)] = own - f[(i, r)];
                }
            }
        }
        out
    }

    /// The bias's random walk over a step; none while the gyro is lost (nothing reads it).
    pub(crate) fn bias_process_noise(&mut self) {
        if self.gyro_bias_on() && !self.gyro_lost {
            for b in BIAS {
                self.p[(b, b)] += self.params.gyro_bias_q;
            }
        }
    }

    /// How far the roll and pitch bias has been learnt to move since the last fused fix,
    /// rad/s (0 on a fix's step, or without the bias states). Without fixes in the air the
    /// IMU's angles read the thrust axis, not the vertical: a bias learnt then was flown as a
    /// tilt, about its size times the time taken to learn it, before anything showed it.
    pub fn bias_learnt_unaided_rad_s(&self) -> f64 {
        if !self.gyro_bias_on() || self.steps_without_fix == 0 {
            return 0.0;
        }
        let [x, y] = self.bias_at_fix_rad_s;
        (self.x[idx::BGX] - x).hypot(self.x[idx::BGY] - y)
    }

    /// The learnt bias, body x y z, rad/s.
    pub fn gyro_bias_rad_s(&self) -> [f64; 3] {
        BIAS.map(|b| self.x[b])
    }
}

#[cfg(test)]
mod tests {
    use crate::core::ekf::{Ekf, EkfParams, GpsFusion, StepInput, idx, jacobian};
    use crate::core::ekf_kernels::D_COLS;
    use crate::core::imu::calib::ImuSample;
    use crate::core::model::GRAVITY_M_S2;

    fn params(bias: bool) -> EkfParams {
        let mut p = EkfParams::flight_2012();
        p.original_model = false;
        p.gps_fusion = GpsFusion::PositionVelocity;
        p.angle_period_s = 1.0;
        p.r_imu_diag[..3].fill(3e-5);
        p.q_diag[idx::PSI] = 1e-7;
        p.q_diag[idx::PHI] = 1e-7;
        p.q_diag[idx::THETA] = 1e-7;
        if bias {
            p.gyro_bias_q = 1e-9;
            p.gyro_bias_p0 = 1e-3;
        }
        p
    }

    fn level() -> ImuSample {
        ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        }
    }

    #[test]
    fn the_bias_learnt_without_fixes_is_measured_from_the_last_fused_one() {
        let mut ekf = Ekf::new(params(true), &level());
        ekf.bias_at_fix_rad_s = [0.01, -0.02];
        ekf.x[idx::BGX] = 0.04;
        ekf.x[idx::BGY] = 0.02;
        ekf.steps_without_fix = 0;
        assert_eq!(ekf.bias_learnt_unaided_rad_s(), 0.0, "a fix this step");
        ekf.steps_without_fix = 300;
        assert!((ekf.bias_learnt_unaided_rad_s() - 0.05).abs() < 1e-12);
        let mut off = Ekf::new(params(false), &level());
        off.steps_without_fix = 300;
        assert_eq!(off.bias_learnt_unaided_rad_s(), 0.0, "no bias states");
    }

    #[test]
    fn the_filters_jacobian_is_the_models_chain_rule_inside_the_fixed_structure() {
        let mut ekf = Ekf::new(params(true), &level());
        for (i, v) in [
            0.3, -0.2, 1.1, 0.05, -0.08, 1.9, 0.4, -0.3, 0.2, 0.1, -0.15, 0.07,
        ]
        .into_iter()
        .enumerate()
        {
            ekf.x[i] = v;
        }
        ekf.x[idx::BGX] = 0.01;
        ekf.x[idx::BGY] = -0.02;
        let u = [300.0, 310.0, 295.0, 305.0];
        let xm = ekf.model_state();
        let f = ekf.filter_jacobian(&jacobian(&xm, &u, 0.01, false));
        // Against finite differences of the filter's own step: model state, model, back.
        let h = 1e-6;
        let step = |x: &crate::core::ekf::FilterState| {
            let mut e = ekf.clone();
            e.x = *x;
            let next = crate::core::ekf::process(&e.model_state(), &u, 0.01, 1.55, false);
            e.set_model_state(&next);
            e.x
        };
        for j in 0..crate::core::ekf::N_STATES {
            let (mut xp, mut xn) = (ekf.x, ekf.x);
            xp[j] += h;
            xn[j] -= h;
            let col = (step(&xp) - step(&xn)) / (2.0 * h);
            for i in 0..crate::core::ekf::N_STATES {
                assert!(
                    (f[(i, j)] - col[i]).abs() < 1e-8,
                    "F[{i}][{j}] = {} but finite difference {}",
                    f[(i, j)],
                    col[i]
                );
                let d = f[(i, j)] - if i == j { 1.0 } else { 0.0 };
                assert!(
                    d == 0.0 || D_COLS[i].contains(&j),
                    "D[{i}][{j}] = {d} unlisted"
                );
            }
        }
    }

    #[test]
    fn without_bias_states_the_filter_is_the_models_and_the_bias_stays_zero() {
        let mut ekf = Ekf::new(params(false), &level());
        let mut tilted = level();
        tilted.euler_rad[0] = 0.02;
        tilted.gyro_rad_s = [0.01, 0.0, 0.0];
        for _ in 0..300 {
            ekf.step(&tilted, &StepInput::hover_10ms()).1.unwrap();
        }
        assert_eq!(ekf.gyro_bias_rad_s(), [0.0; 3]);
        for b in [idx::BGX, idx::BGY, idx::BGZ] {
            assert!(ekf.p.row(b).iter().all(|v| *v == 0.0), "row {b}");
        }
    }

    #[test]
    fn a_body_resting_on_the_ground_teaches_the_bias_within_a_second_and_a_turn_does_not() {
        let resting = |gyro_x_rad_s: f64, at_rest: bool| {
            let mut p = params(true);
            p.ground_fusion = true;
            let mut ekf = Ekf::new(p, &level());
            let mut sample = level();
            sample.gyro_rad_s = [gyro_x_rad_s, 0.0, 0.0];
            let input = StepInput {
                at_rest,
                ..StepInput::hover_10ms()
            };
            for _ in 0..100 {
                ekf.step(&sample, &input).1.unwrap();
            }
            ekf.gyro_bias_rad_s()[0]
        };
        // A bias step of 0.05 rad/s on the x gyro, the vehicle armed on the ground.
        let learnt = resting(0.05, true);
        assert!((learnt - 0.05).abs() < 0.005, "at rest: {learnt}");
        // In the air the angles teach it only over many seconds.
        let aloft = resting(0.05, false);
        assert!(aloft < 0.025, "not at rest: {aloft}");
        // A body turning at 0.5 rad/s is not resting: its turn is no bias.
        let turning = resting(0.5, true);
        assert!(turning.abs() < 0.05, "turning: {turning}");
    }

    #[test]
    fn a_biased_gyro_is_learnt_from_the_angles_and_the_attitude_held() {
        let mut ekf = Ekf::new(params(true), &level());
        // The body is level and still; the x gyro reads 0.05 rad/s.
        let mut biased = level();
        biased.gyro_rad_s = [0.05, 0.0, 0.0];
        for _ in 0..3000 {
            ekf.step(&biased, &StepInput::hover_10ms()).1.unwrap();
        }
        let b = ekf.gyro_bias_rad_s();
        assert!((b[0] - 0.05).abs() < 0.005, "bias {b:?}");
        assert!(b[1].abs() < 0.005 && b[2].abs() < 0.005, "bias {b:?}");
        assert!(
            ekf.x[idx::PSI].abs() < 0.01,
            "roll {} bias {b:?}",
            ekf.x[idx::PSI]
        );
        // The rate the controller sees is the body's.
        assert!(ekf.model_state()[idx::WQX].abs() < 0.005);
    }
}
