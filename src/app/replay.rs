//! `uquad replay`: runs the core on a run folder as the original wrote it.
//!
//! The flight sequence (`core::flight::sequence`) runs here as in flight, on the run's recorded
//! clock, with no ESCs and no watchdog. The whole loop runs closed, as in flight: measurement
//! → EKF → controller → flight ramp and saturation → the motor speeds fed back as the EKF input (ERRATA 6). No recorded motor speed
//! is fed in; only the run's recorded clock is: the time columns of `kalman_in.log` (Kalman
//! step times, ERRATA 3), `int.log` (control step times) and `w.log` (motor command times,
//! ERRATA 8), and `gps.log` (GPS sample times or gpsd fixes, ERRATA 5). Without them the frames'
//! own times stand in.
//!
//! Outputs in OUT_DIR, in the original's formats: `kalman_in.log`, `x_hat.log`, `w.log`,
//! `int.log`; and uquad's `innov.log` (the innovation test ratios), `setpoint.log` (the set
//! points flown) and `mode.log` (the commander's, from the run's recorded operator inputs —
//! a ground station's missions planned again from their files — and halt). They are built in memory
//! and written once at the end (no sync per record).
//! Replay is deterministic: the same inputs give byte-identical outputs.

use crate::config::{GpsMode, Profile};
use crate::core::ekf::Ekf;
use crate::core::flight::ArmCheck;
use crate::core::flight::{
    ControllerSide, EscState, EstimatorSide, FlightRecord, FrameAction, FrameTimes, GatedCounts,
    GpsFeed, Outputs, RecordedClock,
};
use crate::core::gps::{GpsSample, LocalFrame, RecordedGps};
use crate::core::watchdog::Event;
use crate::logs::{self, GpsLogRecord, ImuRawRecord, InnovRecord, KalmanInRecord, Parsed};
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

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
    /// Steps that left a measurement group out of their update (innovation gate).
    pub ekf_gated: GatedCounts,
    /// Motor commands with at least one speed saturated at w_min or w_max.
    pub saturated_commands: usize,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

/// The output records, kept in memory during the loop and formatted and written at the end,
/// one file per thread (formatting tens of thousands of numbers is a large share of a replay).
struct Records {
    kalman_in: Vec<KalmanInRecord>,
    x_hat: Vec<[f64; 15]>,
    innov: Vec<InnovRecord>,
    w: Vec<(i64, [f64; 4])>,
    /// Time and integrators; only the first `n_int` values are meaningful.
    int: Vec<(i64, [f64; 4])>,
    n_int: usize,
    setpoint: Vec<(i64, [f64; 6])>,
    /// The mode stream, formatted as it goes (a few lines).
    mode: String,
}

impl Outputs for Records {
    /// Keeps the streams a replay writes; the others (imu_raw, gps, err) are the run's.
    fn record(&mut self, r: FlightRecord) {
        match r {
            FlightRecord::KalmanIn {
                t_us,
                dt_us,
                sample,
            } => self
                .kalman_in
                .push(KalmanInRecord::from_sample(t_us, dt_us, &sample)),
            FlightRecord::XHat(x) => self.x_hat.push(x),
            FlightRecord::Innov {
                t_us,
                ratios,
                gated,
            } => self.innov.push(InnovRecord {
                t_us,
                ratios,
                gated,
            }),
            FlightRecord::Command { t_us, w_rad_s } => self.w.push((t_us, w_rad_s)),
            FlightRecord::Setpoint { t_us, sp } => self.setpoint.push((t_us, sp)),
            FlightRecord::Int { t_us, x_int, n_int } => {
                self.n_int = n_int;
                self.int.push((t_us, x_int));
            }
            r @ (FlightRecord::Commander(_) | FlightRecord::Operator { .. }) => {
                logs::Record::Flight(r).write(&mut self.mode)
            }
            FlightRecord::Frame { .. }
            | FlightRecord::FakeGps(_)
            | FlightRecord::GpsFix { .. }
            | FlightRecord::Halt(_)
            | FlightRecord::Note(_) => {}
        }
    }

    fn watchdog(&mut self, _: Event) {}
}

impl Records {
    /// Room for a record per frame in each stream: the vectors never grow (and copy) during
    /// the loop.
    fn with_capacity(frames: usize) -> Self {
        Records {
            kalman_in: Vec::with_capacity(frames),
            x_hat: Vec::with_capacity(frames),
            innov: Vec::with_capacity(frames),
            w: Vec::with_capacity(frames),
            int: Vec::with_capacity(frames),
            n_int: 0,
            setpoint: Vec::with_capacity(frames),
            mode: String::new(),
        }
    }

    /// Formats and writes the logs into `out_dir`, on two threads when `parallel`.
    fn write(&self, out_dir: &Path, parallel: bool) -> anyhow::Result<Vec<PathBuf>> {
        let kalman_in = |path: &Path| write_rows(path, &self.kalman_in, |s, r| r.write(s));
        let x_hat =
            |path: &Path| write_rows(path, &self.x_hat, |s, r| logs::write_values_row(s, None, r));
        let innov = |path: &Path| write_rows(path, &self.innov, |s, r| r.write(s));
        let w = |path: &Path| {
            write_rows(path, &self.w, |s, (t, v)| {
                logs::write_values_row(s, Some(*t), v)
            })
        };
        let int = |path: &Path| {
            write_rows(path, &self.int, |s, (t, v)| {
                logs::write_values_row(s, Some(*t), &v[..self.n_int])
            })
        };
        let setpoint = |path: &Path| {
            write_rows(path, &self.setpoint, |s, (t, v)| {
                logs::write_values_row(s, Some(*t), v)
            })
        };
        let mode = |path: &Path| write_text(path, &self.mode);
        // Two halves of about equal work: one on a second thread (when `parallel`), one here.
        // More threads than cores would only add their start-up.
        let first: [Job; 4] = [
            ("x_hat.log", &x_hat),
            ("w.log", &w),
            ("innov.log", &innov),
            ("mode.log", &mode),
        ];
        let second: [Job; 3] = [
            ("kalman_in.log", &kalman_in),
            ("int.log", &int),
            ("setpoint.log", &setpoint),
        ];
        write_jobs(out_dir, &first, &second, parallel)
    }
}

/// A log file's name and what writes it at a path.
type Job<'a> = (
    &'static str,
    &'a (dyn Fn(&Path) -> std::io::Result<()> + Sync),
);

/// Runs `first` on a second thread (when `parallel`) and `second` here; the paths written,
/// or the first failure naming its file.
fn write_jobs(
    out_dir: &Path,
    first: &[Job],
    second: &[Job],
    parallel: bool,
) -> anyhow::Result<Vec<PathBuf>> {
    let write_all = |jobs: &[Job]| -> anyhow::Result<Vec<PathBuf>> {
        jobs.iter()
            .map(|&(name, write)| {
                let path = out_dir.join(name);
                write(&path)
                    .with_context(|| format!("cannot write {}", path.display()))
                    .map(|()| path)
            })
            .collect()
    };
    let (a, b) = if parallel {
        std::thread::scope(|scope| {
            let helper = scope.spawn(|| write_all(first));
            let b = write_all(second);
            let a = helper
                .join()
                .unwrap_or_else(|_| Err(anyhow::anyhow!("a log writer thread panicked")));
            (a, b)
        })
    } else {
        (write_all(first), write_all(second))
    };
    let mut paths = a?;
    paths.extend(b?);
    Ok(paths)
}

/// Formats `rows` into the file at `path` through one small buffer, written out whenever it
/// fills: the memory a log's text would take is never touched (fresh pages cost a fault each),
/// and the buffer stays in the cache.
fn write_rows<T>(path: &Path, rows: &[T], format: impl Fn(&mut String, &T)) -> std::io::Result<()> {
    use std::io::Write as _;
    const FLUSH_AT: usize = 60 * 1024;
    let mut file = open_for_overwrite(path)?;
    // Room for one more row past the flush mark (a row is well under 4 KiB).
    let mut text = String::with_capacity(FLUSH_AT + 4096);
    let mut len = 0u64;
    for row in rows {
        format(&mut text, row);
        if text.len() >= FLUSH_AT {
            file.write_all(text.as_bytes())?;
            len += text.len() as u64;
            text.clear();
        }
    }
    file.write_all(text.as_bytes())?;
    file.set_len(len + text.len() as u64)
}

/// Writes `text` as the whole file at `path` (see [`open_for_overwrite`]).
fn write_text(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write as _;
    let mut file = open_for_overwrite(path)?;
    file.write_all(text.as_bytes())?;
    file.set_len(text.len() as u64)
}

/// Opens `path` for writing from its start without truncating it first: a replay usually
/// rewrites a log of the same size, and truncating frees the file's blocks only for the writes
/// to allocate them again (a third of a batch's time into an existing folder). The caller
/// cuts the file to what it wrote.
fn open_for_overwrite(path: &Path) -> std::io::Result<std::fs::File> {
    std::fs::File::options()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
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

/// The GPS feed of a replay: the run's gps.log when it has one, else the fake-GPS rule.
fn gps_source(
    profile: &Profile,
    recorded: Option<Vec<GpsLogRecord>>,
    local_positions: bool,
) -> anyhow::Result<GpsFeed> {
    let g = &profile.config.gps;
    let mut positions = profile.fake_positions();
    Ok(match (g.mode, recorded) {
        (GpsMode::Off, _) => GpsFeed::Off,
        (GpsMode::FakeZero | GpsMode::FakeRandom, Some(rows)) => {
            GpsFeed::Recorded(RecordedGps::new(
                rows.iter()
                    .map(|r| (r.t_us(), positions.next_sample()))
                    .collect(),
            ))
        }
        (GpsMode::FakeZero | GpsMode::FakeRandom, None) => GpsFeed::fake(positions),
        (GpsMode::Gpsd, Some(rows)) => {
            let mut frame = LocalFrame::default();
            let mut samples = Vec::new();
            for r in rows {
                match r {
                    GpsLogRecord::Gpsd {
                        t_us,
                        fix_mode,
                        pos_m,
                        vel_m_s,
                        lat_deg,
                        lon_deg,
                        alt_m,
                    } if fix_mode >= 2 => samples.push((
                        t_us,
                        // uquad's own logs hold the local position the filter used (z not a
                        // number for a fix without altitude); the original's hold absolute
                        // UTM, so convert from latitude/longitude.
                        if local_positions {
                            GpsSample {
                                xy_m: [pos_m[0], pos_m[1]],
                                z_m: pos_m[2].is_finite().then_some(pos_m[2]),
                                vel_m_s,
                            }
                        } else {
                            frame.to_local(lat_deg, lon_deg, alt_m.is_finite().then_some(alt_m))
                        },
                    )),
                    GpsLogRecord::Gpsd { .. } => {}
                    GpsLogRecord::TimeOnly { .. } => bail!(
                        "gps.log holds fake-GPS times, not gpsd fixes: replay it with --set gps.mode=fake-zero"
                    ),
                }
            }
            GpsFeed::Recorded(RecordedGps::new(samples))
        }
        (GpsMode::Gpsd, None) => {
            tracing::warn!("gps.mode is gpsd but the run has no gps.log: replaying without GPS");
            GpsFeed::Off
        }
    })
}

/// Whether `out_dir` is `run_dir` itself (through any symlink or `..`): a replay there would
/// overwrite the logs it reads.
pub fn out_is_the_run_folder(run_dir: &Path, out_dir: &Path) -> bool {
    let (Ok(run), Ok(out)) = (run_dir.canonicalize(), out_dir.canonicalize()) else {
        // A folder that does not exist yet is not the run folder, which exists.
        return false;
    };
    run == out
}

/// The profile with the mission the run flew (`mission.toml` in its folder), if it flew one
/// and `profile` has none of its own.
fn with_kept_mission(run_dir: &Path, profile: &Profile) -> anyhow::Result<Option<Profile>> {
    let kept = run_dir.join(crate::app::run_dir::MISSION_FILE);
    if profile.mission.is_some() || !kept.is_file() {
        return Ok(None);
    }
    let p = profile
        .clone()
        .with_mission(&kept)
        .map_err(anyhow::Error::msg)?;
    Ok(Some(p))
}

/// Replays `run_dir` with `profile`, writing the logs into `out_dir` (created if missing).
pub fn run(run_dir: &Path, profile: &Profile, out_dir: &Path) -> anyhow::Result<ReplaySummary> {
    run_observed(run_dir, profile, out_dir, true, |_| {})
}

/// [`run`] on this thread alone: for callers that already keep every core busy (a batch).
pub fn run_on_this_thread(
    run_dir: &Path,
    profile: &Profile,
    out_dir: &Path,
) -> anyhow::Result<ReplaySummary> {
    run_observed(run_dir, profile, out_dir, false, |_| {})
}

/// [`run`], calling `on_step` with the filter after every Kalman step (for checks and tools);
/// reading and writing use a second thread when `parallel`.
pub fn run_observed(
    run_dir: &Path,
    profile: &Profile,
    out_dir: &Path,
    parallel: bool,
    mut on_step: impl FnMut(&Ekf),
) -> anyhow::Result<ReplaySummary> {
    let with_mission = with_kept_mission(run_dir, profile)?;
    let profile = with_mission.as_ref().unwrap_or(profile);
    let (raw, recorded_times, cmd_times, ctrl_times, recorded_gps) =
        read_inputs(run_dir, parallel)?;
    let raw = raw.with_context(|| format!("{} has no imu_raw.log", run_dir.display()))?;

    let cfg = &profile.config;
    let local_positions = std::fs::read_to_string(run_dir.join("gps.log"))
        .is_ok_and(|t| t.starts_with(logs::UQUAD_GPS_HEADER));
    let gps = gps_source(profile, recorded_gps, local_positions)?;
    // The original's imu_raw.log holds no settling frames (spec 1.6): start with calibration.
    let mut estimator = EstimatorSide::new(profile.estimator_core(true), gps, profile.commander())
        .with_clock(RecordedClock {
            kalman_us: recorded_times,
            ctrl_us: ctrl_times,
            cmd_us: cmd_times,
        });
    let mut controller = ControllerSide::new(profile.controller_core());
    let mut feedback = controller.first_feedback();
    let mut out = Records::with_capacity(raw.len());
    let mut summary = ReplaySummary {
        raw_frames: raw.len(),
        ..ReplaySummary::default()
    };
    let (inputs, halt) = recorded_inputs(run_dir, profile)?;
    let mut inputs = inputs.into_iter().peekable();
    for rec in &raw {
        let times = FrameTimes {
            t_main_us: rec.t_main_us,
            t_frame_us: rec.t_frame_us,
        };
        // The operator's inputs, at the frame the run applied them at (earlier ones, before
        // the calibration the log starts with, at the first frame).
        while let Some((t_us, input, verdict)) = inputs.next_if(|i| i.0 <= times.t_frame_us) {
            estimator.operator(input, t_us, ArmCheck::Recorded(&verdict), &mut out);
        }
        let sample = match estimator.on_frame(&rec.frame, times, EscState::ABSENT, &mut out) {
            FrameAction::Step(s) => s,
            FrameAction::Abort(why) => bail!("{why}"),
            FrameAction::Wait | FrameAction::StartEscs | FrameAction::Ended => continue,
        };
        let Some(est) = estimator.estimate(sample, times, &feedback, None, &mut out) else {
            continue;
        };
        if let Some(e) = est.ekf_error {
            tracing::warn!(step = est.step, "{e}");
        }
        if let Some(ekf) = estimator.ekf() {
            on_step(ekf);
        }
        feedback = controller.control(&est, |_| {}, &mut out).feedback;
    }
    // The run's halt, from its record: a replay has no watchdog.
    if let Some((t_us, reason)) = halt {
        estimator.note_halt(t_us, &reason, &mut out);
    }
    let (e, c) = (estimator.counts(), controller.counts());
    summary.kalman_steps = e.steps as usize;
    summary.gps_updates = e.gps_updates as usize;
    summary.dt_clamped = e.dt_clamped as usize;
    summary.ekf_errors = e.ekf_errors as usize;
    summary.ekf_gated = e.gated;
    summary.saturated_commands = c.saturated as usize;
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
    summary.outputs = out.write(out_dir, parallel)?;
    Ok(summary)
}

/// A run folder's logs a replay reads: imu_raw.log (`None` when missing), the recorded step
/// times of kalman_in.log, w.log and int.log, and gps.log's fixes.
type Inputs = (
    Option<Vec<ImuRawRecord>>,
    Vec<(i64, i64)>,
    Vec<i64>,
    Vec<i64>,
    Option<Vec<GpsLogRecord>>,
);

/// Reads the run's logs: imu_raw.log here, the others on a second thread when `parallel`
/// (they are independent files).
fn read_inputs(run_dir: &Path, parallel: bool) -> anyhow::Result<Inputs> {
    let others = || -> anyhow::Result<_> {
        let times = |name| read_log(run_dir, name, logs::parse_time_column);
        Ok((
            read_log(run_dir, "kalman_in.log", logs::parse_time_column_pair)?.unwrap_or_default(),
            times("w.log")?.unwrap_or_default(),
            times("int.log")?.unwrap_or_default(),
            read_log(run_dir, "gps.log", GpsLogRecord::parse_fields)?,
        ))
    };
    let raw_log = || read_log(run_dir, "imu_raw.log", ImuRawRecord::parse_fields);
    let (raw, others) = if parallel {
        std::thread::scope(|scope| {
            let helper = scope.spawn(others);
            let raw = raw_log();
            (raw, joined(helper.join()))
        })
    } else {
        (raw_log(), others())
    };
    let raw = raw?;
    let (kalman, cmd, ctrl, gps) = others?;
    Ok((raw, kalman, cmd, ctrl, gps))
}

/// The operator's inputs of a run (its mode.log) and its halt, if the watchdog halted it;
/// none for runs without a mode.log (the 2012 flights, which started flying).
type Recorded = (Vec<logs::mode_log::RecordedInput>, Option<(i64, String)>);

fn recorded_inputs(run_dir: &Path, profile: &Profile) -> anyhow::Result<Recorded> {
    let path = run_dir.join("mode.log");
    // A ground station's mission is planned again from the file the link wrote.
    let mut mission = |name: &str| {
        // A name the link wrote: a file of the run folder, never a path out of it.
        if name.is_empty() || name.contains('/') || name.starts_with('.') {
            return Err(format!(
                "mission file {name:?}: not a file of the run folder"
            ));
        }
        let file = run_dir.join(name);
        let text = std::fs::read_to_string(&file)
            .map_err(|e| format!("cannot read the mission {}: {e}", file.display()))?;
        profile.plan_mission(&file, &text).map(std::sync::Arc::new)
    };
    match std::fs::read_to_string(&path) {
        Ok(text) => {
            let inputs = logs::mode_log::read_inputs(&text, &mut mission)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            Ok((inputs, logs::mode_log::read_halt(&text)))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok((Vec::new(), None)),
        Err(e) => Err(anyhow::anyhow!("cannot read {}: {e}", path.display())),
    }
}
