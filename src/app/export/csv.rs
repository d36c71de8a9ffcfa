//! A run folder as CSV: one file per stream, a header row naming each column with its unit
//! (`name [unit]`), numbers in the shortest form that reads back to the same double. Each
//! log is read a line at a time and written as it is read (memory does not grow with the
//! run's length); a line over-long, cut off or not understood is skipped and reported.

use crate::app::log_lines::{EstimateTimes, LogLines};
use crate::logs::{self, GpsLogRecord, ImuRawRecord, InnovRecord, KalmanInRecord};
use anyhow::Context;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

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

fn kalman_in_row(k: &KalmanInRecord) -> Vec<String> {
    let mut v = vec![k.dt_us as f64 / 1e6];
    v.extend(k.acc_m_s2.iter().chain(&k.gyro_rad_s).chain(&k.euler_rad));
    v.extend([k.temp_c, k.alt_m]);
    row(k.t_us, &v)
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

/// A mode.log line: time, record (mode, failsafe, refused, reached, in, beat, key,
/// mission, run) and the rest of the line as written.
fn mode_row(line: &str) -> Option<Vec<String>> {
    let mut w = line.splitn(3, ' ');
    let t_us: i64 = w.next()?.parse().ok()?;
    let kind = w.next()?.to_string();
    Some(vec![secs(t_us), kind, w.next().unwrap_or("").to_string()])
}

/// Writes the CSV files of the run in `run_dir` into `out_dir` (created) as `NAME.csv.partial`,
/// each stream read a line at a time and written as it is read, so that memory does not grow
/// with the run's length; a warning for each log that had lines skipped (over-long, cut off,
/// not understood). A stream without rows writes no file.
pub fn write(run_dir: &Path, out_dir: &Path) -> anyhow::Result<Written> {
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let mut w = Writer {
        run_dir,
        out_dir,
        written: Vec::new(),
        warnings: Vec::new(),
    };
    w.stream("imu_raw", IMU_RAW, ImuRawRecord::parse_fields, |r| {
        Ok(Some(raw_row(&r)))
    })?;
    // Each estimate at the time of kalman_in's record on its line (kalman_in.log's own
    // skipped lines are told by its stream below).
    let mut times = EstimateTimes::open(run_dir)?;
    w.rows("x_hat", X_HAT, |lines| {
        match lines.next(logs::parse_x_hat)? {
            Some(x) => Ok(Some(Some(row(times.at(lines.last_index())?, &x)))),
            None => Ok(None),
        }
    })?;
    let estimates = w.rows_of("x_hat");
    w.stream("kalman_in", KALMAN_IN, KalmanInRecord::parse_fields, |k| {
        Ok(Some(kalman_in_row(&k)))
    })?;
    w.stream("w", W, logs::parse_time_and_4, |(t, v)| {
        Ok(Some(row(t, &v)))
    })?;
    w.stream("setpoint", SETPOINT, logs::parse_time_and::<6>, |(t, v)| {
        Ok(Some(row(t, &v)))
    })?;
    w.stream("innov", INNOV, InnovRecord::parse_fields, |r| {
        Ok(Some(innov_row(&r)))
    })?;
    w.stream("gps", GPS, GpsLogRecord::parse_fields, |r| Ok(gps_row(&r)))?;
    w.stream_text("mode", MODE, |line| Ok(mode_row(line)))?;
    Ok(Written {
        files: w.written.into_iter().map(|(path, _)| path).collect(),
        warnings: w.warnings,
        estimates,
    })
}

/// What [`write`] wrote: its files (still `.partial`, for the caller to keep or remove),
/// the logs' skipped lines, and how many estimates (x_hat rows) there were.
pub struct Written {
    pub files: Vec<PathBuf>,
    pub warnings: Vec<String>,
    pub estimates: u64,
}

/// Where the CSV files go, and what was written.
struct Writer<'a> {
    run_dir: &'a Path,
    out_dir: &'a Path,
    /// Each file written and its rows.
    written: Vec<(PathBuf, u64)>,
    warnings: Vec<String>,
}

impl Writer<'_> {
    /// `NAME.log`'s records, parsed by `parse`, each made a row by `to_row` (none: left
    /// out), into `NAME.csv`.
    fn stream<T>(
        &mut self,
        name: &str,
        header: &[&str],
        parse: impl Fn(&[&str]) -> Result<T, String>,
        mut to_row: impl FnMut(T) -> anyhow::Result<Option<Vec<String>>>,
    ) -> anyhow::Result<()> {
        self.rows(name, header, |lines| match lines.next(&parse)? {
            Some(r) => to_row(r).map(Some),
            None => Ok(None),
        })
    }

    /// `NAME.log`'s lines as they are written, each made a row by `to_row` (none: left out).
    fn stream_text(
        &mut self,
        name: &str,
        header: &[&str],
        to_row: impl Fn(&str) -> anyhow::Result<Option<Vec<String>>>,
    ) -> anyhow::Result<()> {
        self.rows(name, header, |lines| match lines.next_raw()? {
            Some(line) => to_row(line).map(Some),
            None => Ok(None),
        })
    }

    /// The rows written for `name`.
    fn rows_of(&self, name: &str) -> u64 {
        let file = format!("{name}.csv.partial");
        self.written
            .iter()
            .find(|(p, _)| p.file_name().is_some_and(|f| *f == *file))
            .map_or(0, |(_, n)| *n)
    }

    /// The rows `next` gives (`Some(None)`: a record left out) into `NAME.csv.partial`,
    /// created at the first row.
    fn rows(
        &mut self,
        name: &str,
        header: &[&str],
        mut next: impl FnMut(&mut LogLines) -> anyhow::Result<Option<Option<Vec<String>>>>,
    ) -> anyhow::Result<()> {
        let Some(mut lines) = LogLines::open(&self.run_dir.join(format!("{name}.log")))? else {
            return Ok(());
        };
        let path = self.out_dir.join(format!("{name}.csv.partial"));
        let mut rows = 0u64;
        let mut out: Option<BufWriter<File>> = None;
        let io = |e: std::io::Error| anyhow::anyhow!("cannot write {}: {e}", path.display());
        while let Some(cells) = next(&mut lines)? {
            let Some(cells) = cells else {
                continue;
            };
            let f = match out.as_mut() {
                Some(f) => f,
                None => {
                    let file = File::create(&path).map_err(io)?;
                    let f = out.insert(BufWriter::with_capacity(64 * 1024, file));
                    write_row(f, header.iter().copied()).map_err(io)?;
                    f
                }
            };
            write_row(f, cells.iter().map(String::as_str)).map_err(io)?;
            rows += 1;
        }
        if let Some(mut f) = out {
            self.written.push((path.clone(), rows));
            f.flush().map_err(io)?;
        }
        self.warnings.extend(lines.warning());
        Ok(())
    }
}

/// One CSV row: the cells, quoted where needed, comma-separated.
fn write_row<'c>(f: &mut impl Write, cells: impl Iterator<Item = &'c str>) -> std::io::Result<()> {
    for (i, c) in cells.enumerate() {
        if i > 0 {
            f.write_all(b",")?;
        }
        f.write_all(cell(c).as_bytes())?;
    }
    f.write_all(b"\n")
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
