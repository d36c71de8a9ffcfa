//! `uquad replay`: runs the core on a run folder as the original wrote it.
//!
//! Inputs: `imu_raw.log` (the raw frames: 512 calibration frames, then one per control step)
//! and, when present, the time columns of `kalman_in.log`, which are the recorded clock of that
//! run (spec ERRATA 3, 4). Output: `OUT_DIR/kalman_in.log` in the original's format.
//! Replay is deterministic: the same inputs give byte-identical outputs.

use crate::config::Profile;
use crate::core::imu::calib::unwrap_theta;
use crate::core::imu::startup::{FrontEndEvent, ImuFrontEnd};
use crate::logs::{self, ImuRawRecord, KalmanInRecord, Parsed};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// What a replay produced.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySummary {
    /// Raw frames read.
    pub raw_frames: usize,
    /// Rows written to kalman_in.log (the null sample + one per Kalman step).
    pub kalman_rows: usize,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

/// Reads an optional log of a run folder; `Ok(None)` when the file does not exist.
fn read_log<T>(
    dir: &Path,
    name: &str,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> anyhow::Result<Option<Vec<T>>> {
    let path = dir.join(name);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let Parsed { rows, truncated } =
        logs::parse_log(&text, parse).with_context(|| format!("{}", path.display()))?;
    if let Some(t) = truncated {
        tracing::warn!(file = %path.display(), "dropped a cut-off last record: {t}");
    }
    Ok(Some(rows))
}

/// Replays `run_dir` with `profile`, writing the logs into `out_dir` (created if missing).
pub fn run(run_dir: &Path, profile: &Profile, out_dir: &Path) -> anyhow::Result<ReplaySummary> {
    let raw = read_log(run_dir, "imu_raw.log", ImuRawRecord::parse_fields)?
        .with_context(|| format!("{} has no imu_raw.log", run_dir.display()))?;
    // The recorded clock: kalman_in's time and dt columns.
    let recorded_times: Vec<(i64, i64)> =
        read_log(run_dir, "kalman_in.log", logs::parse_time_column_pair)?.unwrap_or_default();

    let cfg = &profile.config;
    // The original's imu_raw.log holds no settling frames (spec 1.6): start with calibration.
    let mut front = ImuFrontEnd::new(cfg.imu.startup_params(), profile.calib.clone(), true);
    let mut kalman_in = String::new();
    let mut rows = 0usize;
    let mut prev_frame_us: Option<i64> = None;
    let mut theta_ref: Option<f64> = None;
    for rec in &raw {
        let event = front.on_frame(&rec.frame, rec.t_frame_us);
        let (sample, is_null) = match event {
            FrontEndEvent::Settling { .. } | FrontEndEvent::Calibrating { .. } => continue,
            FrontEndEvent::Failed(e) => bail!("start-up failed: {e}"),
            FrontEndEvent::Calibrated(null) => (null.sample, true),
            FrontEndEvent::Sample(s) => (s, false),
        };
        let mut sample = sample;
        // θ unwrapping (spec 3.8) against the previous θ until the estimator supplies θ̂.
        if let Some(r) = theta_ref {
            sample.euler_rad[2] = unwrap_theta(sample.euler_rad[2], r);
        }
        theta_ref = Some(sample.euler_rad[2]);
        let (t_us, dt_us) = match recorded_times.get(rows) {
            Some(&(t, dt)) => (t, dt),
            None => {
                let dt = match (is_null, prev_frame_us) {
                    (false, Some(p)) => rec.t_frame_us - p,
                    _ => 0,
                };
                (rec.t_main_us, dt)
            }
        };
        prev_frame_us = Some(rec.t_frame_us);
        KalmanInRecord::from_sample(t_us, dt_us, &sample).write(&mut kalman_in);
        rows += 1;
    }
    if rows == 0 {
        bail!(
            "{}: {} frames are not enough to finish the {}-frame calibration",
            run_dir.join("imu_raw.log").display(),
            raw.len(),
            cfg.imu.calib_frames
        );
    }
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let out = out_dir.join("kalman_in.log");
    std::fs::write(&out, kalman_in).with_context(|| format!("cannot write {}", out.display()))?;
    Ok(ReplaySummary {
        raw_frames: raw.len(),
        kalman_rows: rows,
        outputs: vec![out],
    })
}
