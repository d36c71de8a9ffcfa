//! `uquad replay`: runs the core on a run folder as the original wrote it.
//!
//! The whole loop runs closed, as in flight: measurement → EKF → controller → flight ramp and
//! saturation → the motor speeds fed back as the EKF input (ERRATA 6). No recorded motor speed
//! is fed in; only the run's recorded clock is: the time columns of `kalman_in.log` (Kalman
//! step times, ERRATA 3), `int.log` (control step times) and `w.log` (motor command times,
//! ERRATA 8), and `gps.log` (GPS sample times or gpsd fixes, ERRATA 5). Without them the frames'
//! own times stand in.
//!
//! Outputs in OUT_DIR, in the original's formats: `kalman_in.log`, `x_hat.log`, `w.log`,
//! `int.log`. They are built in memory and written once at the end (no sync per record).
//! Replay is deterministic: the same inputs give byte-identical outputs.

use crate::config::{GpsMode, Profile};
use crate::core::ekf::{Ekf, StepInput};
use crate::core::gps::{
    FakeGpsClock, FakePositions, GpsSample, LocalFrame, RecordedGps, SplitMix64,
};
use crate::core::imu::startup::{FrontEndEvent, ImuFrontEnd};
use crate::core::motor::{FLIGHT_RAMP_STEPS, command_for_step};
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
    /// Motor commands with at least one speed saturated at w_min or w_max.
    pub saturated_commands: usize,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

/// The output records, kept in memory during the loop and formatted and written at the end,
/// one file per thread (formatting tens of thousands of numbers is a large share of a replay).
#[derive(Default)]
struct Records {
    kalman_in: Vec<KalmanInRecord>,
    x_hat: Vec<[f64; 15]>,
    w: Vec<(i64, [f64; 4])>,
    /// Time and integrators; only the first `n_int` values are meaningful.
    int: Vec<(i64, [f64; 4])>,
    n_int: usize,
}

impl Records {
    /// Formats and writes the four logs into `out_dir` concurrently.
    fn write(&self, out_dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
        let kalman_in = || {
            let mut s = String::with_capacity(self.kalman_in.len() * 160);
            for r in &self.kalman_in {
                r.write(&mut s);
            }
            s
        };
        let x_hat = || {
            let mut s = String::with_capacity(self.x_hat.len() * 300);
            for r in &self.x_hat {
                logs::write_values_row(&mut s, None, r);
            }
            s
        };
        let w = || {
            let mut s = String::with_capacity(self.w.len() * 100);
            for (t, v) in &self.w {
                logs::write_values_row(&mut s, Some(*t), v);
            }
            s
        };
        let int = || {
            let mut s = String::with_capacity(self.int.len() * 100);
            for (t, v) in &self.int {
                logs::write_values_row(&mut s, Some(*t), &v[..self.n_int]);
            }
            s
        };
        let jobs: [(&str, &(dyn Fn() -> String + Sync)); 4] = [
            ("kalman_in.log", &kalman_in),
            ("x_hat.log", &x_hat),
            ("w.log", &w),
            ("int.log", &int),
        ];
        std::thread::scope(|scope| {
            let handles: Vec<_> = jobs
                .iter()
                .map(|&(name, format)| {
                    scope.spawn(move || {
                        let path = out_dir.join(name);
                        std::fs::write(&path, format())
                            .with_context(|| format!("cannot write {}", path.display()))
                            .map(|()| path)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("a log writer thread panicked")))
                })
                .collect()
        })
    }
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

/// The result of a reader thread; a panic in it becomes an error.
fn joined<T>(r: std::thread::Result<anyhow::Result<T>>) -> anyhow::Result<T> {
    r.unwrap_or_else(|_| Err(anyhow::anyhow!("a log reader thread panicked")))
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
    // The inputs are independent files: read them concurrently.
    let (raw, recorded_times, cmd_times, ctrl_times, recorded_gps) = std::thread::scope(|scope| {
        let time_column = |name: &'static str| {
            scope.spawn(move || -> anyhow::Result<Vec<i64>> {
                Ok(read_log(run_dir, name, logs::parse_time_column)?.unwrap_or_default())
            })
        };
        let kalman = scope.spawn(|| -> anyhow::Result<Vec<(i64, i64)>> {
            Ok(
                read_log(run_dir, "kalman_in.log", logs::parse_time_column_pair)?
                    .unwrap_or_default(),
            )
        });
        let cmd = time_column("w.log");
        let ctrl = time_column("int.log");
        let gps = scope.spawn(|| read_log(run_dir, "gps.log", GpsLogRecord::parse_fields));
        let raw = read_log(run_dir, "imu_raw.log", ImuRawRecord::parse_fields);
        anyhow::Ok((
            raw?,
            joined(kalman.join())?,
            joined(cmd.join())?,
            joined(ctrl.join())?,
            joined(gps.join())?,
        ))
    })?;
    let raw = raw.with_context(|| format!("{} has no imu_raw.log", run_dir.display()))?;

    let cfg = &profile.config;
    let mut gps = gps_source(profile, recorded_gps)?;
    // The original's imu_raw.log holds no settling frames (spec 1.6): start with calibration.
    let mut front = ImuFrontEnd::new(cfg.imu.startup_params(), profile.calib.clone(), true);
    let mut ekf: Option<Ekf> = None;
    let mut controller = profile.controller();
    let mut planner = None;
    let mut out = Records {
        n_int: controller.x_int().len(),
        ..Records::default()
    };
    let mut summary = ReplaySummary {
        raw_frames: raw.len(),
        ..ReplaySummary::default()
    };
    let mut prev_frame_us: Option<i64> = None;
    let mut prev_step_us: Option<i64> = None;
    // What the previous step produced: the raw controller output, the command sent and its time.
    let mut prev: Option<([f64; 4], [f64; 4], i64)> = None;
    for rec in &raw {
        let (mut sample, filter) = match front.on_frame(&rec.frame, rec.t_frame_us) {
            FrontEndEvent::Settling { .. } | FrontEndEvent::Calibrating { .. } => continue,
            FrontEndEvent::Failed(e) => bail!("start-up failed: {e}"),
            FrontEndEvent::Calibrated(null) => {
                planner = Some(profile.planner(null.sample.euler_rad[2]));
                (
                    null.sample,
                    ekf.insert(Ekf::new(cfg.ekf.params(&cfg.imu), &null.sample)),
                )
            }
            FrontEndEvent::Sample(s) => match ekf.as_mut() {
                Some(f) => (s, f),
                None => continue,
            },
        };
        let Some(planner) = planner.as_mut() else {
            continue;
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
        let t_cmd_us = cmd_times.get(row).copied().unwrap_or(t_us);
        let t_ctrl_us = ctrl_times.get(row).copied().unwrap_or(t_cmd_us);

        // The filter input u (ERRATA 6): w_hover on step 1; while ramping the previous raw
        // controller output; once running the previous command actually sent.
        let limits = planner.limits();
        let u_rad_s = match prev {
            None => [limits.w_hover_rad_s; 4],
            Some((w_ctrl, _, _)) if step <= FLIGHT_RAMP_STEPS => w_ctrl,
            Some((_, w_sent, _)) => w_sent,
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
                mass_kg: planner.mass_kg(),
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
        out.kalman_in
            .push(KalmanInRecord::from_sample(t_us, dt_col_us, &sample));
        out.x_hat.push(filter.x.into());
        on_step(filter);

        // Control (spec 4.4): T_s = this control step's time − the previous command's time
        // (ERRATA 8). The first step has no previous command: the original measured from the
        // program's start and kept only the microseconds part.
        planner.update_setpoint();
        let t_s_us = match prev {
            Some((_, _, t_prev_cmd)) => t_ctrl_us - t_prev_cmd,
            None if cfg.control.original_timing => t_ctrl_us.rem_euclid(1_000_000),
            None => FIRST_STEP_DT_US,
        };
        let w_ctrl = controller.step(&filter.x, &planner.sp, t_s_us as f64 / 1e6);
        let mut x_int = [0.0; 4];
        x_int[..out.n_int].copy_from_slice(controller.x_int());
        out.int.push((t_ctrl_us, x_int));
        let w_sent = command_for_step(&w_ctrl, step, &limits);
        summary.saturated_commands += usize::from(
            w_sent
                .iter()
                .any(|&w| w == limits.w_min_rad_s || w == limits.w_max_rad_s),
        );
        out.w.push((t_cmd_us, w_sent));
        prev = Some((w_ctrl, w_sent, t_cmd_us));

        // After the motor command, the fake-GPS check (ERRATA 10).
        if let GpsSource::Clock {
            clock,
            positions,
            pending,
        } = &mut gps
            && clock.on_motor_command(t_cmd_us)
        {
            *pending = Some(positions.next_sample());
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
    summary.outputs = out.write(out_dir)?;
    Ok(summary)
}
