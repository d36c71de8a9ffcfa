//! `uquad replay`: runs the core on a run folder as the original wrote it.
//!
//! Inputs: `imu_raw.log` (the raw frames: the calibration frames, then one per control step)
//! and, when present, the recorded clock of that run: the time columns of `kalman_in.log`
//! (Kalman step times, ERRATA 3), `gps.log` (GPS sample times or gpsd fixes, ERRATA 5) and
//! `w.log` (motor commands: the filter input u, ERRATA 6, and the fake-GPS clock, ERRATA 10).
//! Outputs in OUT_DIR: `kalman_in.log` and `x_hat.log` in the original's formats.
//! Replay is deterministic: the same inputs give byte-identical outputs.

use crate::config::{GpsMode, Profile};
use crate::core::ekf::{Ekf, StepInput};
use crate::core::gps::{
    FakeGpsClock, FakePositions, GpsSample, LocalFrame, RecordedGps, SplitMix64,
};
use crate::core::imu::startup::{FrontEndEvent, ImuFrontEnd};
use crate::core::model::MotorLimits;
use crate::core::motor::flight_ramp_offset_rad_s;
use crate::logs::{self, GpsLogRecord, ImuRawRecord, KalmanInRecord, Parsed};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// The first Kalman step has no previous step time: it uses the nominal period (ERRATA 3).
const FIRST_STEP_DT_US: i64 = 10_000;

/// What a replay produced.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReplaySummary {
    /// Raw frames read.
    pub raw_frames: usize,
    /// Kalman steps run (= rows of kalman_in.log and x_hat.log).
    pub kalman_steps: usize,
    /// Steps that fused a GPS sample.
    pub gps_updates: usize,
    /// Steps whose dt was outside the accepted interval and clamped.
    pub dt_clamped: usize,
    /// Steps whose measurement update was refused (prediction only).
    pub ekf_errors: usize,
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

/// Where the filter's GPS samples come from during a replay.
enum GpsSource {
    Off,
    /// Samples stamped in the run's gps.log, fused by the first later Kalman step (ERRATA 5).
    Recorded(RecordedGps),
    /// The fake-GPS rule run on the motor-command clock (ERRATA 10); a sample produced after
    /// command k is fused by Kalman step k + 1.
    Clock {
        clock: FakeGpsClock,
        positions: FakePositions,
        pending: Option<GpsSample>,
    },
}

fn gps_source(profile: &Profile, recorded: Option<Vec<GpsLogRecord>>) -> anyhow::Result<GpsSource> {
    let g = &profile.config.gps;
    let mut positions = match g.mode {
        GpsMode::FakeRandom => FakePositions::Random {
            rng: SplitMix64::new(g.seed),
            span_m: g.fake_span_m,
        },
        _ => FakePositions::Zero,
    };
    Ok(match (g.mode, recorded) {
        (GpsMode::Off, _) => GpsSource::Off,
        (GpsMode::FakeZero | GpsMode::FakeRandom, Some(rows)) => {
            GpsSource::Recorded(RecordedGps::new(
                rows.iter()
                    .map(|r| (r.t_us(), positions.next_sample()))
                    .collect(),
            ))
        }
        (GpsMode::FakeZero | GpsMode::FakeRandom, None) => GpsSource::Clock {
            clock: FakeGpsClock::default(),
            positions,
            pending: None,
        },
        (GpsMode::Gpsd, Some(rows)) => {
            let mut frame = LocalFrame::default();
            let mut samples = Vec::new();
            for r in rows {
                match r {
                    GpsLogRecord::Gpsd {
                        t_us,
                        fix_mode,
                        lat_deg,
                        lon_deg,
                        alt_m,
                    } if fix_mode >= 2 => samples.push((
                        t_us,
                        GpsSample {
                            pos_m: frame.to_local(lat_deg, lon_deg, alt_m),
                        },
                    )),
                    GpsLogRecord::Gpsd { .. } => {}
                    GpsLogRecord::TimeOnly { .. } => bail!(
                        "gps.log holds fake-GPS times, not gpsd fixes: replay it with --set gps.mode=fake-zero"
                    ),
                }
            }
            GpsSource::Recorded(RecordedGps::new(samples))
        }
        (GpsMode::Gpsd, None) => {
            tracing::warn!("gps.mode is gpsd but the run has no gps.log: replaying without GPS");
            GpsSource::Off
        }
    })
}

/// Replays `run_dir` with `profile`, writing the logs into `out_dir` (created if missing).
pub fn run(run_dir: &Path, profile: &Profile, out_dir: &Path) -> anyhow::Result<ReplaySummary> {
    run_observed(run_dir, profile, out_dir, |_| {})
}

/// [`run`], calling `on_step` with the filter after every Kalman step (for checks and tools).
pub fn run_observed(
    run_dir: &Path,
    profile: &Profile,
    out_dir: &Path,
    mut on_step: impl FnMut(&Ekf),
) -> anyhow::Result<ReplaySummary> {
    let raw = read_log(run_dir, "imu_raw.log", ImuRawRecord::parse_fields)?
        .with_context(|| format!("{} has no imu_raw.log", run_dir.display()))?;
    let recorded_times: Vec<(i64, i64)> =
        read_log(run_dir, "kalman_in.log", logs::parse_time_column_pair)?.unwrap_or_default();
    let recorded_w = read_log(run_dir, "w.log", logs::parse_time_and_4)?;
    let recorded_gps = read_log(run_dir, "gps.log", GpsLogRecord::parse_fields)?;

    let cfg = &profile.config;
    let mass_kg = cfg.vehicle.mass_kg;
    let limits = MotorLimits::new(mass_kg, cfg.motor.w_max_rad_s);
    let mut gps = gps_source(profile, recorded_gps)?;
    // The original's imu_raw.log holds no settling frames (spec 1.6): start with calibration.
    let mut front = ImuFrontEnd::new(cfg.imu.startup_params(), profile.calib.clone(), true);
    let mut ekf: Option<Ekf> = None;
    let mut kalman_in = String::new();
    let mut x_hat = String::new();
    let mut summary = ReplaySummary {
        raw_frames: raw.len(),
        ..ReplaySummary::default()
    };
    let mut prev_frame_us: Option<i64> = None;
    let mut prev_step_us: Option<i64> = None;
    for rec in &raw {
        let (mut sample, filter) = match front.on_frame(&rec.frame, rec.t_frame_us) {
            FrontEndEvent::Settling { .. } | FrontEndEvent::Calibrating { .. } => continue,
            FrontEndEvent::Failed(e) => bail!("start-up failed: {e}"),
            FrontEndEvent::Calibrated(null) => (
                null.sample,
                ekf.insert(Ekf::new(cfg.ekf.params(&cfg.imu), &null.sample)),
            ),
            FrontEndEvent::Sample(s) => match ekf.as_mut() {
                Some(f) => (s, f),
                None => continue,
            },
        };
        let row = summary.kalman_steps; // 0-based Kalman step
        let step = row as u32 + 1; // 1-based, as the spec counts
        // The recorded clock when the run has one, else the frames' own times.
        let (t_us, dt_col_us) = match recorded_times.get(row) {
            Some(&(t, dt)) => (t, dt),
            None => (
                rec.t_main_us,
                prev_frame_us.map_or(0, |p| rec.t_frame_us - p),
            ),
        };
        prev_frame_us = Some(rec.t_frame_us);
        let dt_us = prev_step_us.map_or(FIRST_STEP_DT_US, |p| t_us - p);
        prev_step_us = Some(t_us);

        // The filter input u (ERRATA 6): w_hover on step 1; then the previous motor command,
        // with the flight-ramp offset undone while ramping (steps 2–100).
        let u_rad_s = match recorded_w.as_ref().and_then(|w| w.get(row.wrapping_sub(1))) {
            Some(&(_, w_prev)) if step > 1 => {
                let offset = flight_ramp_offset_rad_s(step - 1, &limits);
                w_prev.map(|w| w - offset)
            }
            _ => [limits.w_hover_rad_s; 4],
        };
        let gps_sample = match &mut gps {
            GpsSource::Off => None,
            GpsSource::Recorded(r) => r.take_before(t_us),
            GpsSource::Clock { pending, .. } => pending.take(),
        };
        let (report, result) = filter.step(
            &sample,
            &StepInput {
                u_rad_s,
                mass_kg,
                dt_us,
                gps_m: gps_sample.map(|g| g.pos_m),
            },
        );
        if let Err(e) = result {
            summary.ekf_errors += 1;
            tracing::warn!(step, "{e}");
        }
        summary.gps_updates += usize::from(gps_sample.is_some());
        summary.dt_clamped += usize::from(report.dt_clamped);
        sample.euler_rad[2] = report.theta_unwrapped_rad;
        KalmanInRecord::from_sample(t_us, dt_col_us, &sample).write(&mut kalman_in);
        logs::write_values_row(&mut x_hat, None, filter.x.as_slice());
        on_step(filter);

        // The motor command of this step, then the fake-GPS check (ERRATA 10).
        if let GpsSource::Clock {
            clock,
            positions,
            pending,
        } = &mut gps
        {
            let t_cmd_us = recorded_w
                .as_ref()
                .and_then(|w| w.get(row))
                .map_or(t_us, |&(t, _)| t);
            if clock.on_motor_command(t_cmd_us) {
                *pending = Some(positions.next_sample());
            }
        }
        summary.kalman_steps += 1;
    }
    if summary.kalman_steps == 0 {
        bail!(
            "{}: {} frames are not enough to finish the {}-frame calibration",
            run_dir.join("imu_raw.log").display(),
            raw.len(),
            cfg.imu.calib_frames
        );
    }
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    for (name, text) in [("kalman_in.log", &kalman_in), ("x_hat.log", &x_hat)] {
        let out = out_dir.join(name);
        std::fs::write(&out, text).with_context(|| format!("cannot write {}", out.display()))?;
        summary.outputs.push(out);
    }
    Ok(summary)
}
