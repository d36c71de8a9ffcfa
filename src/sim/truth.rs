//! The estimate against the truth: at every Kalman step of a simulation, the true state in the
//! estimate's convention (`truth.log`), and the figures that say how far the estimate is from
//! it (`est_error`) and whether the filter's own covariance says so (`ekf_consistency`).
//!
//! Consistency is judged as in Bar-Shalom's tests: the normalised estimation error squared
//! (NEES, eᵀ·P⁻¹·e over a block of states) and the normalised innovation squared (NIS, per
//! measurement group) of a consistent filter follow chi-square laws with the block's
//! dimension; a step is inside when its value lies between the law's 2.5 % and 97.5 %
//! quantiles (0.95 of the steps for a perfectly consistent filter).
//!
//! The receiver's wandering bias is observable by the filter only through its fading (nothing
//! but the fixes sees the horizontal position; its states, `core::ekf_gps_bias`): the position NEES is taken in the frame the fixes are in — the
//! true position plus the receiver's current bias, against the estimate's position plus its
//! own bias states when it has them (`core::ekf_gps_bias`), with that sum's covariance — and
//! only once a fix has placed the position. `est_error` is against the truth alone: it holds
//! the bias.

use crate::core::ekf::{Ekf, Nis, idx};
use crate::core::flight::Estimate;
use crate::core::math::wrap_pi;
use crate::sim::physics::Plant;
use serde::Serialize;

/// The file in the run folder: per Kalman step, the time (s, as kalman_in.log's) and the true
/// x y z (m), ψ φ θ
/// (rad), body velocities (m/s), body rates (rad/s), then the receiver's bias north, west, up
/// (m) where the estimate has its accelerometer biases.
pub const FILE: &str = "truth.log";

/// Two-sided 95 % bounds of the chi-square law with 1 to 4 degrees of freedom: its 2.5 % and
/// 97.5 % quantiles (standard tables).
const CHI2_95: [(f64, f64); 4] = [
    (0.000_982, 5.024),
    (0.050_6, 7.378),
    (0.215_8, 9.348),
    (0.484_4, 11.143),
];

/// Where a value lies against the two-sided 95 % bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bounds {
    /// Under the lower bound: the error is smaller than the covariance says (the filter is
    /// too cautious).
    Below,
    Inside,
    /// Over the upper bound: the filter is too sure of itself.
    Above,
}

/// Where `value` with `dof` degrees of freedom lies; `None` for a dimension without bounds
/// or a value that is not a number.
pub fn bounds_95(value: f64, dof: u8) -> Option<Bounds> {
    let &(lo, hi) = CHI2_95.get(usize::from(dof).wrapping_sub(1))?;
    if value.is_nan() {
        return None;
    }
    Some(if value < lo {
        Bounds::Below
    } else if value > hi {
        Bounds::Above
    } else {
        Bounds::Inside
    })
}

/// Whether `value` with `dof` degrees of freedom lies inside the two-sided 95 % bounds.
pub fn inside_95(value: f64, dof: u8) -> bool {
    bounds_95(value, dof) == Some(Bounds::Inside)
}

/// The mean of a normalised error and the fraction of steps inside its 95 % bounds; both
/// null when no step was judged (no fix fused, say): not a filter failing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ChiFigure {
    /// Over the steps with a finite value.
    pub mean: Option<f64>,
    /// Over every step judged; a step whose value is not finite is never inside.
    pub in_95: Option<f64>,
    /// The fractions under the lower bound (the filter too cautious) and over the upper one
    /// (too sure), over the same steps: with `in_95`, they say which way a filter fails.
    pub below_95: Option<f64>,
    pub above_95: Option<f64>,
    /// Steps judged, and those among them whose value was not finite (a covariance that
    /// could not be inverted).
    pub steps: u64,
    pub failed: u64,
}

#[derive(Debug, Clone, Copy, Default)]
struct ChiSum {
    sum: f64,
    inside: u64,
    below: u64,
    above: u64,
    finite: u64,
    failed: u64,
}

impl ChiSum {
    fn add(&mut self, value: f64, dof: u8) {
        if !value.is_finite() {
            self.failed += 1;
            return;
        }
        self.sum += value;
        match bounds_95(value, dof) {
            Some(Bounds::Inside) => self.inside += 1,
            Some(Bounds::Below) => self.below += 1,
            Some(Bounds::Above) => self.above += 1,
            None => {}
        }
        self.finite += 1;
    }

    fn figure(&self) -> ChiFigure {
        let steps = self.finite + self.failed;
        let share = |n: u64| (steps > 0).then(|| n as f64 / steps as f64);
        ChiFigure {
            mean: (self.finite > 0).then(|| self.sum / self.finite as f64),
            in_95: share(self.inside),
            below_95: share(self.below),
            above_95: share(self.above),
            steps,
            failed: self.failed,
        }
    }
}

/// NEES per block of states.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct NeesFigures {
    pub position: ChiFigure,
    pub velocity: ChiFigure,
    pub attitude: ChiFigure,
}

/// NIS per measurement group.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct NisFigures {
    pub attitude: ChiFigure,
    pub altitude: ChiFigure,
    pub gps: ChiFigure,
}

/// The report's `ekf_consistency`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Consistency {
    pub nees: NeesFigures,
    pub nis: NisFigures,
}

/// The report's `est_error`: the estimate against the truth over every Kalman step.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EstError {
    /// 3-D position error, RMS and largest, m.
    pub position_rms_m: f64,
    pub position_max_m: f64,
    /// Body-frame velocity error, RMS of its norm, m/s.
    pub velocity_rms_m_s: f64,
    /// Euler angle error (each wrapped to ±π), RMS of its norm, rad.
    pub attitude_rms_rad: f64,
    pub steps: u64,
}

/// truth.log's row for the vehicle `plant` and the simulated receiver's bias (north, west,
/// up, m; zero without a receiver).
pub fn row(plant: &Plant, receiver_bias_m: Option<[f64; 3]>) -> [f64; 15] {
    let bias_m = receiver_bias_m.unwrap_or_default();
    std::array::from_fn(|i| match i {
        0..12 => plant.x[i],
        _ => bias_m[i - 12],
    })
}

/// The figures over every Kalman step.
#[derive(Debug, Default)]
pub struct TruthTrace {
    pos_sq: f64,
    pos_max: f64,
    vel_sq: f64,
    att_sq: f64,
    n: u64,
    nees: [ChiSum; 3],
    nis: [ChiSum; 3],
}

/// eᵀ·P⁻¹·e over the three states from `first`; NaN when the block is not invertible.
fn nees3(ekf: &Ekf, first: usize, e: [f64; 3]) -> f64 {
    nees_of(ekf.p.fixed_view::<3, 3>(first, first).into_owned(), e)
}

/// eᵀ·P⁻¹·e; NaN when `p` is not invertible.
fn nees_of(p: nalgebra::Matrix3<f64>, e: [f64; 3]) -> f64 {
    let e = nalgebra::Vector3::from(e);
    match p.cholesky() {
        Some(c) => e.dot(&c.solve(&e)),
        None => f64::NAN,
    }
}

impl TruthTrace {
    /// One Kalman step: the estimate `est` from filter `ekf`, the vehicle `plant`, and the
    /// simulated receiver's current bias (north, west, up), m — `None` without one (fake or
    /// no GPS: the fixes are not the vehicle's, and the position is not judged). Returns
    /// truth.log's row ([`FILE`]), the bias zero without a receiver.
    pub fn sample(
        &mut self,
        est: &Estimate,
        ekf: &Ekf,
        plant: &Plant,
        receiver_bias_m: Option<[f64; 3]>,
    ) -> [f64; 15] {
        let x = &plant.x;
        let bias_m = receiver_bias_m.unwrap_or_default();
        let truth = row(plant, receiver_bias_m);
        let e = &est.x;
        let d = |i: usize| e[i] - x[i];
        let pos = [d(idx::X), d(idx::Y), d(idx::Z)];
        let vel = [d(idx::VQX), d(idx::VQY), d(idx::VQZ)];
        let att = [idx::PSI, idx::PHI, idx::THETA].map(|i| wrap_pi(e[i] - x[i]));
        let norm_sq = |v: [f64; 3]| v.iter().map(|c| c * c).sum::<f64>();
        self.pos_sq += norm_sq(pos);
        self.pos_max = self.pos_max.max(norm_sq(pos).sqrt());
        self.vel_sq += norm_sq(vel);
        self.att_sq += norm_sq(att);
        self.n += 1;
        if ekf.fix_seen && receiver_bias_m.is_some() {
            let [bx, by] = ekf.receiver_bias_m();
            let known = [pos[0] + bx - bias_m[0], pos[1] + by - bias_m[1], pos[2]];
            let p = ekf.fix_frame_position_covariance_m2();
            self.nees[0].add(nees_of(p, known), 3);
        }
        self.nees[1].add(nees3(ekf, idx::VQX, vel), 3);
        self.nees[2].add(nees3(ekf, idx::PSI, att), 3);
        let groups = [est.nis.attitude, est.nis.altitude, est.nis.gps];
        for (sum, nis) in self.nis.iter_mut().zip(groups) {
            if let Some(Nis { value, dof }) = nis {
                sum.add(value, dof);
            }
        }
        truth
    }

    /// The figures; `None` before a Kalman step.
    pub fn figures(&self) -> Option<(EstError, Consistency)> {
        if self.n == 0 {
            return None;
        }
        let rms = |s: f64| (s / self.n as f64).sqrt();
        let error = EstError {
            position_rms_m: rms(self.pos_sq),
            position_max_m: self.pos_max,
            velocity_rms_m_s: rms(self.vel_sq),
            attitude_rms_rad: rms(self.att_sq),
            steps: self.n,
        };
        let consistency = Consistency {
            nees: NeesFigures {
                position: self.nees[0].figure(),
                velocity: self.nees[1].figure(),
                attitude: self.nees[2].figure(),
            },
            nis: NisFigures {
                attitude: self.nis[0].figure(),
                altitude: self.nis[1].figure(),
                gps: self.nis[2].figure(),
            },
        };
        Some((error, consistency))
    }
}

/// The summary's line: the error, and the fraction of steps inside the 95 % bounds ("-" for
/// a figure with no step judged).
pub fn text(e: &EstError, c: &Consistency) -> String {
    let (n, s) = (&c.nees, &c.nis);
    let f = |x: &ChiFigure| {
        x.in_95
            .map_or_else(|| "-".to_string(), |v| format!("{v:.2}"))
    };
    format!(
        "estimate against the truth: position RMS {:.3} m (largest {:.3} m), velocity RMS {:.3} m/s, \
         attitude RMS {:.4} rad; inside the 95 % bounds: NEES position {}, velocity {}, \
         attitude {}; NIS attitude {}, altitude {}, gps {}",
        e.position_rms_m,
        e.position_max_m,
        e.velocity_rms_m_s,
        e.attitude_rms_rad,
        f(&n.position),
        f(&n.velocity),
        f(&n.attitude),
        f(&s.attitude),
        f(&s.altitude),
        f(&s.gps)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bounds_hold_the_chi_square_middle() {
        assert!(inside_95(3.0, 3) && !inside_95(0.1, 3) && !inside_95(10.0, 3));
        assert!(inside_95(1.0, 1) && !inside_95(6.0, 1));
        assert!(!inside_95(1.0, 0) && !inside_95(1.0, 5) && !inside_95(f64::NAN, 3));
        let mut s = ChiSum::default();
        s.add(2.0, 2);
        s.add(f64::NAN, 2);
        s.add(100.0, 2);
        let f = s.figure();
        assert_eq!((f.steps, f.failed), (3, 1));
        assert_eq!(f.in_95, Some(1.0 / 3.0));
        assert_eq!((f.below_95, f.above_95), (Some(0.0), Some(1.0 / 3.0)));
        assert_eq!(f.mean, Some(51.0));
        s.add(0.01, 2);
        assert_eq!(s.figure().below_95, Some(0.25));
        assert_eq!(ChiSum::default().figure().in_95, None);
    }

    #[test]
    fn angles_differ_the_short_way() {
        assert!((wrap_pi(3.1 - -3.1) - (6.2 - std::f64::consts::TAU)).abs() < 1e-12);
        assert!((wrap_pi(0.2 - 0.1) - 0.1).abs() < 1e-12);
    }
}
