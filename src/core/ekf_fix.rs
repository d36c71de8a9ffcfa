//! A GPS fix fused into position, velocity and tilt (`ekf.gps_fusion = "position-velocity"`),
//! after the step's IMU rows: its x, y, z (z left out without an altitude) and, when the
//! receiver gives one, its horizontal velocity (the body velocity turned by the estimated
//! attitude), and its vertical velocity while the barometer is lost. Not in the original's
//! spec (3.7 fuses a fix's position with the IMU rows into
//! every state): with a real receiver's metre-level errors that joint update explains a fix's
//! error partly as tilt and accelerometer bias, and the tilt it then reports is flown; and a
//! velocity learnt only from 1 Hz positions lags by half a second, which the position loop
//! cannot fly on. The position rows' gain is kept to position and velocity; the horizontal
//! velocity rows' gain reaches roll and pitch as well: a velocity the estimate did not
//! foresee grew from a tilt it did not see (the velocity aiding of PX4's and ArduPilot's
//! filters; the IMU's own angles read the thrust axis in flight, and the gyros' drift is
//! otherwise corrected by nothing). The covariance is updated in Joseph form (right for any
//! gain); the first fix places the position. Its
//! position rows and its horizontal velocity rows are gated apart (PX4 EKF2's separate
//! gates): a position outside its gate with a velocity inside is a multipath glitch, and the
//! velocity alone is fused; a velocity outside its gate is the estimate's own error, fused at
//! the gate's edge unless it is wild; the vertical velocity row is gated on its own. The
//! velocity rows reach the gyros' bias states too. With `ekf.gps_bias_m` the position rows
//! read x, y plus the receiver's bias, and both the position and the velocity rows reach the
//! bias states (`core::ekf_gps_bias`).

use crate::core::ekf::{
    Ekf, EkfError, GPS_ROWS, GatedGroups, N_STATES, StateMatrix, StepNis, TestRatios,
    UpdateOutcome, group_nis, idx,
};
use crate::core::gps::GpsSample;
use crate::core::math::rotation_portable;
use nalgebra::{SMatrix, SVector};

/// The states a fix's horizontal position rows correct, its horizontal velocity rows, and its
/// altitude row: the barometer owns the vertical, and a horizontal error must not move it (nor
/// the altitude the horizontal). The velocity rows reach the tilt and the gyros' bias it grew
/// from, the position rows do not (a receiver's metre-level bias read as tilt would be
/// flown); nor the accelerometer's states (their rows set them every step).
/// `HORIZONTAL` and `HORIZONTAL_SPEED` both reach the receiver's bias states (zero gain
/// without them: their covariance is zero).
const HORIZONTAL: [usize; 6] = [idx::X, idx::Y, idx::VQX, idx::VQY, idx::BPX, idx::BPY];
const HORIZONTAL_SPEED: [usize; 11] = [
    idx::X,
    idx::Y,
    idx::VQX,
    idx::VQY,
    idx::PSI,
    idx::PHI,
    idx::BGX,
    idx::BGY,
    idx::BGZ,
    idx::BPX,
    idx::BPY,
];
const VERTICAL: [usize; 2] = [idx::Z, idx::VQZ];
/// Rows: x, y, z, north, west and up velocity (the last only while the barometer is lost).
const ROWS: usize = 6;
/// A horizontal velocity whose test ratio is above 1 and at most this is fused at its gate's
/// edge; above it (five gate widths: 25 standard deviations of the innovation with the 5σ
/// gate) it is left out: a receiver's fault, or an estimate beyond saving by a fix.
const VELOCITY_CLIP_MAX_RATIO: f64 = 25.0;
/// The vertical velocity row's gain goes to the vertical speed alone: a correction of the
/// height at a fix is a step the altitude loop flies (a few tenths of a metre saturate it),
/// while the height integrated from a corrected speed moves smoothly.
const VERTICAL_SPEED: [usize; 1] = [idx::VQZ];

impl Ekf {
    /// Fuses fix `g` into position and velocity.
    pub(crate) fn fuse_fix(&mut self, g: &GpsSample) -> UpdateOutcome {
        let rg = self.params.r_gps_diag;
        let rv = self.params.r_gps_vel;
        let mut r = [
            rg[GPS_ROWS - 3],
            rg[GPS_ROWS - 2],
            rg[GPS_ROWS - 1],
            rv,
            rv,
            rv,
        ];
        let vel = g.vel_m_s.unwrap_or([f64::NAN; 3]);
        let z = [
            g.xy_m[0],
            g.xy_m[1],
            g.z_m.unwrap_or(f64::NAN),
            vel[0],
            vel[1],
            vel[2],
        ];
        // Rows without a measurement (no altitude, no velocity) are left out. The barometer
        // owns the vertical; without it the receiver's vertical velocity holds the vertical
        // speed (its altitude wanders by metres: a landing needs the speed, not the height).
        let mut used: [bool; ROWS] = [
            true,
            true,
            g.z_m.is_some(),
            g.vel_m_s.is_some(),
            g.vel_m_s.is_some(),
            self.baro_lost && vel[2].is_finite(),
        ];
        if (0..ROWS).any(|i| used[i] && !z[i].is_finite()) {
            return outcome(
                TestRatios::default(),
                false,
                Err(EkfError::NonFiniteMeasurement),
            );
        }
        if !self.fix_seen {
            self.fix_seen = true;
            self.place(&g.xy_m, &r[..2]);
            return outcome(TestRatios::default(), false, Ok(()));
        }
        let (h, mut y, mut pht, mut s) = self.innovation(&z, &r, &used);
        let gate_sq = self.params.gate_sigma * self.params.gate_sigma;
        let ratio_of = |rows: &[usize],
                        used: &[bool; ROWS],
                        y: &SVector<f64, ROWS>,
                        s: &SMatrix<f64, ROWS, ROWS>| {
            rows.iter()
                .filter(|&&i| used[i])
                .map(|&i| y[i] * y[i] / (gate_sq * s[(i, i)]))
                .fold(0.0f64, |m, v| if v > m || v.is_nan() { v } else { m })
        };
        let outside = |ratio: f64| self.params.gate_fusion && (ratio > 1.0 || ratio.is_nan());
        // The vertical velocity row (a lost barometer's stand-in) is gated on its own: a
        // climb's glitch must not move the only vertical reference left.
        if used[5] && outside(ratio_of(&[5], &used, &y, &s)) {
            drop_row(5, &mut used, &mut y, &mut pht, &mut s);
        }
        // The gps group: the horizontal position rows and the horizontal velocity rows, each
        // gated on its own as PX4 EKF2 gates them: a multipath jump moves the position while
        // the receiver's Doppler velocity stays good, and fusing it holds the vehicle still
        // through the glitch. The group's ratio is the larger.
        let pos_ratio = ratio_of(&[0, 1], &used, &y, &s);
        let vel_ratio = ratio_of(&[3, 4], &used, &y, &s);
        // Not a number (a covariance gone bad) in either: the group's ratio says so, and
        // with the gate on nothing of the fix is fused.
        let broken = pos_ratio.is_nan() || vel_ratio.is_nan();
        let ratio = if broken {
            f64::NAN
        } else {
            pos_ratio.max(vel_ratio)
        };
        let ratios = TestRatios {
            gps: Some(ratio),
            ..TestRatios::default()
        };
        let nis = group_nis(&y, &s, [0, 1, 3, 4].into_iter().filter(|&i| used[i]));
        let position_out = outside(pos_ratio);
        if position_out {
            for i in 0..3 {
                drop_row(i, &mut used, &mut y, &mut pht, &mut s);
            }
        }
        let velocity_ratio = used[3].then_some(vel_ratio);
        let velocity_out = used[3] && (outside(vel_ratio) || (broken && self.params.gate_fusion));
        if velocity_out && !broken && vel_ratio <= VELOCITY_CLIP_MAX_RATIO {
            // Outside its gate but not wild: the estimate's own error (a tilt, a gyro's bias
            // it has not learnt yet), which leaving the velocity out would let grow until the
            // fixes are lost - also while a multipath glitch holds the positions out (the
            // receiver's Doppler velocity stays good). Fused at the noise that puts it on the
            // gate's edge: the estimate moves less than a velocity on the edge would move it;
            // a velocity off by more (a receiver's fault) stays out.
            for i in [3, 4] {
                let edge = y[i] * y[i] / gate_sq;
                if edge > s[(i, i)] {
                    r[i] += edge - s[(i, i)];
                    s[(i, i)] = edge;
                }
            }
        } else if velocity_out {
            for i in [3, 4] {
                drop_row(i, &mut used, &mut y, &mut pht, &mut s);
            }
        }
        // Fused as a measurement, inside its gate: the velocity observed the vehicle.
        let velocity_fused = used[3] && !velocity_out;
        let judged = |result| UpdateOutcome {
            nis: StepNis {
                gps: nis,
                ..StepNis::default()
            },
            fix_velocity_fused: velocity_fused && result == Ok(()),
            fix_velocity_ratio: velocity_ratio,
            ..outcome(ratios, position_out, result)
        };
        if !used.iter().any(|&u| u) {
            return judged(Ok(()));
        }
        let Some(s_inv) = s.try_inverse() else {
            return judged(Err(EkfError::SingularInnovation));
        };
        let mut k = pht * s_inv;
        for st in 0..N_STATES {
            for c in 0..ROWS {
                let keep = match c {
                    2 => &VERTICAL[..],
                    5 => &VERTICAL_SPEED[..],
                    3 | 4 => &HORIZONTAL_SPEED[..],
                    _ => &HORIZONTAL[..],
                };
                if !keep.contains(&st) {
                    k[(st, c)] = 0.0;
                }
            }
        }
        self.x += k * y;
        self.joseph(&k, &h, &r, &used);
        judged(Ok(()))
    }

    /// H, the innovation, P·Hᵀ and S = H·P·Hᵀ + R over the rows `used` (the others zero, with
    /// a unit S so that it stays invertible).
    #[allow(clippy::type_complexity)]
    fn innovation(
        &self,
        z: &[f64; ROWS],
        r: &[f64; ROWS],
        used: &[bool; ROWS],
    ) -> (
        SMatrix<f64, ROWS, N_STATES>,
        SVector<f64, ROWS>,
        SMatrix<f64, N_STATES, ROWS>,
        SMatrix<f64, ROWS, ROWS>,
    ) {
        let h = self.observation(used);
        let y = SVector::<f64, ROWS>::from_fn(|i, _| {
            if used[i] {
                z[i] - (h.row(i) * self.x)[(0, 0)]
            } else {
                0.0
            }
        });
        let pht = self.p * h.transpose();
        let mut s = h * pht;
        for i in 0..ROWS {
            s[(i, i)] += if used[i] { r[i] } else { 1.0 };
        }
        (h, y, pht, s)
    }

    /// H: the position rows read x, y, z (x and y plus the receiver's bias when it is a state,
    /// `core::ekf_gps_bias`); the velocity rows (north, west, up) the body velocity
    /// turned by the estimated attitude (its partials in the angles, a velocity's metres a
    /// second times a tilt's error, are left out: the tilt is reached through its covariance
    /// with the velocity, which the model's g·sin(tilt) builds). Rows not used are zero.
    fn observation(&self, used: &[bool; ROWS]) -> SMatrix<f64, ROWS, N_STATES> {
        let mut h = SMatrix::<f64, ROWS, N_STATES>::zeros();
        for i in 0..3 {
            if used[i] {
                h[(i, i)] = 1.0;
                if let Some(b) = self.fix_bias_column(i) {
                    h[(i, b)] = 1.0;
                }
            }
        }
        let r = rotation_portable(self.x[idx::PSI], self.x[idx::PHI], self.x[idx::THETA]);
        for (row, rr) in r.iter().enumerate() {
            if used[3 + row] {
                for (j, v) in rr.iter().enumerate() {
                    h[(3 + row, idx::VQX + j)] = *v;
                }
            }
        }
        h
    }

    /// P = (I − K·H)·P·(I − K·H)ᵀ + K·R·Kᵀ over the rows used.
    fn joseph(
        &mut self,
        k: &SMatrix<f64, N_STATES, ROWS>,
        h: &SMatrix<f64, ROWS, N_STATES>,
        r: &[f64; ROWS],
        used: &[bool; ROWS],
    ) {
        let i_kh = StateMatrix::identity() - k * h;
        let mut krk = StateMatrix::zeros();
        for c in (0..ROWS).filter(|&c| used[c]) {
            let col = k.column(c);
            krk += col * col.transpose() * r[c];
        }
        self.p = i_kh * self.p * i_kh.transpose() + krk;
    }

    /// The first fix: the horizontal position is the fix's, its covariance the fix's noise,
    /// uncorrelated with the rest (the receiver's bias, when a state, splits it).
    fn place(&mut self, xy: &[f64; 2], r: &[f64]) {
        for (i, (&v, &ri)) in xy.iter().zip(r).enumerate() {
            self.x[i] = v;
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
            self.p[(i, i)] = ri;
        }
        self.place_receiver_bias();
    }
}

fn outcome(ratios: TestRatios, gps_gated: bool, result: Result<(), EkfError>) -> UpdateOutcome {
    UpdateOutcome {
        ratios,
        gated: GatedGroups {
            gps: gps_gated,
            ..GatedGroups::default()
        },
        nis: StepNis::default(),
        fix_velocity_fused: false,
        fix_velocity_ratio: None,
        result,
    }
}

/// Leaves row `i` out of an update already prepared: no innovation, no gain, a unit S row.
fn drop_row(
    i: usize,
    used: &mut [bool; ROWS],
    y: &mut SVector<f64, ROWS>,
    pht: &mut SMatrix<f64, N_STATES, ROWS>,
    s: &mut SMatrix<f64, ROWS, ROWS>,
) {
    used[i] = false;
    y[i] = 0.0;
    pht.column_mut(i).fill(0.0);
    s.row_mut(i).fill(0.0);
    s.column_mut(i).fill(0.0);
    s[(i, i)] = 1.0;
}

#[cfg(test)]
mod tests {
    use crate::core::ekf::{Ekf, EkfParams, GpsFusion, N_MODEL, StepInput, idx};
    use crate::core::gps::GpsSample;
    use crate::core::imu::calib::ImuSample;
    use crate::core::model::GRAVITY_M_S2;

    /// The model states' covariance (the bias states, off here, have none).
    fn model_block(ekf: &Ekf) -> nalgebra::SMatrix<f64, N_MODEL, N_MODEL> {
        ekf.p.fixed_view::<N_MODEL, N_MODEL>(0, 0).into_owned()
    }

    /// A level filter at rest, fusing fixes into position and velocity.
    fn filter() -> (Ekf, ImuSample, StepInput) {
        let mut p = EkfParams::flight_2012();
        p.original_model = false;
        p.gps_fusion = GpsFusion::PositionVelocity;
        p.q_diag[idx::X] = 1e-4;
        p.q_diag[idx::Y] = 1e-4;
        p.q_diag[idx::VQX] = 1e-4;
        p.q_diag[idx::VQY] = 1e-4;
        p.r_gps_diag[11] = 1e12;
        let still = ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        let ekf = Ekf::new(p, &still);
        let input = StepInput::hover_10ms();
        (ekf, still, input)
    }

    fn fix(x: f64, y: f64, vel: Option<[f64; 3]>) -> GpsSample {
        GpsSample {
            xy_m: [x, y],
            z_m: Some(5.0),
            vel_m_s: vel,
        }
    }

    /// [`filter`] with the gate `gate` and a 1 m² receiver (x, y), its first fix `first`
    /// fused (which places the position).
    fn placed(gate: bool, first: GpsSample) -> (Ekf, ImuSample, StepInput) {
        let (mut ekf, still, mut input) = filter();
        ekf.params.gate_fusion = gate;
        ekf.params.r_gps_diag[9] = 1.0;
        ekf.params.r_gps_diag[10] = 1.0;
        input.gps = Some(first);
        ekf.step(&still, &input).1.unwrap();
        (ekf, still, input)
    }

    #[test]
    fn without_the_barometer_the_fixes_hold_the_vertical_and_nothing_is_refused() {
        let (mut ekf, still, mut input) = filter();
        for k in 0..300 {
            input.gps = (k % 100 == 0).then(|| fix(0.0, 0.0, Some([0.0; 3])));
            ekf.step(&still, &input).1.unwrap();
        }
        assert!(!ekf.baro_lost);
        // The barometer goes (not a number): the step goes on without it, its ratio says so.
        let mut no_baro = still;
        no_baro.alt_m = f64::NAN;
        input.gps = None;
        let (rep, res) = ekf.step(&no_baro, &input);
        assert_eq!(res, Ok(()));
        assert!(rep.ratios.altitude.is_nan() && rep.gated.altitude && ekf.baro_lost);
        assert!(ekf.p[(idx::Z, idx::Z)] < 0.2, "the height it left is kept");
        // A fix climbing at 1 m/s, its receiver reading 5 m: the vertical speed follows it,
        // the height does not step (it follows the speed from then on).
        let z_before = ekf.x[idx::Z];
        input.gps = Some(fix(0.0, 0.0, Some([0.0, 0.0, 1.0])));
        ekf.step(&no_baro, &input).1.unwrap();
        assert!(ekf.x[idx::VQZ] > 0.5, "vertical speed {}", ekf.x[idx::VQZ]);
        assert!(
            (ekf.x[idx::Z] - z_before).abs() < 0.05,
            "height {}",
            ekf.x[idx::Z]
        );
        input.gps = None;
        for _ in 0..100 {
            ekf.step(&no_baro, &input).1.unwrap();
        }
        assert!(ekf.x[idx::Z] > z_before + 0.3, "height {}", ekf.x[idx::Z]);
        // With the original's joint fusion the same step is refused, as it always was.
        let (mut joint, _, mut input) = filter();
        joint.params.gps_fusion = GpsFusion::Joint;
        input.gps = None;
        let (_, res) = joint.step(&no_baro, &input);
        assert_eq!(res, Err(crate::core::ekf::EkfError::NonFiniteMeasurement));
    }

    #[test]
    fn the_first_fix_places_the_position_and_a_later_position_leaves_the_attitude_alone() {
        let (mut ekf, still, mut input) = filter();
        input.gps = Some(fix(3.0, -2.0, None));
        let (_, res) = ekf.step(&still, &input);
        res.unwrap();
        assert_eq!([ekf.x[idx::X], ekf.x[idx::Y]], [3.0, -2.0]);
        // A second fix 2 m off, without a velocity: the position moves, attitude, rates,
        // biases and the altitude do not.
        for _ in 0..100 {
            input.gps = None;
            ekf.step(&still, &input).1.unwrap();
        }
        let before = ekf.x;
        input.gps = Some(fix(5.0, -2.0, None));
        ekf.step(&still, &input).1.unwrap();
        assert!(ekf.x[idx::X] > before[idx::X] + 0.01, "{}", ekf.x[idx::X]);
        for s in [
            idx::PSI,
            idx::PHI,
            idx::THETA,
            idx::Z,
            idx::VQZ,
            idx::BAX,
            idx::BAY,
        ] {
            assert!(
                (ekf.x[s] - before[s]).abs() < 1e-3,
                "state {s}: {} vs {}",
                ekf.x[s],
                before[s]
            );
        }
        // The covariance stays symmetric and positive definite.
        assert!((ekf.p - ekf.p.transpose()).norm() < 1e-9 * ekf.p.norm());
        assert!(model_block(&ekf).cholesky().is_some());
    }

    #[test]
    fn a_velocity_the_estimate_did_not_foresee_corrects_the_tilt_it_grew_from() {
        let (mut ekf, still, mut input) = filter();
        input.gps = Some(fix(0.0, 0.0, Some([0.0; 3])));
        ekf.step(&still, &input).1.unwrap();
        // A second of the still model builds the velocity's covariance with the tilt.
        for _ in 0..100 {
            input.gps = None;
            ekf.step(&still, &input).1.unwrap();
        }
        let before = ekf.x;
        // 0.2 m/s north where the estimate holds still: roll and pitch move so that the
        // model's g·sin(tilt) would have accelerated the body north (+x at zero yaw: +φ),
        // the yaw and the accelerometer's states stay.
        input.gps = Some(fix(0.0, 0.0, Some([0.2, 0.0, 0.0])));
        ekf.step(&still, &input).1.unwrap();
        assert!(
            ekf.x[idx::VQX] > before[idx::VQX] + 0.05,
            "{}",
            ekf.x[idx::VQX]
        );
        assert!(
            ekf.x[idx::PHI] > before[idx::PHI] + 1e-4,
            "pitch {}",
            ekf.x[idx::PHI]
        );
        for s in [idx::THETA, idx::BAX, idx::BAY] {
            assert!((ekf.x[s] - before[s]).abs() < 1e-9, "state {s}");
        }
        assert!(model_block(&ekf).cholesky().is_some());
    }

    #[test]
    fn a_fix_far_outside_the_gate_is_left_out() {
        let (mut ekf, still, mut input) = placed(true, fix(0.0, 0.0, None));
        input.gps = Some(fix(500.0, 0.0, None));
        let (rep, _) = ekf.step(&still, &input);
        assert!(rep.gated.gps && rep.ratios.gps.is_some_and(|r| r > 1.0));
        assert!(ekf.x[idx::X].abs() < 1e-6);
        // A fix left out counts as none: the steps without a fix go on (the drag's hold).
        assert_eq!(ekf.steps_without_fix, 1);
        input.gps = None;
        ekf.step(&still, &input).1.unwrap();
        input.gps = Some(fix(500.0, 0.0, None));
        ekf.step(&still, &input).1.unwrap();
        assert_eq!(ekf.steps_without_fix, 3);
        input.gps = Some(fix(0.0, 0.0, None));
        let (rep, _) = ekf.step(&still, &input);
        assert!(!rep.gated.gps && ekf.steps_without_fix == 0);
        // With the drag holding the velocity (no fix fused for long), a fix left out does not
        // turn it off for its step: the drag's bias stays tied (no profile noise of 1 added).
        ekf.params.drag_per_s = 0.065;
        ekf.steps_without_fix = crate::core::ekf_drag::DRAG_AFTER_STEPS + 5;
        input.gps = Some(fix(500.0, 0.0, None));
        let before = ekf.p[(idx::BAX, idx::BAX)];
        let (rep, _) = ekf.step(&still, &input);
        assert!(rep.gated.gps && ekf.drag_modelled());
        assert!(
            ekf.p[(idx::BAX, idx::BAX)] < before + 0.01,
            "{before} -> {}",
            ekf.p[(idx::BAX, idx::BAX)]
        );
    }

    #[test]
    fn a_position_jump_with_a_consistent_velocity_fuses_the_velocity_alone() {
        let (mut ekf, still, mut input) = placed(true, fix(0.0, 0.0, Some([0.0; 3])));
        // A multipath jump: the position 500 m off, the velocity still 0.2 m/s north.
        input.gps = Some(fix(500.0, 0.0, Some([0.2, 0.0, 0.0])));
        let (rep, _) = ekf.step(&still, &input);
        assert!(rep.gated.gps && rep.fix_velocity_fused);
        assert!(rep.fix_velocity_ratio.is_some_and(|r| r < 1.0));
        assert!(ekf.x[idx::X].abs() < 0.1, "{}", ekf.x[idx::X]);
        assert!(ekf.x[idx::VQX] > 0.01, "{}", ekf.x[idx::VQX]);
        // The velocity observed the vehicle: the drag's hold is not needed.
        assert_eq!(ekf.steps_without_fix, 0);
        // Both out of their gates, the velocity wildly: nothing fused, each ratio above 1.
        input.gps = Some(fix(500.0, 0.0, Some([50.0, 0.0, 0.0])));
        let (rep, _) = ekf.step(&still, &input);
        assert!(rep.gated.gps && !rep.fix_velocity_fused);
        assert!(rep.fix_velocity_ratio.is_some_and(|r| r > 1.0));
        assert_eq!(ekf.steps_without_fix, 1);
    }

    #[test]
    fn a_velocity_outside_its_gate_moves_the_estimate_less_than_one_on_its_edge() {
        let (mut ekf, still, mut input) = placed(true, fix(0.0, 0.0, Some([0.0; 3])));
        for _ in 0..100 {
            input.gps = None;
            ekf.step(&still, &input).1.unwrap();
        }
        // The north velocity that lands on the gate's edge, found by its ratio (1 at the edge).
        let ratio_of = |v: f64| {
            let mut e = ekf.clone();
            let mut i = input;
            i.gps = Some(fix(0.0, 0.0, Some([v, 0.0, 0.0])));
            let (rep, res) = e.step(&still, &i);
            res.unwrap();
            (
                rep.fix_velocity_ratio.unwrap(),
                rep.fix_velocity_fused,
                e.x[idx::VQX],
            )
        };
        let edge_m_s = 1.0 / ratio_of(1.0).0.sqrt();
        let (r_edge, in_edge, moved_edge) = ratio_of(0.999 * edge_m_s);
        assert!(r_edge < 1.0 && in_edge);
        let (r2, in2, moved2) = ratio_of(2.0 * edge_m_s);
        let (r4, in4, moved4) = ratio_of(4.0 * edge_m_s);
        assert!(r2 > 3.9 && r4 > 15.9 && r4 < 25.0, "{r2} {r4}");
        // Fused, though not counted as a velocity inside its gate.
        assert!(!in2 && !in4);
        assert!(moved2 > 0.0 && moved4 > 0.0, "{moved2} {moved4}");
        // Never further than the edge's, and the wilder the less.
        assert!(
            moved2 < moved_edge && moved4 < moved2,
            "{moved_edge} {moved2} {moved4}"
        );
        // Far outside (a receiver's fault): left out.
        let (r_wild, _, moved_wild) = ratio_of(6.0 * edge_m_s);
        assert!(
            r_wild > 25.0 && moved_wild.abs() < 1e-3 * moved4,
            "{moved_wild}"
        );
    }

    #[test]
    fn with_gating_off_a_jumped_fix_is_fused_whole_and_its_height_with_it() {
        let (mut ekf, still, mut input) = placed(false, fix(0.0, 0.0, Some([0.0; 3])));
        ekf.params.r_gps_diag[11] = 1.0;
        let z_before = ekf.x[idx::Z];
        input.gps = Some(fix(500.0, 0.0, Some([0.2, 0.0, 0.0])));
        let (rep, _) = ekf.step(&still, &input);
        assert!(!rep.gated.gps && rep.fix_velocity_fused);
        assert!(rep.ratios.gps.is_some_and(|r| r > 1.0));
        assert!(ekf.x[idx::X] > 100.0, "{}", ekf.x[idx::X]);
        // The fix's height (5 m) pulled the height too: its row was not left out.
        assert!(
            ekf.x[idx::Z] > z_before + 0.1,
            "{z_before} -> {}",
            ekf.x[idx::Z]
        );
        // Gated, the same jump leaves the height alone with the position.
        let (mut gated, still, mut input) = placed(true, fix(0.0, 0.0, Some([0.0; 3])));
        gated.params.r_gps_diag[11] = 1.0;
        let z_before = gated.x[idx::Z];
        input.gps = Some(fix(500.0, 0.0, Some([0.2, 0.0, 0.0])));
        let (rep, _) = gated.step(&still, &input);
        assert!(rep.gated.gps && rep.fix_velocity_fused);
        assert!(
            (gated.x[idx::Z] - z_before).abs() < 0.05,
            "{}",
            gated.x[idx::Z]
        );
    }
}
