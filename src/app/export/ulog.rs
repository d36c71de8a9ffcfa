//! A run folder as a ULog, under PX4's topic and field names where a counterpart exists, so
//! Flight Review, PlotJuggler and pyulog plot it without a mapping. Frames are PX4's:
//! north-east-down and forward-right-down (uquad's y and z change sign; roll stays, pitch and
//! yaw change sign). Values from the text logs are written as doubles, so they read back
//! equal to what the text printed.

use crate::app::run_logs::RunLogs;
use crate::gcs::telemetry::{CUSTOM_MODES, ned, wrap_pi};
use crate::logs::GpsLogRecord;
use crate::logs::ulog::{Fields, Level, Type::*, Ulog, Value as V};

type Result = std::result::Result<(), String>;

/// The topics: name and fields after the timestamp.
const TOPICS: &[(&str, Fields)] = &[
    // The IMU's frames as they came (counts of the ADXL345, ITG-3200 and HMC5843; the
    // BMP085's 0.1 °C and Pa): no PX4 topic carries raw counts of these chips.
    (
        "uquad_imu_raw",
        &[
            ("frame_dt_us", U32, 1),
            ("acc_counts", I32, 3),
            ("gyro_counts", I32, 3),
            ("mag_counts", I32, 3),
            ("temp_decidegc", I32, 1),
            ("pressure_pa", U32, 1),
        ],
    ),
    ("vehicle_attitude", &[("q", F32, 4)]),
    (
        "vehicle_local_position",
        &[
            ("x", F64, 1),
            ("y", F64, 1),
            ("z", F64, 1),
            ("vx", F64, 1),
            ("vy", F64, 1),
            ("vz", F64, 1),
            ("heading", F64, 1),
            ("xy_valid", Bool, 1),
            ("z_valid", Bool, 1),
        ],
    ),
    (
        "vehicle_local_position_setpoint",
        &[("x", F64, 1), ("y", F64, 1), ("z", F64, 1), ("yaw", F64, 1)],
    ),
    (
        "vehicle_attitude_setpoint",
        &[
            ("roll_body", F64, 1),
            ("pitch_body", F64, 1),
            ("yaw_body", F64, 1),
        ],
    ),
    (
        "actuator_outputs",
        &[("noutputs", U32, 1), ("output", F64, 4)],
    ),
    (
        "sensor_combined",
        &[("gyro_rad", F64, 3), ("accelerometer_m_s2", F64, 3)],
    ),
    (
        "vehicle_air_data",
        &[("baro_alt_meter", F64, 1), ("baro_temp_celcius", F64, 1)],
    ),
    (
        "vehicle_gps_position",
        &[
            ("lat", I32, 1),
            ("lon", I32, 1),
            ("latitude_deg", F64, 1),
            ("longitude_deg", F64, 1),
            ("fix_type", U8, 1),
            ("vel_n_m_s", F64, 1),
            ("vel_e_m_s", F64, 1),
            ("vel_d_m_s", F64, 1),
            ("vel_ned_valid", Bool, 1),
        ],
    ),
    (
        "estimator_status",
        &[
            ("mag_test_ratio", F64, 1),
            ("hgt_test_ratio", F64, 1),
            ("pos_test_ratio", F64, 1),
            ("gated_groups", U8, 1),
        ],
    ),
    (
        "vehicle_status",
        &[
            ("arming_state", U8, 1),
            ("nav_state", U8, 1),
            ("failsafe", Bool, 1),
            ("custom_mode", U8, 1),
        ],
    ),
];

/// µs as ULog's unsigned timestamp (a negative time, which no run has, is 0).
fn ts(t_us: i64) -> u64 {
    u64::try_from(t_us).unwrap_or(0)
}

/// The quaternion (w, x, y, z) of north-east-down Euler angles (Z-Y-X), rad.
fn quaternion(roll: f64, pitch: f64, yaw: f64) -> [f32; 4] {
    let (sr, cr) = (roll / 2.0).sin_cos();
    let (sp, cp) = (pitch / 2.0).sin_cos();
    let (sy, cy) = (yaw / 2.0).sin_cos();
    [
        (cr * cp * cy + sr * sp * sy) as f32,
        (sr * cp * cy - cr * sp * sy) as f32,
        (cr * sp * cy + sr * cp * sy) as f32,
        (cr * cp * sy - sr * sp * cy) as f32,
    ]
}

/// The ULog of `run`, with `params` (id, value) as its parameters.
pub fn build(run: &RunLogs, params: &[(String, f64)]) -> std::result::Result<Vec<u8>, String> {
    let mut u = Ulog::new(0);
    u.info("sys_name", "uquad")?;
    u.info("ver_sw", env!("CARGO_PKG_VERSION"))?;
    u.info("uquad_run", &run.dir.display().to_string())?;
    for (id, v) in params {
        u.param(id, *v as f32)?;
    }
    for (name, fields) in TOPICS {
        u.topic(name, fields)?;
    }
    estimates(&mut u, run)?;
    setpoints(&mut u, run)?;
    for (t, w) in &run.w {
        let out = [
            V::U32(4),
            V::F64(w[0]),
            V::F64(w[1]),
            V::F64(w[2]),
            V::F64(w[3]),
        ];
        u.data("actuator_outputs", ts(*t), &out)?;
    }
    raw(&mut u, run)?;
    sensors(&mut u, run)?;
    gps(&mut u, run)?;
    modes(&mut u, run)?;
    // err.log's lines carry no time: they are logged at the start, in order, named.
    for line in run.err_log.lines().filter(|l| !l.trim().is_empty()) {
        u.log(Level::Info, 0, &format!("err.log: {line}"))?;
    }
    Ok(u.finish())
}

fn estimates(u: &mut Ulog, run: &RunLogs) -> Result {
    for (x, t) in run.x_hat.iter().zip(run.estimate_times_us()) {
        let (p, v) = ned(x);
        // θ is unwrapped in the logs; PX4's yaw lies in ±π.
        let (roll, pitch, yaw) = (x[3], -x[4], wrap_pi(-x[5]));
        let q = quaternion(roll, pitch, yaw);
        u.data("vehicle_attitude", ts(t), &q.map(V::F32))?;
        let lp = [
            V::F64(p[0]),
            V::F64(p[1]),
            V::F64(p[2]),
            V::F64(v[0]),
            V::F64(v[1]),
            V::F64(v[2]),
            V::F64(yaw),
            V::Bool(true),
            V::Bool(true),
        ];
        u.data("vehicle_local_position", ts(t), &lp)?;
    }
    for r in &run.innov {
        let gps = r.ratios.gps.unwrap_or(f64::NAN);
        let mask = crate::logs::InnovRecord::gated_mask(r.gated);
        let v = [
            V::F64(r.ratios.attitude),
            V::F64(r.ratios.altitude),
            V::F64(gps),
            V::U8(mask),
        ];
        u.data("estimator_status", ts(r.t_us), &v)?;
    }
    Ok(())
}

fn setpoints(u: &mut Ulog, run: &RunLogs) -> Result {
    for (t, sp) in &run.setpoint {
        let yaw = wrap_pi(-sp[5]);
        let pos = [V::F64(sp[0]), V::F64(-sp[1]), V::F64(-sp[2]), V::F64(yaw)];
        u.data("vehicle_local_position_setpoint", ts(*t), &pos)?;
        let att = [V::F64(sp[3]), V::F64(-sp[4]), V::F64(yaw)];
        u.data("vehicle_attitude_setpoint", ts(*t), &att)?;
    }
    Ok(())
}

fn raw(u: &mut Ulog, run: &RunLogs) -> Result {
    for r in &run.imu_raw {
        let f = &r.frame;
        let mut v = vec![V::U32(f.t_us)];
        v.extend(
            f.acc
                .iter()
                .chain(&f.gyro)
                .chain(&f.magn)
                .map(|&c| V::I32(i32::from(c))),
        );
        v.extend([V::I32(i32::from(f.temp_dc)), V::U32(f.pres_pa)]);
        u.data("uquad_imu_raw", ts(r.t_main_us), &v)?;
    }
    Ok(())
}

fn sensors(u: &mut Ulog, run: &RunLogs) -> Result {
    for k in &run.kalman_in {
        let (g, a) = (k.gyro_rad_s, k.acc_m_s2);
        let v = [
            V::F64(g[0]),
            V::F64(-g[1]),
            V::F64(-g[2]),
            V::F64(a[0]),
            V::F64(-a[1]),
            V::F64(-a[2]),
        ];
        u.data("sensor_combined", ts(k.t_us), &v)?;
        u.data(
            "vehicle_air_data",
            ts(k.t_us),
            &[V::F64(k.alt_m), V::F64(k.temp_c)],
        )?;
    }
    Ok(())
}

/// The fixes of a gpsd gps.log (a fake-GPS log has none).
fn gps(u: &mut Ulog, run: &RunLogs) -> Result {
    for r in &run.gps {
        let GpsLogRecord::Gpsd {
            t_us,
            fix_mode,
            vel_m_s,
            lat_deg,
            lon_deg,
            ..
        } = *r
        else {
            continue;
        };
        let e7 = |d: f64| (d * 1e7).round().clamp(-2.1e9, 2.1e9) as i32;
        let v = vel_m_s.unwrap_or([f64::NAN; 3]);
        let fix = [
            V::I32(e7(lat_deg)),
            V::I32(e7(lon_deg)),
            V::F64(lat_deg),
            V::F64(lon_deg),
            V::U8(u8::try_from(fix_mode.clamp(0, 255)).unwrap_or(0)),
            V::F64(v[0]),
            V::F64(-v[1]),
            V::F64(-v[2]),
            V::Bool(vel_m_s.is_some()),
        ];
        u.data("vehicle_gps_position", ts(t_us), &fix)?;
    }
    Ok(())
}

/// PX4's navigation state nearest each of uquad's modes (vehicle_status.nav_state); uquad's
/// own is `custom_mode` (HEARTBEAT's numbering).
fn nav_state(custom: usize) -> u8 {
    match CUSTOM_MODES.get(custom).map(|m| m.name()) {
        Some("takeoff") => 17,
        Some("land") => 18,
        Some("kill") => 13,
        Some("mission") => 3,
        Some("return") => 5,
        // Disarmed, armed on the ground, hold: loiter.
        _ => 4,
    }
}

/// mode.log's outputs: vehicle_status at each mode change and failsafe, and every output
/// line as a logged message at its time.
fn modes(u: &mut Ulog, run: &RunLogs) -> Result {
    let (mut custom, mut failsafe) = (0usize, false);
    for line in run.mode_log.lines() {
        let mut w = line.splitn(3, ' ');
        let (Some(t), Some(kind), Some(rest)) = (w.next(), w.next(), w.next()) else {
            continue;
        };
        let Ok(t_us) = t.parse::<i64>() else { continue };
        let level = match kind {
            "mode" => {
                let name = rest.split(' ').next().unwrap_or("");
                custom = CUSTOM_MODES
                    .iter()
                    .position(|m| m.name() == name)
                    .unwrap_or(0);
                // A failsafe lasts until the vehicle is back on the ground, disarmed.
                failsafe &= custom != 0;
                Level::Info
            }
            "failsafe" => {
                failsafe = true;
                Level::Critical
            }
            "refused" => Level::Warning,
            "reached" => Level::Info,
            _ => continue,
        };
        u.log(level, ts(t_us), &format!("{kind} {rest}"))?;
        if matches!(kind, "mode" | "failsafe") {
            // Standby (1) when disarmed or killed, else armed (2).
            let on_ground = matches!(
                CUSTOM_MODES.get(custom).map(|m| m.name()),
                Some("disarmed" | "kill")
            );
            let armed = if on_ground { 1 } else { 2 };
            let status = [
                V::U8(armed),
                V::U8(nav_state(custom)),
                V::Bool(failsafe),
                V::U8(custom as u8),
            ];
            u.data("vehicle_status", ts(t_us), &status)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternions_of_level_and_turned_attitudes() {
        assert_eq!(quaternion(0.0, 0.0, 0.0), [1.0, 0.0, 0.0, 0.0]);
        let q = quaternion(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let h = std::f32::consts::FRAC_1_SQRT_2;
        assert!((q[0] - h).abs() < 1e-6 && (q[3] - h).abs() < 1e-6, "{q:?}");
    }

    #[test]
    fn modes_map_onto_px4_navigation_states() {
        let names: Vec<(&str, u8)> = (0..CUSTOM_MODES.len())
            .map(|i| (CUSTOM_MODES[i].name(), nav_state(i)))
            .collect();
        assert!(names.contains(&("mission", 3)) && names.contains(&("return", 5)));
        assert!(names.contains(&("land", 18)) && names.contains(&("hold", 4)));
    }
}
