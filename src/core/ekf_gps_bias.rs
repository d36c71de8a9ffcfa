//! The GPS receiver's horizontal bias as two more filter states (`ekf.gps_bias_m`,
//! `ekf.gps_bias_tau_s`; a deviation of 0 leaves them out of everything, as the 2012 flights
//! had it). Only with `ekf.gps_fusion = "position-velocity"` (`core::ekf_fix`).
//!
//! A receiver's position error is mostly not new at each fix: a u-blox NEO-M8N's metres
//! wander over about a minute (the atmosphere, the satellites' geometry), and only a few
//! tenths of a metre are the fix's own noise. Not in the original's spec (3.5–3.7 fuse a fix
//! as white noise on the position): without a state for it the bias has two places, both wrong.
//! In the fixes' noise the filter doubts every fix by the whole bias, while the estimate sits
//! on it: the innovations are smaller than the filter says. In the position's process noise
//! each fix's own noise moves the position, and the vehicle flies it.
//!
//! With the states a fix reads the position plus the bias. The bias is a first-order
//! Gauss-Markov process: over a step it decays by exp(−dt/τ), and its variance is topped up
//! by σ²·(1 − exp(−2·dt/τ)), so that it holds σ² when nothing observes it. The position moves
//! only as the velocity says, which the fixes' Doppler velocity and the IMU hold. Nothing but
//! the fixes sees the bias, so the filter tells a bias from a position error only by what
//! its prior (0, σ²) and the time it is correlated over say: over a flight shorter than τ
//! the position's covariance keeps that doubt (about σ), shrinking over several τ as the
//! fixes' long average places the position - the truth of a single receiver.
//!
//! The first fix places the position and the bias together. The fix reads their sum to its
//! own noise, and the bias's prior splits it: the position takes the fix, with a variance of
//! the fix's noise plus σ²; the bias takes 0, with σ²; their covariance is −σ², so that their
//! sum is known to the fix's noise.

use crate::core::ekf::{Ekf, GpsFusion, N_STATES, idx};
use nalgebra::{Matrix3, SMatrix};

/// The bias states, north and west, with the position states whose fixes they offset.
const BIAS: [usize; 2] = [idx::BPX, idx::BPY];
const POSITION: [usize; 2] = [idx::X, idx::Y];

impl Ekf {
    /// The bias states take part: the profile gave the bias a deviation, and fuses fixes into
    /// position and velocity (the joint fusion has no bias column).
    pub(crate) fn gps_bias_on(&self) -> bool {
        self.params.gps_bias_m > 0.0 && self.params.gps_fusion == GpsFusion::PositionVelocity
    }

    /// The bias over a step of `dt_s`: P's bias rows and columns scale by exp(−dt/τ) (F's
    /// diagonal there; nothing else drives them), the variance is topped up towards σ². Before
    /// the first fix places it there is no bias to carry.
    pub(crate) fn receiver_bias_decay(&mut self, dt_s: f64) {
        if !self.gps_bias_on() || !self.fix_seen {
            return;
        }
        let phi = (-dt_s / self.params.gps_bias_tau_s).exp();
        let sigma2 = self.params.gps_bias_m * self.params.gps_bias_m;
        for b in BIAS {
            self.x[b] *= phi;
            for j in 0..N_STATES {
                self.p[(b, j)] *= phi;
                self.p[(j, b)] *= phi;
            }
            // The loop scaled the diagonal twice: φ², as F·P·Fᵀ does.
            self.p[(b, b)] += sigma2 * (1.0 - phi * phi);
        }
    }

    /// At the first fix, after its position was placed with the fix's noise: the bias takes
    /// its prior (0, σ²), the position the bias's doubt too, and their covariance −σ² (the fix
    /// knew their sum).
    pub(crate) fn place_receiver_bias(&mut self) {
        if !self.gps_bias_on() {
            return;
        }
        let sigma2 = self.params.gps_bias_m * self.params.gps_bias_m;
        for (pos, b) in POSITION.into_iter().zip(BIAS) {
            self.x[b] = 0.0;
            self.p.row_mut(b).fill(0.0);
            self.p.column_mut(b).fill(0.0);
            self.p[(b, b)] = sigma2;
            self.p[(pos, pos)] += sigma2;
            self.p[(pos, b)] = -sigma2;
            self.p[(b, pos)] = -sigma2;
        }
    }

    /// The observation's bias columns of a fix's horizontal position rows (`row` 0 north,
    /// 1 west): the state the row reads beside the position, when the bias is a state.
    pub(crate) fn fix_bias_column(&self, row: usize) -> Option<usize> {
        self.gps_bias_on().then(|| BIAS.get(row).copied()).flatten()
    }

    /// The learnt bias, north and west, m (0 without the states).
    pub fn receiver_bias_m(&self) -> [f64; 2] {
        BIAS.map(|b| self.x[b])
    }

    /// The variance of the horizontal position the fixes read, north or west (`axis` 0 or 1),
    /// m²: the position's own when the bias is no state. What "converged" means to a pre-arm
    /// check: with the states on, the position's own variance also holds the bias's doubt, which
    /// the fixes take away only over several correlation times.
    pub fn fix_frame_variance_m2(&self, axis: usize) -> f64 {
        debug_assert!(axis < 2, "axis {axis}");
        let axis = axis.min(1);
        let pos = POSITION[axis];
        match self.fix_bias_column(axis) {
            Some(b) => self.p[(pos, pos)] + 2.0 * self.p[(pos, b)] + self.p[(b, b)],
            None => self.p[(pos, pos)],
        }
    }

    /// The covariance of the position the fixes read (x and y plus the receiver's bias, and z),
    /// m²: what the fixes let the filter know of the position.
    pub fn fix_frame_position_covariance_m2(&self) -> Matrix3<f64> {
        let mut t = SMatrix::<f64, 3, N_STATES>::zeros();
        for (row, pos) in [idx::X, idx::Y, idx::Z].into_iter().enumerate() {
            t[(row, pos)] = 1.0;
            if let Some(b) = self.fix_bias_column(row) {
                t[(row, b)] = 1.0;
            }
        }
        t * self.p * t.transpose()
    }
}

#[cfg(test)]
mod tests {
    use crate::core::ekf::{Ekf, EkfParams, GpsFusion, StepInput, idx};
    use crate::core::gps::GpsSample;
    use crate::core::imu::calib::ImuSample;
    use crate::core::model::GRAVITY_M_S2;

    fn params(sigma_m: f64) -> EkfParams {
        let mut p = EkfParams::flight_2012();
        p.original_model = false;
        p.gps_fusion = GpsFusion::PositionVelocity;
        p.gate_fusion = true;
        p.r_gps_diag[9] = 0.49;
        p.r_gps_diag[10] = 0.49;
        // Process noise on the default profile's scale: the 2012 flights' (100 on the position and the
        // velocity, 1 on the accelerometer's states) would let the position go wherever a
        // fix says.
        p.q_diag = [
            1e-6, 1e-6, 1e-4, 1e-7, 1e-7, 2e-11, 1e-5, 1e-5, 1e-5, 0.01, 0.01, 0.1, 1e-2, 1e-2,
            1e-5,
        ];
        p.r_gps_vel = 0.0025;
        p.gps_bias_m = sigma_m;
        p.gps_bias_tau_s = 60.0;
        p
    }

    fn level() -> ImuSample {
        ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        }
    }

    fn fix(x_m: f64, y_m: f64) -> GpsSample {
        GpsSample {
            xy_m: [x_m, y_m],
            z_m: None,
            vel_m_s: Some([0.0; 3]),
        }
    }

    fn step(ekf: &mut Ekf, g: Option<GpsSample>) {
        let input = StepInput {
            gps: g,
            ..StepInput::hover_10ms()
        };
        let (_, r) = ekf.step(&level(), &input);
        assert_eq!(r, Ok(()));
    }

    #[test]
    fn the_first_fix_knows_the_sum_of_position_and_bias_to_its_own_noise() {
        let mut ekf = Ekf::new(params(2.0), &level());
        step(&mut ekf, Some(fix(3.0, -1.0)));
        assert_eq!((ekf.x[idx::X], ekf.x[idx::Y]), (3.0, -1.0));
        assert_eq!(ekf.receiver_bias_m(), [0.0, 0.0]);
        assert!((ekf.p[(idx::X, idx::X)] - (0.49 + 4.0)).abs() < 1e-9);
        assert_eq!(ekf.p[(idx::BPX, idx::BPX)], 4.0);
        let sum = ekf.fix_frame_position_covariance_m2();
        assert!((sum[(0, 0)] - 0.49).abs() < 1e-9, "{}", sum[(0, 0)]);
        assert!((sum[(1, 1)] - 0.49).abs() < 1e-9, "{}", sum[(1, 1)]);
        // A pre-arm check asks how well the fixes placed the position; the fence, how far it
        // may be from the truth.
        assert!((ekf.fix_frame_sigma_m() - 0.7).abs() < 1e-6);
        assert!((ekf.horizontal_sigma_m() - 4.49f64.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn unobserved_the_bias_decays_and_its_variance_holds_sigma_squared() {
        let mut ekf = Ekf::new(params(2.0), &level());
        step(&mut ekf, Some(fix(0.0, 0.0)));
        ekf.x[idx::BPX] = 1.0;
        // 60 s without fixes: one correlation time.
        for _ in 0..6000 {
            step(&mut ekf, None);
        }
        let b = ekf.receiver_bias_m()[0];
        assert!((b - (-1.0f64).exp()).abs() < 1e-3, "bias {b}");
        let var = ekf.p[(idx::BPX, idx::BPX)];
        assert!((var - 4.0).abs() < 1e-6, "variance {var}");
    }

    /// Fixes a second apart for `seconds` s, reading `at(second)` north, the velocity 0.
    fn fixes(ekf: &mut Ekf, seconds: u32, at: impl Fn(u32) -> f64) {
        for k in 0..seconds {
            step(ekf, Some(fix(at(k), 0.0)));
            for _ in 0..99 {
                step(ekf, None);
            }
        }
    }

    #[test]
    fn fixes_drifting_as_a_bias_does_move_the_position_less_than_without_the_states() {
        // Fixes still for 20 s, then wandering north at 3 cm a second for 30 s, as a
        // receiver's bias does, while their velocity says the vehicle is still (within the
        // velocity's own noise, so the model cannot tell the two apart: it shares them).
        let drift = |sigma_m: f64| {
            let mut ekf = Ekf::new(params(sigma_m), &level());
            fixes(&mut ekf, 20, |_| 0.0);
            fixes(&mut ekf, 30, |k| 0.03 * f64::from(k + 1));
            (ekf.x[idx::X], ekf.receiver_bias_m()[0])
        };
        let (moved_m, bias_m) = drift(2.0);
        let (moved_without_m, _) = drift(0.0);
        assert!(bias_m > 0.3, "bias {bias_m}");
        assert!(
            moved_m < 0.7 * moved_without_m,
            "x {moved_m}, without the states {moved_without_m}"
        );
        assert!(
            (moved_m + bias_m - 0.9).abs() < 0.15,
            "sum {}",
            moved_m + bias_m
        );
    }

    #[test]
    fn without_a_deviation_the_bias_states_stay_out_of_everything() {
        let mut ekf = Ekf::new(params(0.0), &level());
        step(&mut ekf, Some(fix(1.0, 2.0)));
        for _ in 0..10 {
            step(&mut ekf, Some(fix(1.5, 2.0)));
        }
        assert_eq!(ekf.receiver_bias_m(), [0.0, 0.0]);
        for b in [idx::BPX, idx::BPY] {
            assert!(ekf.p.row(b).iter().all(|v| *v == 0.0), "row {b}");
        }
    }
}
