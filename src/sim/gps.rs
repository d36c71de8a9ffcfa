//! The simulated receiver's errors: what a real GPS reports instead of the true position —
//! white noise, a bias that wanders slowly (a first-order Gauss–Markov process: multipath and
//! the atmosphere change over tens of seconds), a delay, and a rate of 1 to 10 fixes a second.
//!
//! [`GpsErrors::NEO_M8N`] follows the u-blox NEO-M8N data sheet: horizontal accuracy 2.5 m
//! CEP, 1 fix a second by default and at most 10. CEP 2.5 m is a horizontal error of about
//! 2.1 m standard deviation per axis, split here into a wandering bias (2 m, correlated over
//! 60 s as PX4's simulated GPS) and white noise (0.7 m); the vertical error is taken as twice
//! the horizontal, the usual ratio of GNSS geometry; 0.1 s of delay; the velocity's white
//! noise 0.05 m/s (the data sheet's velocity accuracy). These are the defaults (`sim.gps_*`).
//! Pure and seeded: the same seed gives the same fixes.

use super::imu::Gauss;
use crate::core::gps::LiveFix;
use std::collections::VecDeque;

/// The error model's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsErrors {
    /// Fixes a second.
    pub rate_hz: f64,
    /// From the position sampled to the fix reported, s.
    pub delay_s: f64,
    /// White noise, standard deviation: horizontal per axis, vertical, m.
    pub noise_h_m: f64,
    pub noise_v_m: f64,
    /// The wandering bias: standard deviation (horizontal per axis, vertical), m, and
    /// correlation time, s.
    pub bias_h_m: f64,
    pub bias_v_m: f64,
    pub bias_tau_s: f64,
    /// White noise of the velocity, per axis, m/s.
    pub noise_vel_m_s: f64,
}

impl GpsErrors {
    /// The model `sim.gps_*` describes.
    pub fn of(sim: &crate::config::Sim) -> Self {
        GpsErrors {
            rate_hz: sim.gps_rate_hz,
            delay_s: sim.gps_delay_s,
            noise_h_m: sim.gps_noise_h_m,
            noise_v_m: sim.gps_noise_v_m,
            bias_h_m: sim.gps_bias_h_m,
            bias_v_m: sim.gps_bias_v_m,
            bias_tau_s: sim.gps_bias_tau_s,
            noise_vel_m_s: sim.gps_noise_vel_m_s,
        }
    }

    /// The u-blox NEO-M8N (see the module's notes): the profile's defaults.
    pub const NEO_M8N: GpsErrors = GpsErrors {
        rate_hz: 1.0,
        delay_s: 0.1,
        noise_h_m: 0.7,
        noise_v_m: 1.4,
        bias_h_m: 2.0,
        bias_v_m: 4.0,
        bias_tau_s: 60.0,
        noise_vel_m_s: 0.05,
    };

    /// No error: every fix is the true position, once a second, at once.
    pub const EXACT: GpsErrors = GpsErrors {
        rate_hz: 1.0,
        delay_s: 0.0,
        noise_h_m: 0.0,
        noise_v_m: 0.0,
        bias_h_m: 0.0,
        bias_v_m: 0.0,
        bias_tau_s: 60.0,
        noise_vel_m_s: 0.0,
    };

    /// The horizontal error's standard deviation per axis (noise and bias together), m: what
    /// the receiver reports as its horizontal error estimate.
    pub fn eph_m(&self) -> f64 {
        self.noise_h_m.hypot(self.bias_h_m)
    }
}

/// A receiver: call [`Receiver::step`] at every physics step with the true position.
#[derive(Debug, Clone)]
pub struct Receiver {
    p: GpsErrors,
    gauss: Gauss,
    bias_m: [f64; 3],
    /// Samples not yet reported: (time to report, position, velocity).
    queue: VecDeque<(i64, [f64; 3], [f64; 3])>,
    next_sample_us: i64,
    last_bias_us: Option<i64>,
}

impl Receiver {
    pub fn new(p: GpsErrors, seed: u64) -> Self {
        let mut gauss = Gauss::new(seed);
        // The bias starts where its stationary spread puts it.
        let bias_m = [
            gauss.sample(p.bias_h_m),
            gauss.sample(p.bias_h_m),
            gauss.sample(p.bias_v_m),
        ];
        Receiver {
            p,
            gauss,
            bias_m,
            queue: VecDeque::new(),
            next_sample_us: 0,
            last_bias_us: None,
        }
    }

    /// The bias the receiver's fixes carry now (north, west, up), m.
    pub fn bias_m(&self) -> [f64; 3] {
        self.bias_m
    }

    fn period_us(&self) -> i64 {
        (1e6 / self.p.rate_hz).round() as i64
    }

    /// The fix due at `t_us`, if one is: the position and velocity sampled `delay_s` ago,
    /// with the errors.
    pub fn step(
        &mut self,
        t_us: i64,
        true_m: [f64; 3],
        true_m_s: [f64; 3],
    ) -> Option<([f64; 3], [f64; 3])> {
        self.advance_bias(t_us);
        if t_us >= self.next_sample_us {
            self.next_sample_us += self.period_us();
            let delay_us = (self.p.delay_s * 1e6).round() as i64;
            let b = self.bias_m;
            let n = [
                self.gauss.sample(self.p.noise_h_m),
                self.gauss.sample(self.p.noise_h_m),
                self.gauss.sample(self.p.noise_v_m),
            ];
            let seen = std::array::from_fn(|i| true_m[i] + b[i] + n[i]);
            let vel = true_m_s.map(|v| v + self.gauss.sample(self.p.noise_vel_m_s));
            self.queue.push_back((t_us + delay_us, seen, vel));
        }
        match self.queue.front() {
            Some(&(due_us, pos, vel)) if due_us <= t_us => {
                self.queue.pop_front();
                Some((pos, vel))
            }
            _ => None,
        }
    }

    /// The bias's Gauss–Markov step over the time since the last: it decays toward 0 with
    /// `bias_tau_s` and is driven so that its spread stays `bias_*_m`.
    fn advance_bias(&mut self, t_us: i64) {
        let Some(last) = self.last_bias_us.replace(t_us) else {
            return;
        };
        let dt_s = (t_us - last) as f64 / 1e6;
        if dt_s <= 0.0 {
            return;
        }
        let a = (-dt_s / self.p.bias_tau_s).exp();
        let drive = (1.0 - a * a).sqrt();
        let sd = [self.p.bias_h_m, self.p.bias_h_m, self.p.bias_v_m];
        for (b, sd) in self.bias_m.iter_mut().zip(sd) {
            *b = a * *b + self.gauss.sample(sd * drive);
        }
    }
}

/// The simulated gpsd: the receiver's fixes as they reach the flight, numbered, with the
/// receiver's horizontal error estimate.
#[derive(Debug, Clone)]
pub struct SimGps {
    receiver: Receiver,
    eph_m: f64,
    seq: u64,
}

/// Mixed into `sim.seed` for the receiver's draws (apart from the IMU's).
const SEED_SALT: u64 = 0x4750_5352;

impl SimGps {
    /// The receiver `sim.gps_*` describes, drawing from the run's `seed`.
    pub fn new(sim: &crate::config::Sim, seed: u64) -> Self {
        let p = GpsErrors::of(sim);
        SimGps {
            receiver: Receiver::new(p, seed ^ SEED_SALT),
            eph_m: p.eph_m(),
            seq: 0,
        }
    }

    /// The bias the receiver's fixes carry now (north, west, up), m.
    pub fn bias_m(&self) -> [f64; 3] {
        self.receiver.bias_m()
    }

    /// Called at every physics step (simulated time `t_us`) with the true position and
    /// velocity: the fix due now, stamped `stamp_us` (the run's clock).
    pub fn step(
        &mut self,
        t_us: i64,
        true_m: [f64; 3],
        true_m_s: [f64; 3],
        stamp_us: i64,
    ) -> Option<LiveFix> {
        let (pos, vel) = self.receiver.step(t_us, true_m, true_m_s)?;
        Some(super::gps_fix(
            &mut self.seq,
            pos,
            vel,
            stamp_us,
            self.eph_m,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The NEO-M8N's errors at 5 Hz with 0.2 s of delay (the rate and delay tested too).
    const NEO_M8N: GpsErrors = GpsErrors {
        rate_hz: 5.0,
        delay_s: 0.2,
        ..GpsErrors::NEO_M8N
    };

    /// Fixes of a receiver held still at the origin for `seconds`, stepped each ms.
    fn fixes(p: GpsErrors, seconds: i64, seed: u64) -> Vec<(i64, [f64; 3])> {
        let mut r = Receiver::new(p, seed);
        (0..=seconds * 1000)
            .filter_map(|ms| {
                r.step(ms * 1000, [0.0; 3], [0.0; 3])
                    .map(|f| (ms * 1000, f.0))
            })
            .collect()
    }

    #[test]
    fn exact_fixes_are_the_true_position_once_a_second() {
        let f = fixes(GpsErrors::EXACT, 5, 1);
        assert_eq!(f.len(), 6);
        assert!(f.iter().all(|(_, p)| *p == [0.0; 3]));
        assert_eq!(f[1].0, 1_000_000);
    }

    #[test]
    fn rate_and_delay_are_kept() {
        let f = fixes(NEO_M8N, 10, 1);
        // 5 a second, the first after the 0.2 s delay.
        assert_eq!(f.len(), 50);
        assert_eq!(f[0].0, 200_000);
        assert_eq!(f[1].0 - f[0].0, 200_000);
    }

    #[test]
    fn the_spread_matches_the_parameters_and_the_bias_wanders_slowly() {
        // Many receivers' first fixes: per-axis spread of bias and noise together.
        let n = 4000;
        let firsts: Vec<[f64; 3]> = (0..n).map(|s| fixes(NEO_M8N, 1, s)[0].1).collect();
        let sd = |i: usize| (firsts.iter().map(|f| f[i] * f[i]).sum::<f64>() / n as f64).sqrt();
        let want_h = NEO_M8N.eph_m();
        assert!(
            (sd(0) - want_h).abs() < 0.1 * want_h,
            "{} vs {want_h}",
            sd(0)
        );
        assert!((sd(2) - 2.0 * want_h).abs() < 0.2 * want_h, "{}", sd(2));
        // One receiver over 10 s: successive fixes differ by the noise, not the bias.
        let f = fixes(NEO_M8N, 10, 3);
        let steps: Vec<f64> = f.windows(2).map(|w| w[1].1[0] - w[0].1[0]).collect();
        let step_sd = (steps.iter().map(|d| d * d).sum::<f64>() / steps.len() as f64).sqrt();
        // Two independent noise draws: √2 · 0.7 ≈ 1.0 m.
        assert!((0.7..1.4).contains(&step_sd), "{step_sd}");
    }

    #[test]
    fn the_same_seed_gives_the_same_fixes() {
        assert_eq!(fixes(NEO_M8N, 3, 9), fixes(NEO_M8N, 3, 9));
        assert_ne!(fixes(NEO_M8N, 3, 9), fixes(NEO_M8N, 3, 10));
    }
}
