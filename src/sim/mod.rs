//! The software-in-the-loop simulator: a physics model of the uQuad, a simulated IMU that
//! emits the real 30-byte frames, simulated ESCs behind the same bus trait, and the two ways of
//! flying the real code against them (`--fast` lock-step, `--realtime` with fly's tasks).

pub mod esc;
pub mod imu;
pub mod physics;
pub mod realtime;
pub mod run;

use crate::config::Profile;

/// The vehicle and its IMU as the profile's `[sim]` section describes them, with `seed`.
pub fn vehicle(profile: &Profile, seed: u64) -> (physics::Plant, imu::SimImu) {
    let sc = &profile.config.sim;
    let plant = physics::Plant::new(
        physics::PlantParams {
            mass_kg: profile.config.vehicle.mass_kg,
            motor_tau_s: sc.motor_tau_s,
            drag_n_per_m_s: sc.drag_n_per_m_s,
            wind_m_s: sc.wind_m_s,
        },
        sc.initial_yaw_rad,
    );
    let imu = imu::SimImu::new(
        profile.calib.clone(),
        imu::ImuNoise {
            acc_m_s2: sc.acc_noise_m_s2,
            gyro_rad_s: sc.gyro_noise_rad_s,
            gyro_bias_rad_s: sc.gyro_bias_rad_s,
            baro_pa: sc.baro_noise_pa,
            mag: sc.mag_noise,
            temp_c: 0.0,
        },
        sc.temp_c,
        seed,
    );
    (plant, imu)
}
