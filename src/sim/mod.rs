//! The software-in-the-loop simulator's models: the uQuad's physics, a simulated IMU that
//! emits the real 30-byte frames, simulated ESCs behind the same bus trait, simulated gpsd
//! fixes, the faults and their schedule, and the hover window. The two ways of flying the real
//! code against them are composition roots in `app` (`sim_fast`, `sim_realtime`).

pub mod esc;
pub mod faults;
pub mod gps;
pub mod hover;
pub mod imu;
pub mod operator;
pub mod physics;
pub mod safety;
pub mod track;
pub mod transmitter;
pub mod truth;

use crate::config::Profile;
use crate::core::gps::{Fix, GpsSample, LiveFix};

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
            gyro_walk_rad_s_per_sqrt_s: sc.gyro_bias_walk_rad_s_per_sqrt_s,
            acc_walk_m_s2_per_sqrt_s: sc.acc_bias_walk_m_s2_per_sqrt_s,
        },
        sc.temp_c,
        seed,
    );
    (plant, imu)
}

/// The simulated site's ground above sea level, m (the receiver reports its altitude above
/// sea level, as gpsd does): a ground station's takeoff altitude given above sea level reads
/// as the height it means, as on a real field.
pub const SITE_ALT_M: f64 = 30.0;

/// Where the simulated vehicle flies: the 2012 flight's first fix (Facultad de Ingeniería,
/// Montevideo), latitude and longitude, degrees.
pub const SITE_DEG: [f64; 2] = [-34.919588333, -56.166258333];

/// Simulated gpsd: a fix at `pos_m` (local frame; the receiver's, errors included) arriving
/// at `t_us`, the next in `seq`. Its latitude and longitude place the local frame at [`SITE_DEG`] (for a
/// ground station's map); the run's gps.log carries the local position, which is what the
/// filter and a replay fuse.
pub fn gps_fix(
    seq: &mut u64,
    pos_m: [f64; 3],
    vel_m_s: [f64; 3],
    t_us: i64,
    eph_m: f64,
) -> LiveFix {
    *seq += 1;
    let [lat_deg, lon_deg] = crate::core::gps::offset_deg(SITE_DEG, [pos_m[0], pos_m[1]]);
    LiveFix {
        seq: *seq,
        fix: Fix {
            mode: 3,
            lat_deg,
            lon_deg,
            alt_m: Some(SITE_ALT_M + pos_m[2]),
            // The receiver's own estimate of its error (`sim::gps`).
            eph_m: Some(eph_m),
        },
        sample: GpsSample {
            vel_m_s: Some(vel_m_s),
            ..GpsSample::at(pos_m)
        },
        stamp_us: t_us,
    }
}

/// The IMU's frame period, µs (spec 1.1).
pub const FRAME_US: i64 = 10_000;

/// The start byte of the `k`-th frame: the simulated IMU alternates its two, as the real one.
pub fn frame_start_byte(k: u64) -> u8 {
    if k.is_multiple_of(2) { b'C' } else { b'A' }
}

/// The push of the `gust` fault at `t_us` (inertial frame, N): `sim.gust_n` northward for
/// `sim.gust_s` from its time.
pub fn gust_n(faults: &faults::FaultSchedule, sim: &crate::config::Sim, t_us: i64) -> [f64; 3] {
    if faults.active_for(faults::Fault::Gust, t_us, sim.gust_s) {
        [sim.gust_n, 0.0, 0.0]
    } else {
        [0.0; 3]
    }
}

/// Where the receiver takes the vehicle to be at `t_us`: the true position `pos_m`, moved
/// `sim.gps_glitch_m` north for `sim.gps_glitch_s` from the `gps-glitch` fault's time (a
/// multipath jump; the receiver's own errors and delay come on top).
pub fn gps_seen_m(
    faults: &faults::FaultSchedule,
    sim: &crate::config::Sim,
    t_us: i64,
    pos_m: [f64; 3],
) -> [f64; 3] {
    let mut seen = pos_m;
    if faults.active_for(faults::Fault::GpsGlitch, t_us, sim.gps_glitch_s) {
        seen[0] += sim.gps_glitch_m;
    }
    seen
}

/// The `gyro-bias` fault's step on the gyro at `t_us`, rad/s: `sim.gyro_bias_step_rad_s` on
/// x from its time on.
pub fn gyro_step_rad_s(
    faults: &faults::FaultSchedule,
    sim: &crate::config::Sim,
    t_us: i64,
) -> [f64; 3] {
    if faults.active(faults::Fault::GyroBias, t_us) {
        [sim.gyro_bias_step_rad_s, 0.0, 0.0]
    } else {
        [0.0; 3]
    }
}
