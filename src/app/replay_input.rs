//! The run folder's logs a replay reads: imu_raw.log, the recorded clock (the time columns of
//! kalman_in.log, w.log and int.log) and gps.log. Read on whichever thread asks, with no
//! logging there: a cut-off last line is returned, for the caller to report.

use crate::config::bounded::{self, FileKind};
use crate::core::flight::RecordedClock;
use crate::logs::{self, GpsLogRecord, ImuRawRecord, LineError, Parsed};
use anyhow::Context;
use std::path::{Path, PathBuf};

/// What a replay reads from a run folder.
pub struct RunLogs {
    pub raw: Vec<ImuRawRecord>,
    /// The recorded step times; empty where the run has no such log.
    pub clock: RecordedClock,
    /// gps.log's records, if the run has one.
    pub gps: Option<Vec<GpsLogRecord>>,
    /// Whether gps.log is uquad's own (local positions) rather than the original's (UTM).
    pub gps_local: bool,
    /// The logs whose cut-off last line was dropped, with why it did not read.
    pub cut_off: Vec<(PathBuf, LineError)>,
}

impl RunLogs {
    /// Reads `run_dir`'s logs; imu_raw.log must be there.
    pub fn read(run_dir: &Path) -> anyhow::Result<RunLogs> {
        let mut logs = RunLogs::read_imu_side(run_dir)?;
        logs.add(ControlTimes::read(run_dir)?);
        Ok(logs)
    }

    /// imu_raw.log (which must be there), kalman_in.log's times and gps.log: all but the
    /// control side's times ([`ControlTimes`]), which a replay's two threads share out.
    pub fn read_imu_side(run_dir: &Path) -> anyhow::Result<RunLogs> {
        let mut cut_off = Vec::new();
        let raw = read_log(run_dir, "imu_raw.log", usize::MAX, &mut cut_off, |f| {
            ImuRawRecord::parse_fields(f)
        })?
        .with_context(|| format!("{} has no imu_raw.log", run_dir.display()))?;
        // Only the time columns are read: the rest of a line is not looked at.
        let kalman_us = read_log(
            run_dir,
            "kalman_in.log",
            2,
            &mut cut_off,
            logs::parse_time_column_pair,
        )?;
        let gps_text = read_text(run_dir, "gps.log")?;
        let gps_local = gps_text
            .as_ref()
            .is_some_and(|(_, t)| t.starts_with(logs::UQUAD_GPS_HEADER));
        let gps = match gps_text {
            Some((path, text)) => Some(parse_text(&path, &text, usize::MAX, &mut cut_off, |f| {
                GpsLogRecord::parse_fields(f)
            })?),
            None => None,
        };
        Ok(RunLogs {
            raw,
            clock: RecordedClock {
                kalman_us: kalman_us.unwrap_or_default(),
                ctrl_us: Vec::new(),
                cmd_us: Vec::new(),
            },
            gps,
            gps_local,
            cut_off,
        })
    }

    /// The control side's times, read apart.
    pub fn add(&mut self, times: ControlTimes) {
        self.clock.cmd_us = times.cmd_us;
        self.clock.ctrl_us = times.ctrl_us;
        self.cut_off.extend(times.cut_off);
    }

    /// Logs a warning for each cut-off last line that was dropped.
    pub fn report_cut_off(&self) {
        for (path, why) in &self.cut_off {
            tracing::warn!(file = %path.display(), "dropped a cut-off last record: {why}");
        }
    }
}

/// The recorded times of the control side: w.log's (motor commands) and int.log's (control
/// steps); empty where the run has no such log.
pub struct ControlTimes {
    cmd_us: Vec<i64>,
    ctrl_us: Vec<i64>,
    cut_off: Vec<(PathBuf, LineError)>,
}

impl ControlTimes {
    /// Reads them from `run_dir` (only the time column of each line).
    pub fn read(run_dir: &Path) -> anyhow::Result<ControlTimes> {
        let mut cut_off = Vec::new();
        let mut times = |name| read_log(run_dir, name, 1, &mut cut_off, logs::parse_time_column);
        let (cmd_us, ctrl_us) = (times("w.log")?, times("int.log")?);
        Ok(ControlTimes {
            cmd_us: cmd_us.unwrap_or_default(),
            ctrl_us: ctrl_us.unwrap_or_default(),
            cut_off,
        })
    }
}

/// Reads and parses an optional log of `dir` (`Ok(None)` when it does not exist), handing
/// `parse` each line's first `columns` columns; a cut-off last line goes to `cut_off`.
fn read_log<T>(
    dir: &Path,
    name: &str,
    columns: usize,
    cut_off: &mut Vec<(PathBuf, LineError)>,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> anyhow::Result<Option<Vec<T>>> {
    match read_text(dir, name)? {
        Some((path, text)) => parse_text(&path, &text, columns, cut_off, parse).map(Some),
        None => Ok(None),
    }
}

/// A log's path and text; `None` when it does not exist.
fn read_text(dir: &Path, name: &str) -> anyhow::Result<Option<(PathBuf, String)>> {
    let path = dir.join(name);
    match bounded::read_text(&path, FileKind::RunLog) {
        Ok(text) => Ok(Some((path, text))),
        Err(e) if e.missing => Ok(None),
        Err(e) => Err(e).with_context(|| format!("cannot read {}", path.display())),
    }
}

/// Parses a log's `text` (from `path`); see [`read_log`].
fn parse_text<T>(
    path: &Path,
    text: &str,
    columns: usize,
    cut_off: &mut Vec<(PathBuf, LineError)>,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> anyhow::Result<Vec<T>> {
    let Parsed { rows, truncated } = logs::parse_log_columns(text, columns, parse)
        .with_context(|| format!("{}", path.display()))?;
    cut_off.extend(truncated.map(|t| (path.to_path_buf(), t)));
    Ok(rows)
}
