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
}

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
        }
    }

    /// Accelerometer and gyro counts now (not yet truncated).
    fn sub_sample(&mut self, plant: &Plant) -> [f64; 6] {
        let f = plant.specific_force_m_s2;
        let w = plant.rates_rad_s();
        let n = self.noise;
        let acc: [f64; 3] = std::array::from_fn(|i| f[i] + self.rng.sample(n.acc_m_s2));
        let gyro: [f64; 3] =
            std::array::from_fn(|i| w[i] + n.gyro_bias_rad_s[i] + self.rng.sample(n.gyro_rad_s));
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
}
