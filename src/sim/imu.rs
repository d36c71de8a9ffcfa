//! The simulated IMU board (spec 10: the Mongoose firmware): specific force, rates, magnetic
//! field and pressure of the true state turned into raw counts by inverting the calibration
//! (spec 2.2), with seeded noise and bias; each frame the mean of two 5 ms sub-samples
//! truncated toward zero, the magnetometer held for 5 frames and the barometer for 2, as the
//! real board did.

use crate::core::gps::SplitMix64;
use crate::core::imu::calib::{Calibration, P0_DEFAULT_PA, PRESS_K_M, YAW_OFFSET_RAD};
use crate::core::imu::frame::RawFrame;
use crate::sim::physics::Plant;

/// Noise and bias of the simulated sensors (standard deviations).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoise {
    pub acc_m_s2: f64,
    pub gyro_rad_s: f64,
    pub gyro_bias_rad_s: [f64; 3],
    pub baro_pa: f64,
    pub mag: f64,
    pub temp_c: f64,
    /// Bias random walk of the gyro and the accelerometer, per √s (0: none).
    pub gyro_walk_rad_s_per_sqrt_s: f64,
    pub acc_walk_m_s2_per_sqrt_s: f64,
}

/// The firmware samples its accelerometer and gyro every 5 ms, two per frame, s.
pub const SUB_SAMPLE_S: f64 = 0.005;

/// Gaussian samples from the seeded generator (Box–Muller).
#[derive(Debug, Clone)]
pub struct Gauss(SplitMix64);

impl Gauss {
    pub fn new(seed: u64) -> Self {
        Gauss(SplitMix64::new(seed))
    }

    pub fn sample(&mut self, sd: f64) -> f64 {
        if sd == 0.0 {
            return 0.0;
        }
        let u1 = self.0.next_f64().max(f64::MIN_POSITIVE);
        let u2 = self.0.next_f64();
        sd * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Magnetic field in the inertial frame (arbitrary unit; only its direction is used): its
/// horizontal part points so that the original's yaw formula, with its 0.17069 rad offset,
/// reads the true yaw.
pub fn earth_field() -> [f64; 3] {
    [YAW_OFFSET_RAD.cos(), YAW_OFFSET_RAD.sin(), -0.8]
}

/// Frames the magnetometer and the barometer hold their values for.
const MAG_HOLD_FRAMES: u64 = 5;
const BARO_HOLD_FRAMES: u64 = 2;

pub struct SimImu {
    calib: Calibration,
    noise: ImuNoise,
    rng: Gauss,
    temp_c: f64,
    frames: u64,
    held_mag: [i16; 3],
    held_baro: (i16, u32),
    first_sub: Option<[f64; 6]>,
    /// The random walks' part of the biases so far: gyro (rad/s), accelerometer (m/s²).
    gyro_walk_rad_s: [f64; 3],
    acc_walk_m_s2: [f64; 3],
    /// A step in the gyro's bias (the `gyro-bias` fault), rad/s.
    pub gyro_step_rad_s: [f64; 3],
}

impl SimImu {
    pub fn new(calib: Calibration, noise: ImuNoise, temp_c: f64, seed: u64) -> Self {
        SimImu {
            calib,
            noise,
            rng: Gauss::new(seed),
            temp_c,
            frames: 0,
            held_mag: [0; 3],
            held_baro: (0, 0),
            first_sub: None,
            gyro_walk_rad_s: [0.0; 3],
            acc_walk_m_s2: [0.0; 3],
            gyro_step_rad_s: [0.0; 3],
        }
    }

    /// Accelerometer and gyro counts now (not yet truncated).
    fn sub_sample(&mut self, plant: &Plant) -> [f64; 6] {
        let f = plant.specific_force_m_s2;
        let w = plant.rates_rad_s();
        let n = self.noise;
        // A random walk's step over one sub-sample (no draw when it is off: the default
        // runs' noise stays the same).
        let sqrt_dt = SUB_SAMPLE_S.sqrt();
        for i in 0..3 {
            self.gyro_walk_rad_s[i] += self.rng.sample(n.gyro_walk_rad_s_per_sqrt_s * sqrt_dt);
            self.acc_walk_m_s2[i] += self.rng.sample(n.acc_walk_m_s2_per_sqrt_s * sqrt_dt);
        }
        let acc: [f64; 3] =
            std::array::from_fn(|i| f[i] + self.acc_walk_m_s2[i] + self.rng.sample(n.acc_m_s2));
        let gyro: [f64; 3] = std::array::from_fn(|i| {
            let bias = n.gyro_bias_rad_s[i] + self.gyro_walk_rad_s[i] + self.gyro_step_rad_s[i];
            w[i] + bias + self.rng.sample(n.gyro_rad_s)
        });
        let (a, g) = self.calib.counts_for(&acc, self.temp_c, &gyro, &[0.0; 3]);
        [a[0], a[1], a[2], g[0], g[1], g[2]]
    }

    /// Call 5 ms before each frame: the firmware's first sub-sample.
    pub fn first_half(&mut self, plant: &Plant) {
        self.first_sub = Some(self.sub_sample(plant));
    }

    /// The frame sent now, `t_us` after the previous one.
    pub fn frame(&mut self, plant: &Plant, t_us: u32) -> RawFrame {
        let second = self.sub_sample(plant);
        let first = self.first_sub.take().unwrap_or(second);
        // The firmware sums integer readings and divides by two, truncating toward zero.
        let avg = |i: usize| {
            let a = first[i].round().clamp(-32768.0, 32767.0) as i32;
            let b = second[i].round().clamp(-32768.0, 32767.0) as i32;
            ((a + b) / 2) as i16
        };
        if self.frames.is_multiple_of(MAG_HOLD_FRAMES) {
            let m_body = plant.to_body(&earth_field());
            let m: [f64; 3] = std::array::from_fn(|i| m_body[i] + self.rng.sample(self.noise.mag));
            let c = self.calib.magn_counts_for(&m);
            self.held_mag = c.map(|v| v.round().clamp(-32768.0, 32767.0) as i16);
        }
        if self.frames.is_multiple_of(BARO_HOLD_FRAMES) {
            let z = plant.position_m()[2];
            let p = P0_DEFAULT_PA * (1.0 - z / PRESS_K_M).powf(5.255)
                + self.rng.sample(self.noise.baro_pa);
            let t = self.temp_c + self.rng.sample(self.noise.temp_c);
            self.held_baro = ((t * 10.0).round() as i16, p.round().max(0.0) as u32);
        }
        self.frames += 1;
        RawFrame {
            t_us,
            acc: [avg(0), avg(1), avg(2)],
            gyro: [avg(3), avg(4), avg(5)],
            magn: self.held_mag,
            temp_dc: self.held_baro.0,
            pres_pa: self.held_baro.1,
        }
    }
}

/// The per-frame noise this IMU produces, as `uquad noise` should find it (to first order in
/// the calibration's cross-axis terms, about 1 %): the standard
/// deviation of each accelerometer and gyro axis of a frame (m/s², rad/s) with the vehicle at
/// rest reading `acc_m_s2` and `gyro_rad_s` (the bias included), at `temp_c`.
///
/// How: `sim.*_noise_*` is each 5 ms sub-sample's. The sub-sample becomes counts through the
/// inverted calibration (sd in counts: the noise through K⁻¹), is rounded to a count; the
/// firmware sums two and halves the sum toward zero ([`frame_counts_sd`]); the frame's counts
/// go back to units through K (each axis of counts on its own). Far from zero counts that is
/// about σ²/2 + (5/48)·Σⱼ Kᵢⱼ² (rounding 1/24 count², the halving's truncation 1/16); near
/// zero counts the truncation is a dead zone that makes it narrower.
pub fn expected_frame_sd(
    calib: &Calibration,
    noise: &ImuNoise,
    temp_c: f64,
    acc_m_s2: [f64; 3],
    gyro_rad_s: [f64; 3],
) -> ([f64; 3], [f64; 3]) {
    let counts = |a: &[f64; 3], g: &[f64; 3]| calib.counts_for(a, temp_c, g, &[0.0; 3]);
    let (mean_a, mean_g) = counts(&acc_m_s2, &gyro_rad_s);
    // Each unit axis's noise through K⁻¹: the counts it moves, per axis of counts.
    let mut var_a = [0.0; 3];
    let mut var_g = [0.0; 3];
    for i in 0..3 {
        let mut a = acc_m_s2;
        a[i] += noise.acc_m_s2;
        let mut g = gyro_rad_s;
        g[i] += noise.gyro_rad_s;
        let (da, dg) = (counts(&a, &gyro_rad_s).0, counts(&acc_m_s2, &g).1);
        for j in 0..3 {
            var_a[j] += (da[j] - mean_a[j]).powi(2);
            var_g[j] += (dg[j] - mean_g[j]).powi(2);
        }
    }
    let frame_var = |mean: [f64; 3], var: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|j| frame_counts_sd(mean[j], var[j].sqrt()).powi(2))
    };
    let (fa, fg) = (frame_var(mean_a, var_a), frame_var(mean_g, var_g));
    let to_units = |k: &[[f64; 3]; 3], v: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| k[i][j].powi(2) * v[j]).sum::<f64>().sqrt())
    };
    (
        to_units(&calib.acc.tk_inv, fa),
        to_units(&calib.gyro.tk_inv, fg),
    )
}

/// The standard deviation, counts, of `(round(a) + round(b)) / 2` halved toward zero, with a
/// and b independent Gaussian about `mean` with `sd` (counts): summed exactly over the
/// rounded values' distribution.
pub fn frame_counts_sd(mean: f64, sd: f64) -> f64 {
    if sd <= 0.0 {
        return 0.0;
    }
    if sd > 20.0 {
        // Rounding is then noise of its own, the same anywhere: the closed form (and the sum
        // below would grow with sd²).
        return (sd * sd / 2.0 + 5.0 / 48.0).sqrt();
    }
    let lo = (mean - 9.0 * sd).floor() as i64 - 1;
    let hi = (mean + 9.0 * sd).ceil() as i64 + 1;
    let cdf = |x: f64| 0.5 * (1.0 + erf((x - mean) / (sd * std::f64::consts::SQRT_2)));
    let p: Vec<(i64, f64)> = (lo..=hi)
        .map(|k| (k, cdf(k as f64 + 0.5) - cdf(k as f64 - 0.5)))
        .collect();
    let (mut m1, mut m2) = (0.0, 0.0);
    for &(a, pa) in &p {
        for &(b, pb) in &p {
            let v = ((a + b) / 2) as f64;
            m1 += pa * pb * v;
            m2 += pa * pb * v * v;
        }
    }
    (m2 - m1 * m1).max(0.0).sqrt()
}

/// The error function (Abramowitz and Stegun 7.1.26; absolute error under 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let y = 1.0 - poly * (-x * x).exp();
    if x < 0.0 { -y } else { y }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::imu::calib::{NullReference, euler_from_acc_magn};
    use crate::sim::physics::PlantParams;

    #[test]
    fn frames_read_back_as_the_true_state() {
        let calib = Calibration::parse(include_str!("../../config/imu_calib.txt")).unwrap();
        let noise = ImuNoise {
            acc_m_s2: 0.0,
            gyro_rad_s: 0.0,
            gyro_bias_rad_s: [0.0; 3],
            baro_pa: 0.0,
            mag: 0.0,
            temp_c: 0.0,
            gyro_walk_rad_s_per_sqrt_s: 0.0,
            acc_walk_m_s2_per_sqrt_s: 0.0,
        };
        let mut imu = SimImu::new(calib.clone(), noise, 30.0, 1);
        let mut plant = Plant::new(
            PlantParams {
                mass_kg: 1.55,
                motor_tau_s: 0.03,
                drag_n_per_m_s: 0.0,
                wind_m_s: [0.0; 3],
            },
            1.2,
        );
        plant.step(1000);
        imu.first_half(&plant);
        let f = imu.frame(&plant, 10_000);
        let s = calib.convert(&f, &NullReference::default());
        assert!((s.acc_m_s2[2] - 9.81).abs() < 0.05, "{:?}", s.acc_m_s2);
        assert!(
            s.gyro_rad_s.iter().all(|w| w.abs() < 0.005),
            "{:?}",
            s.gyro_rad_s
        );
        let e = euler_from_acc_magn(&s.acc_m_s2, &s.magn);
        assert!((e[2] - 1.2).abs() < 0.02, "yaw {e:?}");
        assert!(s.alt_m.abs() < 0.5);
        assert_eq!(f.temp_dc, 300);
    }

    #[test]
    fn a_frame_halves_the_variance_and_adds_the_counts_rounding() {
        // Far from zero: σ²/2 + 5/48 count².
        let sd = frame_counts_sd(100.3, 3.0);
        assert!((sd - (4.5f64 + 5.0 / 48.0).sqrt()).abs() < 0.01, "{sd}");
        // About zero the truncation's dead zone narrows it.
        assert!(frame_counts_sd(0.0, 1.3) < frame_counts_sd(50.0, 1.3));
        assert_eq!(frame_counts_sd(3.0, 0.0), 0.0);
        assert!((erf(0.5) - 0.520_499_877_8).abs() < 2e-7 && (erf(-0.5) + erf(0.5)).abs() < 1e-12);
    }
}
