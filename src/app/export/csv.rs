//! A run folder as CSV: one file per stream, a header row naming each column with its unit
//! (`name [unit]`), numbers in the shortest form that reads back to the same double.

use crate::app::run_logs::RunLogs;
use crate::logs::{GpsLogRecord, ImuRawRecord, InnovRecord};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A table: its header and rows of cells.
struct Table {
    header: &'static [&'static str],
    rows: Vec<Vec<String>>,
}

const X_HAT: &[&str] = &[
    "t [s]",
    "x north [m]",
    "y west [m]",
    "z up [m]",
    "roll psi [rad]",
    "pitch phi [rad]",
    "yaw theta [rad]",
    "vqx body [m/s]",
    "vqy body [m/s]",
    "vqz body [m/s]",
    "wqx body [rad/s]",
    "wqy body [rad/s]",
    "wqz body [rad/s]",
    "bax accelerometer bias [m/s^2]",
    "bay accelerometer bias [m/s^2]",
    "baz accelerometer bias [m/s^2]",
];
const KALMAN_IN: &[&str] = &[
    "t [s]",
    "dt imu [s]",
    "acc x [m/s^2]",
    "acc y [m/s^2]",
    "acc z [m/s^2]",
    "gyro x [rad/s]",
    "gyro y [rad/s]",
    "gyro z [rad/s]",
    "roll psi [rad]",
    "pitch phi [rad]",
    "yaw theta [rad]",
    "temperature [degC]",
    "altitude [m]",
];
const W: &[&str] = &[
    "t [s]",
    "motor 0 [rad/s]",
    "motor 1 [rad/s]",
    "motor 2 [rad/s]",
    "motor 3 [rad/s]",
];
/// The set point's columns are the estimate's first seven (time, position, attitude).
const SETPOINT: &[&str] = X_HAT.split_at(7).0;
const INNOV: &[&str] = &[
    "t [s]",
    "attitude test ratio [1]",
    "altitude test ratio [1]",
    "gps test ratio [1]",
    "gated groups (1 attitude + 2 altitude + 4 gps) [1]",
];
const GPS: &[&str] = &[
    "t [s]",
    "fix mode [1]",
    "x north [m]",
    "y west [m]",
    "z up [m]",
    "vx north [m/s]",
    "vy west [m/s]",
    "vz up [m/s]",
    "latitude [deg]",
    "longitude [deg]",
];
const MODE: &[&str] = &["t [s]", "record [text]", "what [text]"];
const IMU_RAW: &[&str] = &[
    "t [s]",
    "t frame [s]",
    "frame dt [us]",
    "acc x [counts]",
    "acc y [counts]",
    "acc z [counts]",
    "gyro x [counts]",
    "gyro y [counts]",
    "gyro z [counts]",
    "mag x [counts]",
    "mag y [counts]",
    "mag z [counts]",
    "temperature [0.1 degC]",
    "pressure [Pa]",
];

fn num(v: f64) -> String {
    format!("{v}")
}

fn secs(t_us: i64) -> String {
    crate::logs::fmt_time_us(t_us)
}

/// A cell quoted when it holds a comma, a quote or a line end.
fn cell(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn row(t_us: i64, values: &[f64]) -> Vec<String> {
    std::iter::once(secs(t_us))
        .chain(values.iter().map(|&v| num(v)))
        .collect()
}

fn tables(run: &RunLogs) -> Vec<(&'static str, Table)> {
    let x_hat = run
        .x_hat
        .iter()
        .zip(run.estimate_times_us())
        .map(|(x, t)| row(t, x))
        .collect();
    let kalman_in = run
        .kalman_in
        .iter()
        .map(|k| {
            let mut v = vec![k.dt_us as f64 / 1e6];
            v.extend(k.acc_m_s2.iter().chain(&k.gyro_rad_s).chain(&k.euler_rad));
            v.extend([k.temp_c, k.alt_m]);
            row(k.t_us, &v)
        })
        .collect();
    let t = |header, rows| Table { header, rows };
    let mut out = vec![
        (
            "imu_raw",
            t(IMU_RAW, run.imu_raw.iter().map(raw_row).collect()),
        ),
        ("x_hat", t(X_HAT, x_hat)),
        ("kalman_in", t(KALMAN_IN, kalman_in)),
        ("w", t(W, run.w.iter().map(|(t, v)| row(*t, v)).collect())),
        (
            "setpoint",
            t(
                SETPOINT,
                run.setpoint.iter().map(|(t, v)| row(*t, v)).collect(),
            ),
        ),
        ("innov", t(INNOV, run.innov.iter().map(innov_row).collect())),
        ("gps", t(GPS, run.gps.iter().filter_map(gps_row).collect())),
        ("mode", t(MODE, mode_rows(&run.mode_log))),
    ];
    out.retain(|(_, t)| !t.rows.is_empty());
    out
}

fn raw_row(r: &ImuRawRecord) -> Vec<String> {
    let f = &r.frame;
    let mut cells = vec![secs(r.t_main_us), secs(r.t_frame_us), f.t_us.to_string()];
    let counts = f
        .acc
        .iter()
        .chain(&f.gyro)
        .chain(&f.magn)
        .chain([&f.temp_dc]);
    cells.extend(counts.map(|c| c.to_string()));
    cells.push(f.pres_pa.to_string());
    cells
}

fn innov_row(r: &InnovRecord) -> Vec<String> {
    let v = [
        r.ratios.attitude,
        r.ratios.altitude,
        r.ratios.gps.unwrap_or(f64::NAN),
        f64::from(InnovRecord::gated_mask(r.gated)),
    ];
    row(r.t_us, &v)
}

fn gps_row(r: &GpsLogRecord) -> Option<Vec<String>> {
    let GpsLogRecord::Gpsd {
        t_us,
        fix_mode,
        pos_m,
        vel_m_s,
        lat_deg,
        lon_deg,
        ..
    } = *r
    else {
        return None;
    };
    let v = vel_m_s.unwrap_or([f64::NAN; 3]);
    let mut values = vec![f64::from(fix_mode)];
    values.extend(pos_m.iter().chain(&v));
    values.extend([lat_deg, lon_deg]);
    Some(row(t_us, &values))
}

/// mode.log's lines: time, record (mode, failsafe, refused, reached, in, beat, key,
/// mission) and the rest of the line.
fn mode_rows(text: &str) -> Vec<Vec<String>> {
    text.lines()
        .filter_map(|l| {
            let mut w = l.splitn(3, ' ');
            let t_us: i64 = w.next()?.parse().ok()?;
            let kind = w.next()?.to_string();
            Some(vec![secs(t_us), kind, w.next().unwrap_or("").to_string()])
        })
        .collect()
}

/// Writes the CSV files of `run` into `out_dir` (created); returns them.
pub fn write(run: &RunLogs, out_dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    use anyhow::Context;
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let mut written = Vec::new();
    for (name, table) in tables(run) {
        let mut s = String::with_capacity(table.rows.len() * 160);
        let header: Vec<String> = table.header.iter().map(|h| cell(h)).collect();
        let _ = writeln!(s, "{}", header.join(","));
        for r in &table.rows {
            let cells: Vec<String> = r.iter().map(|c| cell(c)).collect();
            let _ = writeln!(s, "{}", cells.join(","));
        }
        let path = out_dir.join(format!("{name}.csv"));
        std::fs::write(&path, s).with_context(|| format!("cannot write {}", path.display()))?;
        written.push(path);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_with_commas_or_quotes_are_quoted() {
        assert_eq!(cell("a,b"), "\"a,b\"");
        assert_eq!(cell("say \"hi\""), "\"say \"\"hi\"\"\"");
        assert_eq!(cell("plain"), "plain");
    }

    #[test]
    fn numbers_read_back_exactly() {
        for v in [0.1, 1.0 / 3.0, -2.5e-17, 12_345.678_901_234_5] {
            assert_eq!(num(v).parse::<f64>().unwrap(), v);
        }
    }

    #[test]
    fn every_header_names_a_unit() {
        for h in [IMU_RAW, X_HAT, KALMAN_IN, W, SETPOINT, INNOV, GPS, MODE] {
            assert!(
                h.iter().all(|c| c.ends_with(']') && c.contains(" [")),
                "{h:?}"
            );
        }
    }
}
