//! A run folder's streams read back for the tools that show them (`uquad plot`, `uquad
//! export`): ours, or the original's (which have no setpoint, innov, mode or config). A
//! stream that is missing is empty; one that cannot be read or parsed is an error naming it.

use crate::config::bounded::{self, FileKind};
use crate::logs::{self, GpsLogRecord, ImuRawRecord, InnovRecord, KalmanInRecord, Parsed};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// The streams of a run folder, as parsed.
#[derive(Debug, Clone, Default)]
pub struct RunLogs {
    pub dir: PathBuf,
    pub imu_raw: Vec<ImuRawRecord>,
    pub kalman_in: Vec<KalmanInRecord>,
    pub x_hat: Vec<[f64; 15]>,
    pub innov: Vec<InnovRecord>,
    pub w: Vec<(i64, [f64; 4])>,
    pub setpoint: Vec<(i64, [f64; 6])>,
    pub gps: Vec<GpsLogRecord>,
    pub mode_log: String,
    pub err_log: String,
}

/// `name` in `dir`, parsed; empty when the file does not exist.
fn read<T>(
    dir: &Path,
    name: &str,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> anyhow::Result<Vec<T>> {
    let path = dir.join(name);
    let text = match bounded::read_text(&path, FileKind::RunLog) {
        Ok(t) => t,
        Err(e) if e.missing => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let Parsed { rows, .. } =
        logs::parse_log(&text, parse).with_context(|| path.display().to_string())?;
    Ok(rows)
}

fn text(dir: &Path, name: &str) -> anyhow::Result<String> {
    let path = dir.join(name);
    match bounded::read_text(&path, FileKind::RunLog) {
        Ok(t) => Ok(t),
        Err(e) if e.missing => Ok(String::new()),
        Err(e) => Err(e).with_context(|| format!("cannot read {}", path.display())),
    }
}

impl RunLogs {
    /// Reads `dir`; it must hold estimates (x_hat.log).
    pub fn read(dir: &Path) -> anyhow::Result<RunLogs> {
        let x_hat = read(dir, "x_hat.log", logs::parse_x_hat)?;
        if x_hat.is_empty() {
            bail!(
                "{}: no estimates (x_hat.log missing or empty)",
                dir.display()
            );
        }
        Ok(RunLogs {
            dir: dir.to_path_buf(),
            imu_raw: read(dir, "imu_raw.log", ImuRawRecord::parse_fields)?,
            kalman_in: read(dir, "kalman_in.log", KalmanInRecord::parse_fields)?,
            x_hat,
            innov: read(dir, "innov.log", InnovRecord::parse_fields)?,
            w: read(dir, "w.log", logs::parse_time_and_4)?,
            setpoint: read(dir, "setpoint.log", logs::parse_time_and::<6>)?,
            gps: read(dir, "gps.log", GpsLogRecord::parse_fields)?,
            mode_log: text(dir, "mode.log")?,
            err_log: text(dir, "err.log")?,
        })
    }

    /// The time of each estimate, µs: kalman_in's, continued 10 ms apart past its last row
    /// (the original's x_hat.log has one row more than its kalman_in.log).
    pub fn estimate_times_us(&self) -> Vec<i64> {
        let times: Vec<i64> = self.kalman_in.iter().map(|k| k.t_us).collect();
        (0..self.x_hat.len())
            .map(|k| match (times.get(k), times.last()) {
                (Some(&t), _) => t,
                (None, Some(&last)) => {
                    last.saturating_add(((k + 1 - times.len()) as i64).saturating_mul(10_000))
                }
                (None, None) => (k as i64).saturating_mul(10_000),
            })
            .collect()
    }
}
