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

use crate::app::replay_input::{ControlTimes, RunLogs};
use crate::app::replay_output::{self, ChunkSink, Records, Texts, ToFormatter};
use crate::config::bounded::{self, FileKind};
use crate::config::{GpsMode, Profile};
use crate::core::ekf::Ekf;
use crate::core::flight::ArmCheck;
use crate::core::flight::drive::{Edges, EscAsk, EscEdges, Flight};
use crate::core::flight::{
    Command, ControllerSide, EscState, Estimate, EstimatorSide, FrameTimes, GatedCounts, GpsFeed,
    Outputs,
};
use crate::core::gps::{GpsSample, LiveFix, LocalFrame, RecordedGps};
use crate::logs::{self, GpsLogRecord};
use anyhow::{Context, bail};
use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::mpsc;

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
    // Missing: the run flew none. Anything else that is not a regular file (a link to
    // nothing, a FIFO) is an error, not "no mission": the replay would differ in silence.
    if profile.mission.is_some() || !bounded::exists(&kept) {
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
    let profile = || Ok(Cow::Borrowed(profile));
    replay(run_dir, out_dir, several_cpus(), profile, |_| {})
}

/// [`run`] with the profile `load` gives, loaded while a second thread (with more than one
/// CPU) reads the run's logs.
pub fn run_loading(
    run_dir: &Path,
    out_dir: &Path,
    load: impl FnOnce() -> anyhow::Result<Profile>,
) -> anyhow::Result<ReplaySummary> {
    replay(
        run_dir,
        out_dir,
        several_cpus(),
        || load().map(Cow::Owned),
        |_| {},
    )
}

/// Whether this process may run on more than one CPU: a second thread is worth it only then
/// (on one CPU the two would take turns, and poll in each other's time).
fn several_cpus() -> bool {
    std::thread::available_parallelism().is_ok_and(|n| n.get() > 1)
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
/// a second thread reads and formats when `parallel`.
pub fn run_observed(
    run_dir: &Path,
    profile: &Profile,
    out_dir: &Path,
    parallel: bool,
    on_step: impl FnMut(&Ekf),
) -> anyhow::Result<ReplaySummary> {
    replay(
        run_dir,
        out_dir,
        parallel,
        || Ok(Cow::Borrowed(profile)),
        on_step,
    )
}

/// The whole replay: the closed loop, then the logs written (only when the loop succeeded).
///
/// With `parallel`, a second thread reads the run's IMU-side logs while this one loads the
/// profile and reads the control side's times (about even shares), then formats the records
/// chunk by chunk while this one runs the loop: the loop is the one part that cannot be
/// shared, and most of the rest fits beside it.
fn replay<'p>(
    run_dir: &Path,
    out_dir: &Path,
    parallel: bool,
    profile: impl FnOnce() -> anyhow::Result<Cow<'p, Profile>>,
    on_step: impl FnMut(&Ekf),
) -> anyhow::Result<ReplaySummary> {
    if parallel {
        return replay_on_two_threads(run_dir, out_dir, profile, on_step);
    }
    let profile = profile()?;
    let logs = RunLogs::read(run_dir)?;
    let mut out = Records::new(Texts::for_frames(logs.raw.len()));
    let summary = closed_loop(run_dir, &profile, logs, &mut out, on_step)?;
    write_logs(summary, &out.finish(), out_dir)
}

/// [`replay`] with a second thread that reads the run's logs and then formats the records.
fn replay_on_two_threads<'p>(
    run_dir: &Path,
    out_dir: &Path,
    profile: impl FnOnce() -> anyhow::Result<Cow<'p, Profile>>,
    on_step: impl FnMut(&Ekf),
) -> anyhow::Result<ReplaySummary> {
    let (logs_tx, logs_rx) = mpsc::sync_channel(1);
    let (full_tx, full_rx) = mpsc::channel();
    let (spare_tx, spare_rx) = mpsc::channel();
    let (texts_tx, texts_rx) = mpsc::sync_channel(1);
    std::thread::scope(|scope| {
        let helper = std::thread::Builder::new().spawn_scoped(scope, move || {
            let logs = RunLogs::read_imu_side(run_dir);
            let frames = logs.as_ref().map_or(0, |l| l.raw.len());
            // Neither send blocks (room for one); the loop may have failed and gone already.
            let _ = logs_tx.send(logs);
            let _ = texts_tx.send(replay_output::format_chunks(full_rx, spare_tx, frames));
        });
        let helper = helper.context("cannot start the replay's reader and formatter thread")?;
        let replayed = (move || -> anyhow::Result<ReplaySummary> {
            let profile = profile()?;
            let control_times = ControlTimes::read(run_dir)?;
            let mut logs = replay_output::next_polling(&logs_rx)
                .unwrap_or_else(|| Err(anyhow::anyhow!("the log reader thread panicked")))?;
            logs.add(control_times);
            let sink = ToFormatter {
                full: full_tx,
                spare: spare_rx,
            };
            let mut out = Records::new(sink);
            let summary = closed_loop(run_dir, &profile, logs, &mut out, on_step)?;
            // Dropping the sink ends the formatter's input; the texts come as soon as they
            // are formatted, and the thread's own end overlaps the writing.
            drop(out.finish());
            let texts = replay_output::next_polling(&texts_rx)
                .ok_or_else(|| anyhow::anyhow!("the log formatter thread panicked"))?;
            write_logs(summary, &texts, out_dir)
        })();
        // Whatever ended the loop dropped the chunks' sender, so the thread is done or ending;
        // joined here, a panic in it is an error, not a panic of the scope.
        helper
            .join()
            .map_err(|_| anyhow::anyhow!("the replay's reader and formatter thread panicked"))?;
        replayed
    })
}

/// Writes the logs into `out_dir` (created if missing); the summary with the files written.
fn write_logs(
    mut summary: ReplaySummary,
    texts: &Texts,
    out_dir: &Path,
) -> anyhow::Result<ReplaySummary> {
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    summary.outputs = texts.write(out_dir)?;
    Ok(summary)
}

/// Runs the flight sequence over the run's frames, its records into `out`.
fn closed_loop(
    run_dir: &Path,
    profile: &Profile,
    logs: RunLogs,
    out: &mut Records<impl ChunkSink>,
    on_step: impl FnMut(&Ekf),
) -> anyhow::Result<ReplaySummary> {
    logs.report_cut_off();
    let with_mission = with_kept_mission(run_dir, profile)?;
    let profile = with_mission.as_ref().unwrap_or(profile);
    let gps = gps_source(profile, logs.gps, logs.gps_local)?;
    // The original's imu_raw.log holds no settling frames (spec 1.6): start with calibration.
    let mut estimator = EstimatorSide::new(profile.estimator_core(true), gps, profile.commander())
        .with_clock(logs.clock);
    if profile.config.calibrates_before_arm() {
        // A refused calibration is taken again as the run did; the ESCs' ramp end is read
        // from mode.log.
        estimator = estimator.calibrating_before_arm().escs_from_records();
    }
    let mut flight = Flight::new(estimator, ControllerSide::new(profile.controller_core()));
    let mut edges = ReplayEdges { on_step };
    let raw = logs.raw;
    let last_frame_us = raw.last().map_or(0, |r| r.t_frame_us);
    let recorded = recorded_inputs(run_dir, profile, last_frame_us)?;
    if let Some(id) = &recorded.run_id {
        out.run_line(id);
    }
    let mut inputs = recorded.inputs.into_iter().peekable();
    for rec in &raw {
        let times = FrameTimes {
            t_main_us: rec.t_main_us,
            t_frame_us: rec.t_frame_us,
        };
        // The operator's inputs, at the frame the run applied them at (earlier ones, before
        // the calibration the log starts with, at the first frame).
        while let Some((t_us, input, verdict)) = inputs.next_if(|i| i.0 <= times.t_frame_us) {
            let check = ArmCheck::Recorded(&verdict);
            flight.operate(input, t_us, check, &mut edges, out);
        }
        out.hand_off_if_full();
        if let Err(why) = flight.frame(&rec.frame, times, &mut edges, out) {
            bail!("{why}");
        }
    }
    // Inputs recorded after the last frame (expired ones, at the run's end), as the run
    // applied them.
    for (t_us, input, verdict) in inputs {
        let check = ArmCheck::Recorded(&verdict);
        flight.operate(input, t_us, check, &mut edges, out);
    }
    // The run's halt, from its record: a replay has no watchdog.
    if let Some((t_us, reason)) = recorded.halt {
        flight.estimator.note_halt(t_us, &reason, out);
    }
    summarize(
        run_dir,
        profile,
        raw.len(),
        &flight.estimator,
        &flight.controller,
    )
}

/// A replay's edges: no ESCs (the records say what they did), no live fixes (the recorded
/// ones are the GPS feed's), and a look at each Kalman step (an EKF error warned, the
/// caller's hook).
struct ReplayEdges<F: FnMut(&Ekf)> {
    on_step: F,
}

impl<F: FnMut(&Ekf)> EscEdges for ReplayEdges<F> {
    fn escs(&mut self, _: EscAsk) {}

    fn quit(&mut self) {}
}

impl<O: Outputs, F: FnMut(&Ekf)> Edges<O> for ReplayEdges<F> {
    fn esc_state(&self) -> EscState {
        EscState::ABSENT
    }

    fn take_fix(&mut self) -> Option<LiveFix> {
        None
    }

    fn estimated(&mut self, est: &Estimate, ekf: Option<&Ekf>, _: &mut O) {
        if let Some(e) = &est.ekf_error {
            tracing::warn!(step = est.step, "{e}");
        }
        if let Some(ekf) = ekf {
            (self.on_step)(ekf);
        }
    }

    fn command(&mut self, _: &Command) {}
}

/// The replay's counts, or why it ran no Kalman step.
fn summarize(
    run_dir: &Path,
    profile: &Profile,
    raw_frames: usize,
    estimator: &EstimatorSide,
    controller: &ControllerSide,
) -> anyhow::Result<ReplaySummary> {
    let (e, c) = (estimator.counts(), controller.counts());
    // Calibrated before arming, a run whose every calibration was refused (taken again at
    // rest) has its refusals to replay, and no step.
    let refused_at_rest = profile.config.calibrates_before_arm()
        && raw_frames >= profile.config.imu.calib_frames as usize;
    if e.steps == 0 && !refused_at_rest {
        bail!(
            "{}: {} frames are not enough to finish the {}-frame calibration",
            run_dir.join("imu_raw.log").display(),
            raw_frames,
            profile.config.imu.calib_frames
        );
    }
    Ok(ReplaySummary {
        raw_frames,
        kalman_steps: e.steps as usize,
        gps_updates: e.gps_updates as usize,
        dt_clamped: e.dt_clamped as usize,
        ekf_errors: e.ekf_errors as usize,
        ekf_gated: e.gated,
        saturated_commands: c.saturated as usize,
        outputs: Vec::new(),
    })
}

/// The run gps.log's header names (`…; run ID`), if it has such a header: its first line,
/// read bounded (the rest is the log reader's).
fn gps_log_run(run_dir: &Path) -> Option<String> {
    use std::io::{BufRead, Read};
    let file = std::fs::File::open(run_dir.join("gps.log")).ok()?;
    let mut first = String::new();
    std::io::BufReader::new(file.take(4096))
        .read_line(&mut first)
        .ok()?;
    let header = first.trim_end_matches(['\n', '\r']);
    header
        .starts_with(logs::UQUAD_GPS_HEADER)
        .then(|| header.rsplit_once("; run ").map(|(_, id)| id.to_string()))
        .flatten()
}

/// What a run's mode.log gives its replay; nothing for runs without one (the 2012 flights,
/// which started flying).
#[derive(Default)]
struct Recorded {
    /// The operator's inputs, checked (see [`logs::mode_log::read_inputs`]).
    inputs: Vec<logs::mode_log::RecordedInput>,
    /// Its halt, if the watchdog halted it.
    halt: Option<(i64, String)>,
    /// The run it names, the same as its config.toml's.
    run_id: Option<String>,
}

fn recorded_inputs(
    run_dir: &Path,
    profile: &Profile,
    last_frame_us: i64,
) -> anyhow::Result<Recorded> {
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
        let text = crate::config::read_mission(&file)?;
        profile.plan_mission(&file, &text).map(std::sync::Arc::new)
    };
    let folder_id = crate::app::run_dir::run_id_of(run_dir)?;
    let text = match bounded::read_text(&path, FileKind::RunLog) {
        Ok(text) => text,
        Err(e) if e.missing && folder_id.is_none() => return Ok(Recorded::default()),
        Err(e) => bail!("cannot read {}: {e}", path.display()),
    };
    let run_id = logs::mode_log::read_run(&text).map(str::to_string);
    if let Some(gps_id) = gps_log_run(run_dir)
        && Some(&gps_id) != folder_id.as_ref()
    {
        bail!(
            "{}: names run {gps_id}, but the run folder's config.toml does not: the gps.log of another run",
            run_dir.join("gps.log").display()
        );
    }
    if run_id != folder_id {
        let name = |id: &Option<String>| id.as_deref().unwrap_or("no run").to_string();
        bail!(
            "{}: names {}, but the run folder's config.toml names {}: the mode.log of another run",
            path.display(),
            name(&run_id),
            name(&folder_id)
        );
    }
    let inputs = logs::mode_log::read_inputs(&text, last_frame_us, &mut mission)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(Recorded {
        inputs,
        halt: logs::mode_log::read_halt(&text),
        run_id,
    })
}
