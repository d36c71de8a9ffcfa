//! A run folder as a ULog, under PX4's topic and field names where a counterpart exists, so
//! Flight Review, PlotJuggler and pyulog plot it without a mapping. Frames are PX4's:
//! north-east-down and forward-right-down (uquad's y and z change sign; roll stays, pitch and
//! yaw change sign). Values from the text logs are written as doubles, so they read back
//! equal to what the text printed. Each log is read a line at a time and the logs merged by
//! time as the file is written: memory does not grow with the run's length.

use crate::app::log_lines::{EstimateTimes, LogLines};
use crate::core::commander::Mode;
use crate::gcs::telemetry::{ned, wrap_pi};
use crate::logs::ulog::{Fields, Level, Type::*, Ulog, Value as V};
use crate::logs::{self, GpsLogRecord, ImuRawRecord, InnovRecord, KalmanInRecord};
use anyhow::Context;
use std::cell::Cell;
use std::collections::VecDeque;
use std::io::Write;
use std::path::Path;
use std::rc::Rc;

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
            ("alt", I32, 1),
            ("latitude_deg", F64, 1),
            ("longitude_deg", F64, 1),
            ("altitude_msl_m", F64, 1),
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

/// Writes the ULog of the run in `run_dir` (its path named in the log as given) to `out`,
/// with `params` (id, value) as its parameters. Each log is read a line at a time and the
/// data is merged by time as it is written (memory does not grow with the run's length);
/// returns a warning for each log that had lines skipped or whose times went back (its
/// messages are then out of time order in the file), and how many estimates were written.
pub fn write(
    run_dir: &Path,
    params: &[(String, f64)],
    out: &mut impl Write,
) -> anyhow::Result<(Vec<String>, u64)> {
    let mut u = Ulog::new(0);
    u.info("sys_name", "uquad").map_err(anyhow::Error::msg)?;
    u.info("ver_sw", env!("CARGO_PKG_VERSION"))
        .map_err(anyhow::Error::msg)?;
    u.info("uquad_run", &run_dir.display().to_string())
        .map_err(anyhow::Error::msg)?;
    for (id, v) in params {
        u.param(id, *v as f32).map_err(anyhow::Error::msg)?;
    }
    for (name, fields) in TOPICS {
        u.topic(name, fields).map_err(anyhow::Error::msg)?;
    }
    let estimates = Rc::new(Cell::new(0u64));
    let mut sources = sources(run_dir, estimates.clone())?;
    out.write_all(&u.head()).context("cannot write the ULog")?;
    merge(&u, &mut sources, out)?;
    let mut warnings = Vec::new();
    for s in &sources {
        warnings.extend(s.lines.as_ref().and_then(LogLines::warning));
        if let (Some(l), Some(at)) = (&s.lines, &s.went_back) {
            warnings.push(format!(
                "{}: {} time(s) earlier than the one before (the first at {at} µs): its messages are out of time order in the ULog",
                l.path().display(),
                s.backs
            ));
        }
    }
    Ok((warnings, estimates.get()))
}

/// A log's messages, one record's at a time.
type Read = Box<dyn FnMut(&mut LogLines, &Ulog, &mut Pending) -> anyhow::Result<bool>>;
/// A source's messages read and not yet written: time and bytes.
type Pending = VecDeque<(u64, Vec<u8>)>;

/// One log of the run as ULog messages in its own time order.
struct Source {
    lines: Option<LogLines>,
    /// Reads the next record's messages into the pending ones; `false` at the log's end.
    read: Read,
    pending: Pending,
    /// The newest time read, and how often (and first where) a time went back.
    newest: u64,
    backs: u64,
    went_back: Option<u64>,
}

impl Source {
    fn new(run_dir: &Path, name: &str, read: Read) -> anyhow::Result<Source> {
        Ok(Source {
            lines: LogLines::open(&run_dir.join(name))?,
            read,
            pending: VecDeque::with_capacity(4),
            newest: 0,
            backs: 0,
            went_back: None,
        })
    }

    /// The time of its next message, reading a record when none is pending.
    fn next_t(&mut self, u: &Ulog) -> anyhow::Result<Option<u64>> {
        while self.pending.is_empty() {
            let Some(lines) = self.lines.as_mut() else {
                return Ok(None);
            };
            if !(self.read)(lines, u, &mut self.pending)? {
                return Ok(None);
            }
            if let Some(&(t, _)) = self.pending.front() {
                if t < self.newest {
                    self.backs += 1;
                    self.went_back.get_or_insert(t);
                }
                self.newest = self.newest.max(t);
            }
        }
        Ok(self.pending.front().map(|(t, _)| *t))
    }
}

/// Writes every source's messages in time order; at one time, in the sources' order (each
/// source's own order kept), as a sort by time over the whole run would.
fn merge(u: &Ulog, sources: &mut [Source], out: &mut impl Write) -> anyhow::Result<()> {
    loop {
        let mut next: Option<(u64, usize)> = None;
        for (i, s) in sources.iter_mut().enumerate() {
            if let Some(t) = s.next_t(u)?
                && next.is_none_or(|(best, _)| t < best)
            {
                next = Some((t, i));
            }
        }
        let Some((_, i)) = next else {
            return Ok(());
        };
        if let Some((_, bytes)) = sources[i].pending.pop_front() {
            out.write_all(&bytes).context("cannot write the ULog")?;
        }
    }
}

/// A message built, or the ULog writer's refusal as an error.
fn msg(m: std::result::Result<Vec<u8>, String>) -> anyhow::Result<Vec<u8>> {
    m.map_err(anyhow::Error::msg)
}

/// The run's logs as sources, in the order their messages go at one time; `estimates`
/// counts the estimates read.
fn sources(run_dir: &Path, estimates: Rc<Cell<u64>>) -> anyhow::Result<Vec<Source>> {
    let mut times = EstimateTimes::open(run_dir)?;
    Ok(vec![
        Source::new(
            run_dir,
            "x_hat.log",
            Box::new(move |l, u, p| {
                let Some(x) = l.next(logs::parse_x_hat)? else {
                    return Ok(false);
                };
                estimates.set(estimates.get() + 1);
                estimate(u, times.at(l.last_index())?, &x, p)?;
                Ok(true)
            }),
        )?,
        Source::new(run_dir, "innov.log", Box::new(innov))?,
        Source::new(run_dir, "setpoint.log", Box::new(setpoint))?,
        Source::new(run_dir, "w.log", Box::new(motors))?,
        Source::new(run_dir, "imu_raw.log", Box::new(raw))?,
        Source::new(run_dir, "kalman_in.log", Box::new(sensors))?,
        Source::new(run_dir, "gps.log", Box::new(gps))?,
        Source::new(run_dir, "mode.log", modes())?,
        // err.log's lines carry no time: they are logged at the start, in order, named.
        Source::new(
            run_dir,
            "err.log",
            Box::new(|l, _, p| {
                let Some(line) = l.next_raw()? else {
                    return Ok(false);
                };
                if !line.trim().is_empty() {
                    let text = format!("err.log: {line}");
                    p.push_back((0, msg(Ulog::log_message(Level::Info, 0, &text))?));
                }
                Ok(true)
            }),
        )?,
    ])
}

fn estimate(u: &Ulog, t_us: i64, x: &[f64; 15], p: &mut Pending) -> anyhow::Result<()> {
    let t = ts(t_us);
    let (pos, v) = ned(x);
    // θ is unwrapped in the logs; PX4's yaw lies in ±π.
    let (roll, pitch, yaw) = (x[3], -x[4], wrap_pi(-x[5]));
    let q = quaternion(roll, pitch, yaw);
    p.push_back((
        t,
        msg(u.data_message("vehicle_attitude", t, &q.map(V::F32)))?,
    ));
    let lp = [
        V::F64(pos[0]),
        V::F64(pos[1]),
        V::F64(pos[2]),
        V::F64(v[0]),
        V::F64(v[1]),
        V::F64(v[2]),
        V::F64(yaw),
        V::Bool(true),
        V::Bool(true),
    ];
    p.push_back((t, msg(u.data_message("vehicle_local_position", t, &lp))?));
    Ok(())
}

fn innov(l: &mut LogLines, u: &Ulog, p: &mut Pending) -> anyhow::Result<bool> {
    let Some(r) = l.next(InnovRecord::parse_fields)? else {
        return Ok(false);
    };
    let gps = r.ratios.gps.unwrap_or(f64::NAN);
    let v = [
        V::F64(r.ratios.attitude),
        V::F64(r.ratios.altitude),
        V::F64(gps),
        V::U8(InnovRecord::gated_mask(r.gated)),
    ];
    let t = ts(r.t_us);
    p.push_back((t, msg(u.data_message("estimator_status", t, &v))?));
    Ok(true)
}

fn setpoint(l: &mut LogLines, u: &Ulog, p: &mut Pending) -> anyhow::Result<bool> {
    let Some((t_us, sp)) = l.next(logs::parse_time_and::<6>)? else {
        return Ok(false);
    };
    let t = ts(t_us);
    let yaw = wrap_pi(-sp[5]);
    let pos = [V::F64(sp[0]), V::F64(-sp[1]), V::F64(-sp[2]), V::F64(yaw)];
    p.push_back((
        t,
        msg(u.data_message("vehicle_local_position_setpoint", t, &pos))?,
    ));
    let att = [V::F64(sp[3]), V::F64(-sp[4]), V::F64(yaw)];
    p.push_back((
        t,
        msg(u.data_message("vehicle_attitude_setpoint", t, &att))?,
    ));
    Ok(true)
}

fn motors(l: &mut LogLines, u: &Ulog, p: &mut Pending) -> anyhow::Result<bool> {
    let Some((t_us, w)) = l.next(logs::parse_time_and_4)? else {
        return Ok(false);
    };
    let out = [
        V::U32(4),
        V::F64(w[0]),
        V::F64(w[1]),
        V::F64(w[2]),
        V::F64(w[3]),
    ];
    let t = ts(t_us);
    p.push_back((t, msg(u.data_message("actuator_outputs", t, &out))?));
    Ok(true)
}

fn raw(l: &mut LogLines, u: &Ulog, p: &mut Pending) -> anyhow::Result<bool> {
    let Some(r) = l.next(ImuRawRecord::parse_fields)? else {
        return Ok(false);
    };
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
    let t = ts(r.t_main_us);
    p.push_back((t, msg(u.data_message("uquad_imu_raw", t, &v))?));
    Ok(true)
}

fn sensors(l: &mut LogLines, u: &Ulog, p: &mut Pending) -> anyhow::Result<bool> {
    let Some(k) = l.next(KalmanInRecord::parse_fields)? else {
        return Ok(false);
    };
    let (g, a) = (k.gyro_rad_s, k.acc_m_s2);
    let v = [
        V::F64(g[0]),
        V::F64(-g[1]),
        V::F64(-g[2]),
        V::F64(a[0]),
        V::F64(-a[1]),
        V::F64(-a[2]),
    ];
    let t = ts(k.t_us);
    p.push_back((t, msg(u.data_message("sensor_combined", t, &v))?));
    let air = [V::F64(k.alt_m), V::F64(k.temp_c)];
    p.push_back((t, msg(u.data_message("vehicle_air_data", t, &air))?));
    Ok(true)
}

/// The fixes of a gpsd gps.log (a fake-GPS log has none).
fn gps(l: &mut LogLines, u: &Ulog, p: &mut Pending) -> anyhow::Result<bool> {
    let Some(r) = l.next(GpsLogRecord::parse_fields)? else {
        return Ok(false);
    };
    let GpsLogRecord::Gpsd {
        t_us,
        fix_mode,
        pos_m,
        vel_m_s,
        lat_deg,
        lon_deg,
        ..
    } = r
    else {
        return Ok(true);
    };
    let e7 = |d: f64| (d * 1e7).round().clamp(-2.1e9, 2.1e9) as i32;
    let v = vel_m_s.unwrap_or([f64::NAN; 3]);
    // The altitude as gps.log has it: the receiver's in the original's logs; in uquad's, up
    // from the first fix (its local frame's z: no sea-level altitude is logged).
    let alt_m = pos_m[2];
    let fix = [
        V::I32(e7(lat_deg)),
        V::I32(e7(lon_deg)),
        V::I32((alt_m * 1e3).round().clamp(-2.1e9, 2.1e9) as i32),
        V::F64(lat_deg),
        V::F64(lon_deg),
        V::F64(alt_m),
        V::U8(u8::try_from(fix_mode.clamp(0, 255)).unwrap_or(0)),
        V::F64(v[0]),
        V::F64(-v[1]),
        V::F64(-v[2]),
        V::Bool(vel_m_s.is_some()),
    ];
    let t = ts(t_us);
    p.push_back((t, msg(u.data_message("vehicle_gps_position", t, &fix))?));
    Ok(true)
}

/// PX4's navigation state nearest each of uquad's modes (vehicle_status.nav_state); uquad's
/// own is `custom_mode` (its index in `Mode::ALL`, uquad's own numbering).
fn nav_state(custom: usize) -> u8 {
    match Mode::ALL.get(custom).map(|m| m.name()) {
        Some("takeoff") => 17,
        Some("land") => 18,
        Some("kill") => 13,
        Some("mission") => 3,
        Some("return") => 5,
        Some("altitude") => 1,
        Some("position") => 2,
        // Disarmed, armed on the ground, hold: loiter.
        _ => 4,
    }
}

/// mode.log's outputs: vehicle_status at each mode change and failsafe, and every output
/// line as a logged message at its time.
fn modes() -> Read {
    let (mut custom, mut failsafe) = (0usize, false);
    Box::new(move |l, u, p| {
        let Some(line) = l.next_raw()? else {
            return Ok(false);
        };
        let mut w = line.splitn(3, ' ');
        let (Some(t), Some(kind), Some(rest)) = (w.next(), w.next(), w.next()) else {
            return Ok(true);
        };
        let Ok(t_us) = t.parse::<i64>() else {
            return Ok(true);
        };
        let level = match kind {
            "mode" => {
                let name = rest.split(' ').next().unwrap_or("");
                custom = Mode::ALL.iter().position(|m| m.name() == name).unwrap_or(0);
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
            _ => return Ok(true),
        };
        let t = ts(t_us);
        let text = format!("{kind} {rest}");
        p.push_back((t, msg(Ulog::log_message(level, t, &text))?));
        if matches!(kind, "mode" | "failsafe") {
            // Standby (1) when disarmed or killed, else armed (2).
            let on_ground = matches!(
                Mode::ALL.get(custom).map(|m| m.name()),
                Some("disarmed" | "kill")
            );
            let status = [
                V::U8(if on_ground { 1 } else { 2 }),
                V::U8(nav_state(custom)),
                V::Bool(failsafe),
                V::U8(custom as u8),
            ];
            p.push_back((t, msg(u.data_message("vehicle_status", t, &status))?));
        }
        Ok(true)
    })
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
        let names: Vec<(&str, u8)> = (0..Mode::ALL.len())
            .map(|i| (Mode::ALL[i].name(), nav_state(i)))
            .collect();
        assert!(names.contains(&("mission", 3)) && names.contains(&("return", 5)));
        assert!(names.contains(&("land", 18)) && names.contains(&("hold", 4)));
    }
}
