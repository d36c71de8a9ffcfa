//! `uquad sim --fast`: the flight loop's pure state machines — front end and EKF, controller,
//! ESC driver, watchdog policy — driven in lock-step with the physics on a simulated clock, so
//! a minute of flight takes a fraction of a second and every run with the same seed is the
//! same. The frames go through the real byte decoder; the ESC writes go through the simulated
//! ESCs; the logs and the run folder are written as `fly` writes them, so `uquad replay` reruns
//! a simulated flight to identical bytes.

use crate::app::fly::{FlySummary, create_run_dir, write_run_config};
use crate::config::{GpsMode, Profile};
use crate::core::esc::{CycleKind, EscDriver, EscPhase};
use crate::core::flight::GpsFeed;
use crate::core::gps::{Fix, GpsSample};
use crate::core::imu::frame::FrameDecoder;
use crate::core::imu::startup::FrontEndEvent;
use crate::core::motor::FLIGHT_RAMP_STEPS;
use crate::core::watchdog::{Trip, Watchdog};
use crate::logs::{ImuRawRecord, KalmanInRecord};
use crate::sim::esc::EscModel;
use crate::tasks::gps_client::LiveFix;
use crate::tasks::logger::{Record, STREAMS};
use crate::tasks::watchdog::Halt;
use anyhow::Context;
use bytes::BytesMut;
use std::path::PathBuf;

/// IMU frame period, µs.
const FRAME_US: i64 = 10_000;

/// A fault injected at a simulated time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The IMU stops sending frames.
    ImuStall,
    /// Every I2C write goes unacknowledged.
    EscNack,
    /// GPS fixes stop.
    GpsLoss,
    /// A logger's writes block for 500 ms.
    LogStall,
    /// Motor m0 loses 30 % of its thrust.
    ThrustLoss,
}

impl Fault {
    pub const NAMES: [(&'static str, Fault); 5] = [
        ("imu-stall", Fault::ImuStall),
        ("esc-nack", Fault::EscNack),
        ("gps-loss", Fault::GpsLoss),
        ("log-stall", Fault::LogStall),
        ("thrust-loss", Fault::ThrustLoss),
    ];

    pub fn name(self) -> &'static str {
        Fault::NAMES
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("?", |(n, _)| n)
    }
}

/// Parses `FAULT@T` (T in simulated seconds), e.g. `imu-stall@30`.
pub fn parse_injection(s: &str) -> Result<(Fault, f64), String> {
    let names = Fault::NAMES.map(|(n, _)| n).join(", ");
    let (name, at) = s
        .split_once('@')
        .ok_or_else(|| format!("{s:?}: expected FAULT@T, e.g. imu-stall@30 (faults: {names})"))?;
    let fault = Fault::NAMES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, f)| *f)
        .ok_or_else(|| format!("{name:?} is not a fault; one of {names}"))?;
    let t: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| format!("{at:?} is not a time in seconds"))?;
    Ok((fault, t))
}

/// A simulated gpsd fix of `pos_m` (local frame) arriving at `t_us`. The simulator has no
/// place on the Earth: latitude and longitude are 0; the run's gps.log carries the local
/// position, which is what a replay fuses.
pub(crate) fn sim_fix(seq: &mut u64, pos_m: [f64; 3], t_us: i64) -> LiveFix {
    *seq += 1;
    LiveFix {
        seq: *seq,
        fix: Fix {
            mode: 3,
            lat_deg: 0.0,
            lon_deg: 0.0,
            alt_m: pos_m[2],
        },
        sample: GpsSample { pos_m },
        stamp_us: t_us,
    }
}

/// Simulated time a stalled logger blocks, µs.
const LOG_STALL_US: i64 = 500_000;

/// How a simulation runs.
#[derive(Debug, Clone, Default)]
pub struct SimOptions {
    /// Faults and when they strike, simulated seconds.
    pub inject: Vec<(Fault, f64)>,
    /// Simulated seconds (default: `sim.duration_s`).
    pub duration_s: Option<f64>,
    /// Seed (default: `sim.seed`).
    pub seed: Option<u64>,
    /// Folder under which the run folder is created (default: `log.dir`).
    pub log_dir: Option<PathBuf>,
    /// Print a progress line on stderr every 5 simulated seconds.
    pub progress: bool,
}

/// The hover quality of a simulated flight: the true state against the set point.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HoverStats {
    pub samples: u64,
    pub alt_rms_m: f64,
    pub roll_rms_rad: f64,
    pub pitch_rms_rad: f64,
    /// Largest |altitude - set point| in the window, m.
    pub alt_max_err_m: f64,
    /// Largest distance from the set point (x, y and z) in the window, m.
    pub pos_max_err_m: f64,
    /// Simulated time the window started, s.
    pub window_start_s: f64,
}

/// Sums of squares behind [`HoverStats`], one sample per IMU period of the window.
#[derive(Debug, Clone, Copy, Default)]
pub struct HoverAcc {
    stats: HoverStats,
    se_z: f64,
    se_roll: f64,
    se_pitch: f64,
}

impl HoverAcc {
    /// Adds a sample of the true state at `t_s`: position minus set point (m), roll and pitch
    /// (rad).
    pub fn add(&mut self, t_s: f64, pos_err_m: [f64; 3], roll_rad: f64, pitch_rad: f64) {
        let alt_err_m = pos_err_m[2];
        if self.stats.samples == 0 {
            self.stats.window_start_s = t_s;
        }
        self.stats.samples += 1;
        self.se_z += alt_err_m * alt_err_m;
        self.se_roll += roll_rad * roll_rad;
        self.se_pitch += pitch_rad * pitch_rad;
        self.stats.alt_max_err_m = self.stats.alt_max_err_m.max(alt_err_m.abs());
        let dist_m = pos_err_m.iter().map(|e| e * e).sum::<f64>().sqrt();
        self.stats.pos_max_err_m = self.stats.pos_max_err_m.max(dist_m);
    }

    pub fn stats(&self) -> HoverStats {
        let mut h = self.stats;
        if h.samples > 0 {
            let n = h.samples as f64;
            h.alt_rms_m = (self.se_z / n).sqrt();
            h.roll_rms_rad = (self.se_roll / n).sqrt();
            h.pitch_rms_rad = (self.se_pitch / n).sqrt();
        }
        h
    }
}

#[derive(Debug, Clone)]
pub struct SimSummary {
    pub fly: FlySummary,
    pub hover: HoverStats,
    pub simulated_s: f64,
}

impl SimSummary {
    /// The flight report plus the hover figures.
    pub fn report(&self) -> serde_json::Value {
        let mut r = self.fly.report();
        if let Some(o) = r.as_object_mut() {
            o.insert("alt_rms_m".into(), self.hover.alt_rms_m.into());
            o.insert("roll_rms_rad".into(), self.hover.roll_rms_rad.into());
            o.insert("pitch_rms_rad".into(), self.hover.pitch_rms_rad.into());
            o.insert("alt_max_err_m".into(), self.hover.alt_max_err_m.into());
            o.insert("pos_max_err_m".into(), self.hover.pos_max_err_m.into());
            o.insert(
                "hover_window_start_s".into(),
                self.hover.window_start_s.into(),
            );
            o.insert("hover_samples".into(), self.hover.samples.into());
            o.insert("simulated_s".into(), self.simulated_s.into());
        }
        r
    }

    pub fn text(&self) -> String {
        let h = &self.hover;
        let hover = if h.samples == 0 {
            "no hover window (it starts sim.settle_s after the flight ramp)".to_string()
        } else {
            format!(
                "hover from {:.1} s: altitude RMS {:.3} m (largest error {:.3} m, {:.3} m in 3-D), roll RMS {:.4} rad, pitch RMS {:.4} rad",
                h.window_start_s,
                h.alt_rms_m,
                h.alt_max_err_m,
                h.pos_max_err_m,
                h.roll_rms_rad,
                h.pitch_rms_rad
            )
        };
        format!(
            "{}\n  simulated {:.1} s; {hover}",
            self.fly.text(),
            self.simulated_s
        )
    }
}

/// Records per stream, written at the end as the loggers would.
struct Streams(Vec<String>);

impl Streams {
    fn log(&mut self, r: Record) {
        let i = r.stream();
        r.write(&mut self.0[i]);
    }
}

pub fn run_fast(profile: &Profile, opts: &SimOptions) -> anyhow::Result<SimSummary> {
    let cfg = &profile.config;
    let sc = &cfg.sim;
    let duration_us = (opts.duration_s.unwrap_or(sc.duration_s) * 1e6).round() as i64;
    let seed = opts.seed.unwrap_or(sc.seed);
    let step_us = 1_000_000 / i64::from(sc.physics_hz);
    let parent = opts.log_dir.clone().unwrap_or_else(|| cfg.log.dir.clone());
    let run_dir = create_run_dir(&parent)?;
    let mut profile_run = profile.clone();
    profile_run.config.sim.seed = seed;
    write_run_config(&profile_run, &run_dir)?;

    let (mut plant, mut imu) = crate::sim::vehicle(profile, seed);
    let map = profile.motor_map();
    let mut escs = EscModel::new(map);
    let mut driver = EscDriver::new(
        map,
        i64::from(cfg.esc.resend_ms) * 1000,
        i64::from(cfg.esc.command_timeout_ms) * 1000,
    );
    let mut estimator = profile.estimator_core(false).hold_after_settle();
    let mut control = profile.controller_core();
    let mut gps = match cfg.gps.mode {
        GpsMode::Off => GpsFeed::Off,
        // A simulated gpsd: fixes of the true position at 1 Hz.
        GpsMode::Gpsd => GpsFeed::Live(None),
        GpsMode::FakeZero | GpsMode::FakeRandom => GpsFeed::fake(profile.fake_positions()),
    };
    // Simulated fixes are logged as fly logs gpsd's, so the run replays exactly.
    let mut gps_seq = 0u64;
    let mut offered: Option<LiveFix> = None;
    let mut watchdog = Watchdog::new(cfg.watchdog.params());
    let mut decoder = FrameDecoder::new();
    let mut bytes = BytesMut::with_capacity(64);
    let mut logs = Streams(vec![String::new(); STREAMS.len()]);
    logs.log(Record::Err(format!(
        "uquad {} simulation, seed {seed}, run {}",
        env!("CARGO_PKG_VERSION"),
        run_dir.display()
    )));
    if let GpsFeed::Live(_) = gps {
        logs.log(Record::GpsHeader);
    }

    let mut cycles = Vec::with_capacity(8);
    // Consecutive failed write cycles (the watchdog's missed acks) and when the run began.
    let mut failed_cycles = 0u32;
    let mut first_failure_us = 0i64;
    let mut fly = FlySummary::empty(run_dir.clone());
    let mut last_t_cmd: Option<i64> = None;
    let mut prev_stamp: Option<i64> = None;
    let mut flight_ramp_end_us: Option<i64> = None;
    let mut hover = HoverAcc::default();
    let mut frame_k: u64 = 0;
    let mut position_hold = false;
    let mut halt: Option<(Trip, i64)> = None;
    let mut t: i64 = 0;
    let fault_at = |f: Fault| {
        opts.inject
            .iter()
            .filter(|(g, _)| *g == f)
            .map(|(_, at)| (at * 1e6).round() as i64)
            .min()
    };
    let imu_stall_at = fault_at(Fault::ImuStall);
    let esc_nack_at = fault_at(Fault::EscNack);
    let gps_loss_at = fault_at(Fault::GpsLoss);
    let log_stall_at = fault_at(Fault::LogStall);
    let thrust_loss_at = fault_at(Fault::ThrustLoss);
    // The stalled logger (x_hat) takes nothing for 500 ms; its queue fills, then records drop.
    let x_hat_stream = 2;
    let mut stalled_queue = 0u64;
    for (f, at) in &opts.inject {
        logs.log(Record::Err(format!(
            "fault injection: {} at {at} s",
            f.name()
        )));
    }
    while t < duration_us {
        t += step_us;
        if esc_nack_at.is_some_and(|a| t >= a) {
            escs.failing = true;
        }
        if thrust_loss_at.is_some_and(|a| t >= a) {
            plant.thrust_scale[0] = 0.7;
        }
        if gps_loss_at.is_some_and(|a| t >= a) {
            gps = GpsFeed::Off;
        }
        // The motors follow what the ESCs were last told, then the physics advances.
        plant.w_cmd_rad_s = escs.commands_rad_s(t);
        plant.step(step_us);
        if t % FRAME_US == FRAME_US / 2 {
            imu.first_half(&plant);
        }
        // A GPS fix of the true position each second (gps.mode = "gpsd").
        if t % 1_000_000 == 0
            && let GpsFeed::Live(_) = gps
        {
            let live = sim_fix(&mut gps_seq, plant.position_m(), t);
            gps.offer_live(live.sample);
            offered = Some(live);
        }
        let imu_silent = imu_stall_at.is_some_and(|a| t >= a);
        if t % FRAME_US == 0 && halt.is_none() && !imu_silent {
            let frame = imu.frame(&plant, FRAME_US as u32);
            bytes.extend_from_slice(&frame.encode(if frame_k.is_multiple_of(2) {
                b'C'
            } else {
                b'A'
            }));
            frame_k += 1;
            while let Some(frame) = decoder.next_frame(&mut bytes) {
                fly.frames += 1;
                watchdog.on_frame(t);
                let raw = Record::ImuRaw(ImuRawRecord {
                    t_main_us: t,
                    t_frame_us: t,
                    frame,
                });
                let sample = match estimator.on_frame(&frame, t) {
                    FrontEndEvent::Settling { .. } => continue,
                    FrontEndEvent::Holding => {
                        match driver.phase() {
                            EscPhase::Disabled => {
                                logs.log(Record::Err(
                                    "IMU sampling period stable; ESC start-up ramp".into(),
                                ));
                                driver.start(t);
                            }
                            EscPhase::Running => {
                                logs.log(Record::Err("ESC ramp done; IMU calibration".into()));
                                estimator.begin_calibration();
                            }
                            EscPhase::Ramping | EscPhase::Stopped => {}
                        }
                        continue;
                    }
                    FrontEndEvent::Calibrating { .. } => {
                        logs.log(raw);
                        continue;
                    }
                    FrontEndEvent::Failed(e) => anyhow::bail!("IMU start-up failed: {e}"),
                    FrontEndEvent::Calibrated(null) => {
                        logs.log(raw);
                        logs.log(Record::Err(format!(
                            "IMU calibration completed: acc {:?} m/s2, euler {:?} rad, temp {} C",
                            null.sample.acc_m_s2, null.sample.euler_rad, null.sample.temp_c
                        )));
                        null.sample
                    }
                    FrontEndEvent::Sample(s) => {
                        logs.log(raw);
                        s
                    }
                };
                // The same calls, in the same order, as the estimator and controller tasks.
                let step = estimator.steps() + 1;
                if let Some(t_cmd) = last_t_cmd
                    && gps.after_command(t_cmd)
                {
                    logs.log(Record::Gps(t_cmd));
                }
                let fix = gps.for_step(t);
                if fix.is_some()
                    && let Some(live) = offered.take()
                {
                    // As the estimator task logs it: a time the replay fuses in this same step.
                    logs.log(Record::GpsFix(prev_stamp.unwrap_or(t - 1), live));
                }
                let Some(est) = estimator.step(
                    sample,
                    t,
                    control.input_for_step(step),
                    control.mass_kg(),
                    fix,
                ) else {
                    continue;
                };
                fly.steps += 1;
                fly.gps_updates += u64::from(est.gps_used);
                fly.ekf_errors += u64::from(est.ekf_error.is_some());
                let dt_col = prev_stamp.map_or(0, |p| t - p);
                prev_stamp = Some(t);
                logs.log(Record::KalmanIn(KalmanInRecord::from_sample(
                    est.t_us,
                    dt_col,
                    &est.sample,
                )));
                let stalled = log_stall_at.is_some_and(|a| t >= a && t < a + LOG_STALL_US);
                if stalled {
                    // Queued while the logger is stalled; beyond the queue, dropped and counted.
                    if stalled_queue < u64::from(cfg.log.queue_records) {
                        stalled_queue += 1;
                        logs.log(Record::XHat(est.x.into()));
                    } else {
                        fly.log_drops[x_hat_stream] += 1;
                    }
                } else {
                    logs.log(Record::XHat(est.x.into()));
                }
                if let Some(trip) = watchdog.on_estimate(
                    t,
                    est.sample.temp_c,
                    est.x[crate::core::ekf::idx::PSI],
                    est.x[crate::core::ekf::idx::PHI],
                ) {
                    halt.get_or_insert((trip, t));
                }
                let c = control.control(&est, t, t);
                if c.position_hold != position_hold {
                    position_hold = c.position_hold;
                    logs.log(Record::Err(control.position_hold_message(position_hold)));
                }
                fly.saturated_commands += u64::from(c.saturated);
                logs.log(Record::Int(c.t_ctrl_us, c.x_int, c.n_int));
                logs.log(Record::W(c.t_cmd_us, c.w_sent));
                last_t_cmd = Some(c.t_cmd_us);
                driver.command(&c.w_sent, t, t, &mut cycles);
                if c.step == FLIGHT_RAMP_STEPS {
                    flight_ramp_end_us = Some(t);
                }
            }
        }
        // The ESC driver's due work, executed on the simulated ESCs.
        if let Some((trip, _)) = halt
            && driver.phase() != EscPhase::Stopped
        {
            driver.stop(trip.reason.name(), &mut cycles);
        }
        driver.poll(t, &mut cycles);
        for (kind, cycle) in cycles.drain(..) {
            let mut ok = true;
            for (addr, reg, value) in cycle {
                fly.esc_writes += 1;
                if escs.write(addr, reg, value, t).is_err() {
                    ok = false;
                    fly.esc_failed_writes += 1;
                }
            }
            if ok {
                failed_cycles = 0;
            } else {
                if failed_cycles == 0 {
                    first_failure_us = t;
                }
                failed_cycles += 1;
            }
            match kind {
                CycleKind::Command => {
                    fly.esc_commands += 1;
                    fly.latencies_us.push(0);
                    if let Some(trip) = watchdog.on_command(t, t) {
                        halt.get_or_insert((trip, t));
                    }
                }
                CycleKind::StopDisable => {
                    if let Some((trip, _)) = halt {
                        halt = Some((trip, t));
                    }
                }
                _ => {}
            }
            if failed_cycles > 0
                && let Some(trip) = watchdog.on_esc_failures(failed_cycles, first_failure_us, t)
            {
                halt.get_or_insert((trip, t));
            }
        }
        if let Some(trip) = watchdog.tick(t) {
            halt.get_or_insert((trip, t));
        }
        // A decided halt is executed in the same millisecond: zero, then disable.
        if let Some((trip, _)) = halt
            && driver.phase() != EscPhase::Stopped
        {
            driver.stop(trip.reason.name(), &mut cycles);
            for (kind, cycle) in cycles.drain(..) {
                for (addr, reg, value) in cycle {
                    fly.esc_writes += 1;
                    if escs.write(addr, reg, value, t).is_err() {
                        fly.esc_failed_writes += 1;
                    }
                }
                if kind == CycleKind::StopDisable {
                    halt = Some((trip, t));
                }
            }
        }
        // Hover quality over the window.
        if let Some(end) = flight_ramp_end_us
            && t >= end + (sc.settle_s * 1e6) as i64
            && halt.is_none()
            && t % FRAME_US == 0
        {
            let e = plant.euler_rad();
            let sp_m = control
                .planner()
                .map_or([0.0, 0.0, cfg.control.hover_z_m], |p| {
                    [p.sp.x[0], p.sp.x[1], p.sp.x[2]]
                });
            let pos_m = plant.position_m();
            hover.add(
                t as f64 / 1e6,
                std::array::from_fn(|i| pos_m[i] - sp_m[i]),
                e[0],
                e[1],
            );
        }
        if opts.progress && t % 5_000_000 == 0 {
            eprintln!(
                "sim {:5.1} s  z {:6.3} m  roll {:+.3} pitch {:+.3} rad  ESC {:?}  steps {}",
                t as f64 / 1e6,
                plant.position_m()[2],
                plant.euler_rad()[0],
                plant.euler_rad()[1],
                driver.phase(),
                fly.steps
            );
        }
        if driver.phase() == EscPhase::Stopped && halt.is_some() {
            break;
        }
    }
    // The end of the run: zero and disable, as fly's shutdown does.
    driver.stop("shutdown", &mut cycles);
    for (_, cycle) in cycles.drain(..) {
        for (addr, reg, value) in cycle {
            fly.esc_writes += 1;
            if escs.write(addr, reg, value, t).is_err() {
                fly.esc_failed_writes += 1;
            }
        }
    }
    fly.esc_stop_reason = driver.stop_reason().map(str::to_string);
    fly.deadline_misses = watchdog.deadline_misses();
    fly.halt = halt.map(|(trip, halt_us)| Halt { trip, halt_us });
    if let Some(h) = fly.halt {
        logs.log(Record::Err(format!(
            "watchdog: halt, reason {}; event at {} s, halt at {} s ({:.3} ms later)",
            h.trip.reason.name(),
            crate::logs::fmt_time_us(h.trip.event_us),
            crate::logs::fmt_time_us(h.halt_us),
            h.latency_ms()
        )));
    }
    for (i, name) in STREAMS.iter().enumerate() {
        if fly.log_drops[i] > 0 {
            logs.log(Record::Err(format!(
                "log stream {name}: {} records dropped",
                fly.log_drops[i]
            )));
        }
    }
    logs.log(Record::Err(format!(
        "run ended: {} frames, {} steps, ESCs stopped: {}",
        fly.frames,
        fly.steps,
        fly.esc_stop_reason.as_deref().unwrap_or("never started")
    )));
    for (i, name) in STREAMS.iter().enumerate() {
        let path = run_dir.join(format!("{name}.log"));
        std::fs::write(&path, &logs.0[i])
            .with_context(|| format!("cannot write {}", path.display()))?;
        fly.log_records[i] = logs.0[i].lines().count() as u64;
    }
    fly.discarded_bytes = decoder.stats().discarded_bytes;
    fly.rejected_frames = decoder.stats().rejected_frames;
    Ok(SimSummary {
        fly,
        hover: hover.stats(),
        simulated_s: t as f64 / 1e6,
    })
}
