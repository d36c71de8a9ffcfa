//! Roll, pitch and yaw torque-disturbance observer: an addition to the original's controller
//! (spec 4.4), built on the EKF's own rate model (spec 3.2–3.3, rows wqx, wqy and wqz) and
//! the IMU pre-filter's delay (spec 2.3).
//!
//! Why: the state-feedback controller integrates x, y (or ψ, φ) errors, so a steady torque —
//! a weak motor, an off-centre payload — is cancelled only after it has tilted the vehicle
//! long enough to move it. A tilt that lasts is also a tilt the filter loses: the roll and
//! pitch the IMU derives from its accelerometer read the thrust axis, not the vertical, while
//! the vehicle accelerates. The observer compares the body rates the filter estimates with the
//! rates the model predicts from the previous estimate and the motor speeds sent, low-passes
//! the difference (the unexplained angular acceleration) and commands the motor speed changes
//! that cancel it: the torque is taken out within a few time constants, before the vehicle
//! has tilted much.
//!
//! Pure and deterministic: the same estimates and commands give the same corrections, so a
//! replay reproduces a flight flown with it.

use crate::core::ekf::{Input, State, idx, process};
use crate::core::imu::filter::{FIR_LEN, FIR_TAPS};
use crate::core::model::{
    ARM_LENGTH_M, F_B1, F_B2, IXX_KG_M2, IYY_KG_M2, IZZ_KG_M2, M_D1, M_D2, MotorLimits,
};

/// Largest disturbance the observer answers, rad/s². The motors, ±(w_max − w_hover) around
/// hover on opposite arms, make at most about 45 rad/s² about x or y; a larger estimate is a
/// model error (ground contact, a crash), not a torque to cancel.
pub const MAX_DISTURBANCE_RAD_S2: f64 = 40.0;

/// Taps of the delay between a torque and the rates the filter reports, newest step first:
/// the front end's FIR (spec 2.3) after half a period, as the IMU samples on average half a
/// frame period before its frame is decoded and the command that follows goes out.
const DELAY_TAPS: usize = FIR_LEN + 1;
const DELAY: [f64; DELAY_TAPS] = {
    let mut d = [0.0; DELAY_TAPS];
    let mut k = 0;
    while k < FIR_LEN {
        d[k] += 0.5 * FIR_TAPS[k];
        d[k + 1] += 0.5 * FIR_TAPS[k];
        k += 1;
    }
    d
};

/// The observer's state.
#[derive(Debug, Clone, PartialEq)]
pub struct TorqueObserver {
    /// Low-pass time constant, s.
    tau_s: f64,
    /// The motors' first-order time constant, s: the speeds that make the torque lag the
    /// commands, and a lag the observer did not model would read as a disturbance that
    /// opposes every command, and be cancelled by amplifying it.
    motor_tau_s: f64,
    /// The motors' modelled speeds, rad/s (None until the first command).
    w_model: Option<Input>,
    /// The model's angular accelerations about x and y of the last steps, newest first,
    /// rad/s²: the filter's rates come from gyro readings that the IMU front end's FIR
    /// delays, so the model's accelerations go through the same delay before they are
    /// compared.
    a_model_rad_s2: [[f64; 3]; DELAY_TAPS],
    /// Model accelerations taken so far (saturating at DELAY_TAPS).
    n_model: usize,
    /// Estimated unexplained angular acceleration about body x, y and z, rad/s².
    d_rad_s2: [f64; 3],
    /// The previous estimate, its time (µs) and the motor speeds sent after it.
    prev: Option<(State, i64, Input)>,
}

impl TorqueObserver {
    pub fn new(tau_s: f64, motor_tau_s: f64) -> Self {
        TorqueObserver {
            tau_s,
            motor_tau_s,
            w_model: None,
            a_model_rad_s2: [[0.0; 3]; DELAY_TAPS],
            n_model: 0,
            d_rad_s2: [0.0; 3],
            prev: None,
        }
    }

    /// The current estimate, rad/s² about body x, y and z.
    pub fn disturbance_rad_s2(&self) -> [f64; 3] {
        self.d_rad_s2
    }

    /// Takes the estimate `x` at `t_us` and updates the disturbance from what the model
    /// predicted since the previous one. `mass_kg` only feeds the model's vertical row.
    pub fn observe(&mut self, x: &State, t_us: i64, mass_kg: f64) {
        let Some((x_prev, t_prev_us, u_prev)) = &self.prev else {
            return;
        };
        let dt_s = (t_us - t_prev_us) as f64 / 1e6;
        if !(dt_s > 0.0 && dt_s < 1.0) {
            // A gap (or a clock step) says nothing about the torque; start again from here.
            self.prev = None;
            self.w_model = None;
            self.n_model = 0;
            return;
        }
        // The motors move toward what was sent; the torque over the step is the one at the
        // speeds they reach (exact for a constant command, and the model's own resolution).
        let lag = 1.0 - (-dt_s / self.motor_tau_s.max(1e-6)).exp();
        let w = self.w_model.get_or_insert(*u_prev);
        for (wm, u) in w.iter_mut().zip(u_prev) {
            *wm += lag * (u - *wm);
        }
        let predicted = process(x_prev, w, dt_s, mass_kg, false);
        let rows = [idx::WQX, idx::WQY, idx::WQZ];
        let a_model: [f64; 3] =
            std::array::from_fn(|i| (predicted[rows[i]] - x_prev[rows[i]]) / dt_s);
        if !a_model.iter().all(|a| a.is_finite()) {
            return;
        }
        self.a_model_rad_s2.rotate_right(1);
        self.a_model_rad_s2[0] = a_model;
        if self.n_model == 0 {
            // No history yet: the motors have been where they are.
            self.a_model_rad_s2 = [a_model; DELAY_TAPS];
        }
        self.n_model = (self.n_model + 1).min(DELAY_TAPS);
        let alpha = dt_s / (self.tau_s + dt_s);
        for (i, (d, row)) in self.d_rad_s2.iter_mut().zip(rows).enumerate() {
            let a_delayed: f64 = DELAY
                .iter()
                .zip(&self.a_model_rad_s2)
                .map(|(h, a)| h * a[i])
                .sum();
            let residual = (x[row] - x_prev[row]) / dt_s - a_delayed;
            if residual.is_finite() {
                *d = (*d + alpha * (residual - *d))
                    .clamp(-MAX_DISTURBANCE_RAD_S2, MAX_DISTURBANCE_RAD_S2);
            }
        }
    }

    /// Remembers the estimate `x` at `t_us` and the speeds sent after it, for the next
    /// [`TorqueObserver::observe`].
    pub fn sent(&mut self, x: &State, t_us: i64, w_sent: &Input) {
        self.prev = Some((*x, t_us, *w_sent));
    }

    /// The motor speed changes (rad/s, m0..m3) that cancel the disturbance around hover.
    /// For roll and pitch, opposite arms move by equal and opposite thrust, so the total
    /// thrust and, to first order, the yaw torque stay as they were (model spec 3.2: roll from
    /// m1 − m3, pitch from m2 − m0); for yaw, one pair speeds up as the other slows down.
    pub fn correction_rad_s(&self, limits: &MotorLimits) -> Input {
        // dT/dw at hover, N per rad/s (positive above 11 rad/s, far below any hover speed).
        let dthrust = 2.0 * F_B1 * limits.w_hover_rad_s + F_B2;
        if dthrust.is_nan() || dthrust <= 0.0 {
            return [0.0; 4];
        }
        // dQ/dw at hover, N·m per rad/s.
        let ddrag = 2.0 * M_D1 * limits.w_hover_rad_s + M_D2;
        if ddrag.is_nan() || ddrag <= 0.0 {
            return [0.0; 4];
        }
        // Thrust change on each arm of the pair that gives −d: I·(−d) = L·2·ΔT.
        let roll_n = -IXX_KG_M2 * self.d_rad_s2[0] / (2.0 * ARM_LENGTH_M);
        let pitch_n = -IYY_KG_M2 * self.d_rad_s2[1] / (2.0 * ARM_LENGTH_M);
        // Drag-torque change of each motor that gives −d about z: m0, m2 against m1, m3
        // (ẇz = −(Q0 − Q1 + Q2 − Q3)/Izz), so the thrusts cancel to first order.
        let yaw_nm = IZZ_KG_M2 * self.d_rad_s2[2] / 4.0;
        [
            -pitch_n / dthrust + yaw_nm / ddrag,
            roll_n / dthrust - yaw_nm / ddrag,
            pitch_n / dthrust + yaw_nm / ddrag,
            -roll_n / dthrust - yaw_nm / ddrag,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::model::{W_MAX_2012_RAD_S, thrust_n, w_hover_rad_s};

    const MASS_KG: f64 = 1.55;

    fn hover() -> (State, Input, MotorLimits) {
        let mut x = State::zeros();
        x[idx::Z] = 1.0;
        let w_h = w_hover_rad_s(MASS_KG);
        (x, [w_h; 4], MotorLimits::new(MASS_KG, W_MAX_2012_RAD_S))
    }

    #[test]
    fn a_true_model_leaves_nothing_to_cancel() {
        let (x, u, limits) = hover();
        let mut o = TorqueObserver::new(0.05, 1e-6);
        let mut x_k = x;
        for k in 0..200 {
            o.sent(&x_k, k * 10_000, &u);
            x_k = process(&x_k, &u, 0.01, MASS_KG, false);
            o.observe(&x_k, (k + 1) * 10_000, MASS_KG);
        }
        assert!(o.disturbance_rad_s2().iter().all(|d| d.abs() < 1e-9));
        assert!(o.correction_rad_s(&limits).iter().all(|w| w.abs() < 1e-6));
    }

    #[test]
    fn a_weak_motor_is_found_and_cancelled() {
        // m0 gives 70 % of its thrust: the true pitch acceleration is L·(T2 − 0.7·T0)/Iyy more
        // than the model's. Closed loop with the plant: the observer's correction goes into
        // the speeds sent, and the pitch rate settles with the torque cancelled.
        let (x0, u_hover, limits) = hover();
        let mut o = TorqueObserver::new(0.05, 1e-6);
        let mut x = x0;
        let mut t_us = 0;
        for _ in 0..300 {
            let c = o.correction_rad_s(&limits);
            let u: Input = std::array::from_fn(|m| u_hover[m] + c[m]);
            o.sent(&x, t_us, &u);
            // The plant: the model with m0's thrust scaled (the rate row only).
            let mut next = process(&x, &u, 0.01, MASS_KG, false);
            let lost_n = 0.3 * thrust_n(u[0]);
            next[idx::WQY] += 0.01 * ARM_LENGTH_M * lost_n / IYY_KG_M2;
            // Only the rotation matters here; keep the vehicle level to isolate the rates.
            next[idx::PSI] = 0.0;
            next[idx::PHI] = 0.0;
            x = next;
            t_us += 10_000;
            o.observe(&x, t_us, MASS_KG);
        }
        let expected = ARM_LENGTH_M * 0.3 * thrust_n(u_hover[0]) / IYY_KG_M2;
        let d = o.disturbance_rad_s2();
        // Roll and yaw see only the gyroscopic coupling of the pitch rate: next to nothing.
        assert!(
            d[0].abs() < 0.01 * d[1] && d[2].abs() < 0.01 * d[1],
            "{d:?}"
        );
        // Cancelling it takes more than the lost torque: m0 answers with 70 % of its change.
        assert!(
            d[1] > expected && d[1] < 1.5 * expected,
            "{d:?} vs {expected}"
        );
        // The pitch rate has all but stopped growing: what is left of the torque is the
        // linearisation's error, under 2 % of the loss.
        let before = x[idx::WQY];
        let c = o.correction_rad_s(&limits);
        let u: Input = std::array::from_fn(|m| u_hover[m] + c[m]);
        let mut next = process(&x, &u, 0.01, MASS_KG, false);
        next[idx::WQY] += 0.01 * ARM_LENGTH_M * 0.3 * thrust_n(u[0]) / IYY_KG_M2;
        let uncorrected = 0.01 * expected;
        let left = (next[idx::WQY] - before).abs();
        assert!(
            left < 0.02 * uncorrected,
            "{left} of {uncorrected} rad/s per step"
        );
        // m0 speeds up and m2 slows down; m1 and m3 all but stay.
        assert!(c[0] > 0.0 && c[2] < 0.0, "{c:?}");
        assert!(
            c[1].abs() < 0.02 * c[0] && c[3].abs() < 0.02 * c[0],
            "{c:?}"
        );
    }

    #[test]
    fn implausible_residuals_are_bounded_and_gaps_restart() {
        let (x, u, _) = hover();
        let mut o = TorqueObserver::new(0.01, 1e-6);
        o.sent(&x, 0, &u);
        let mut spun = x;
        spun[idx::WQX] = 1e6;
        o.observe(&spun, 10_000, MASS_KG);
        assert_eq!(o.disturbance_rad_s2()[0], MAX_DISTURBANCE_RAD_S2);
        // A non-finite estimate changes nothing.
        o.sent(&x, 10_000, &u);
        let mut nan = x;
        nan[idx::WQY] = f64::NAN;
        o.observe(&nan, 20_000, MASS_KG);
        assert_eq!(o.disturbance_rad_s2()[1], 0.0);
        // A 2 s gap: no update, and the next call has nothing to compare with.
        let d = o.disturbance_rad_s2();
        o.sent(&x, 20_000, &u);
        o.observe(&spun, 2_020_000, MASS_KG);
        assert_eq!(o.disturbance_rad_s2(), d);
        assert!(o.prev.is_none());
    }
}
