//! `uquad sim --fast`: the flight sequence (`core::flight::sequence`), the ESC driver and its
//! write loop, and the watchdog policy driven in lock-step with the physics on a simulated
//! clock, so a minute of flight takes a fraction of a second and every run with the same seed
//! is the same. The frames go through the real byte decoder; the ESC writes go through the
//! simulated ESCs; the logs and the run folder are written as `fly` writes them, so
//! `uquad replay` reruns a simulated flight to identical bytes.
//!
//! Each simulated step (`sim.physics_hz`) runs, in this order: faults, physics, the IMU (a
//! frame every 10 ms through the flight sequence), simulated gpsd (a fix each second), the ESC
//! driver's due work, the watchdog's clock, a decided halt (zero, then disable, in the same
//! step), the hover window.

use crate::app::flight::live_sides;
use crate::app::report::{FlySummary, SimSummary};
use crate::app::run_dir::{create_run_dir, new_run_id, write_run_config};
use crate::app::sim::SimOptions;
use crate::config::{GpsMode, Profile};
use crate::core::commander::{ArmFacts, Mode, OperatorInput};
use crate::core::ekf::Ekf;
use crate::core::esc::{CycleKind, CycleRunner, EscDriver, EscPhase, StopReason};
use crate::core::flight::ArmCheck;
use crate::core::flight::drive::{Edges, EscAsk, EscEdges, Flight};
use crate::core::flight::{Command, EscState, Estimate, FlightRecord, FrameTimes, Outputs};
use crate::core::gps::LiveFix;
use crate::core::imu::frame::{FrameDecoder, RawFrame};
use crate::core::motor::FLIGHT_RAMP_STEPS;
use crate::core::status::Live;
use crate::core::watchdog::{Event, Trip, Watchdog};
use crate::logs::{PerStream, Record, Stream};
use crate::sim::esc::EscModel;
use crate::sim::faults::{Fault, FaultSchedule, LOG_STALL_US, WireFaults};
use crate::sim::gps::SimGps;
use crate::sim::hover::{CycleTrace, FlightView, HoverWindow, TrueState, progress_line};
use crate::sim::operator::SimOperator;
use crate::sim::safety::SafetyTrace;
use crate::sim::track::TrackTrace;
use crate::sim::truth::TruthTrace;
use crate::sim::{FRAME_US, frame_start_byte, imu::SimImu, physics::Plant};
use crate::tasks::logger::LogHub;
use crate::tasks::notices::{Notice, Notices};
use crate::tasks::prearm::PreArm;
use bytes::BytesMut;
use std::path::PathBuf;

/// The streams, kept in memory and written at the end as the loggers would write them (or,
/// in a paced run, handed to fly's loggers as the run goes). The x_hat logger can be stalled
/// (`log-stall`): its queue fills, then records drop and count.
pub(crate) struct FastOutputs {
    text: PerStream<String>,
    /// A paced run's loggers, and the link's notices (none in a lock-step run).
    hub: Option<LogHub>,
    notices: Notices,
    records: PerStream<u64>,
    drops: PerStream<u64>,
    /// Watchdog events of the current frame, dispatched by the loop.
    events: Vec<Event>,
    now_us: i64,
    stall_from_us: Option<i64>,
    stalled_queue: u64,
    queue_cap: u64,
}

impl FastOutputs {
    /// Empty streams; the x_hat logger stalls from `stall_from_us` with a queue of
    /// `queue_records`.
    fn new(stall_from_us: Option<i64>, queue_records: u32) -> Self {
        FastOutputs {
            text: PerStream::default(),
            hub: None,
            notices: Notices::default(),
            records: PerStream::default(),
            drops: PerStream::default(),
            events: Vec::with_capacity(8),
            now_us: 0,
            stall_from_us,
            stalled_queue: 0,
            queue_cap: u64::from(queue_records),
        }
    }

    fn log(&mut self, r: Record) {
        let s = r.stream();
        if let Some(hub) = &self.hub {
            hub.log(r);
            self.records[s] += 1;
            return;
        }
        let stalled = s == Stream::XHat
            && self
                .stall_from_us
                .is_some_and(|a| self.now_us >= a && self.now_us < a + LOG_STALL_US);
        if stalled {
            // Queued while the logger is stalled; beyond the queue, dropped and counted.
            if self.stalled_queue >= self.queue_cap {
                self.drops[s] += 1;
                return;
            }
            self.stalled_queue += 1;
        }
        r.write(&mut self.text[s]);
        self.records[s] += 1;
    }
}

impl Outputs for FastOutputs {
    fn record(&mut self, r: FlightRecord) {
        if let FlightRecord::Commander(e) = &r {
            self.notices.send(Notice::Event(e.clone()));
        }
        self.log(Record::Flight(r));
    }

    fn watchdog(&mut self, e: Event) {
        self.events.push(e);
    }
}

/// The vehicle, its edges and the flight, on one simulated clock.
pub(crate) struct FastSim<'a> {
    opts: &'a SimOptions,
    cfg: crate::config::Config,
    faults: FaultSchedule,
    wire: WireFaults,
    step_us: i64,
    gps_live: bool,
    t_us: i64,
    plant: Plant,
    imu: SimImu,
    frames_sent: u64,
    decoder: FrameDecoder,
    bytes: BytesMut,
    gps: SimGps,
    pending_fix: Option<LiveFix>,
    /// Both sides of the flight and the feedback between them (`core::flight::drive`).
    flight: Flight,
    escs: EscModel,
    driver: EscDriver,
    runner: CycleRunner,
    cycles: Vec<(CycleKind, crate::core::esc::Cycle)>,
    watchdog: Watchdog,
    /// The decided halt (its stop is the driver's).
    trip: Option<Trip>,
    out: FastOutputs,
    fly: FlySummary,
    hover: HoverWindow,
    operator: SimOperator,
    /// The pilot's radio (`--rc`), if any, and its kill switch's stops.
    transmitter: Option<crate::sim::transmitter::Transmitter>,
    kills: Vec<crate::app::report::KillFigures>,
    /// The last frame read had the kill switch on.
    kill_on: bool,
    /// The true vertical speed at the previous step, m/s (a kill's fall).
    last_vz_m_s: f64,
    /// The operator's inputs due at this frame.
    inputs: Vec<(i64, OperatorInput)>,
    /// The newest fix simulated gpsd gave (the pre-arm GPS check).
    newest_fix: Option<LiveFix>,
    /// The pre-arm inputs, and where the log folder's probe is published.
    prearm: (PreArm, tokio::sync::watch::Sender<Option<String>>),
    /// The operator quit (the manual quit key): the run ends, as `fly`'s does.
    quit: bool,
    /// The ESCs were started once: a disarmed vehicle has flown.
    armed_once: bool,
    /// The ESC start (its count) whose flight's start-up is over.
    started_up_at: Option<u32>,
    trace: CycleTrace,
    track: TrackTrace,
    safety: SafetyTrace,
    truth: TruthTrace,
    /// truth.log's text.
    truth_text: String,
    /// The newest step as a watcher sees it.
    pub(crate) live: Option<Live>,
    /// A paced run's operators and watchers (`app::sim_paced`); none in a lock-step run.
    pub(crate) served: Option<Served>,
}

pub fn run_fast(profile: &Profile, opts: &SimOptions) -> anyhow::Result<SimSummary> {
    let cfg = &profile.config;
    let duration_us = (crate::app::sim::duration_s(opts, profile) * 1e6).round() as i64;
    let seed = opts.seed.unwrap_or(cfg.sim.seed);
    let run_dir = create_run_dir(&opts.log_dir.clone().unwrap_or_else(|| cfg.log.dir.clone()))?;
    let mut profile_run = profile.clone();
    profile_run.config.sim.seed = seed;
    let run_id = new_run_id(&run_dir);
    write_run_config(&profile_run, &run_dir, &run_id)?;
    let mut sim = FastSim::new(profile, opts, seed, run_dir, run_id, None);
    while sim.t_us < duration_us {
        sim.t_us += sim.step_us;
        if !sim.step() {
            break;
        }
    }
    sim.finish()
}

/// Writes every stream into the run folder, err.log and mode.log first (what a full disk
/// leaves room for is what tells what happened); a failed write is counted in the report's
/// `log_io_errors_by_stream` and, the first, ends the run in error, the report still written.
fn write_streams(fly: &mut FlySummary, text: &PerStream<String>) {
    let first = [Stream::Err, Stream::Mode];
    let rest = Stream::ALL.into_iter().filter(|s| !first.contains(s));
    for s in first.into_iter().chain(rest) {
        let path = fly.run_dir.join(format!("{}.log", s.name()));
        if let Err(e) = std::fs::write(&path, &text[s]) {
            fly.log_io_errors[s] += 1;
            let why = format!("cannot write {}: {e}", path.display());
            tracing::error!("{why}");
            fly.error.get_or_insert(why);
        }
    }
}

/// Writes truth.log, the simulator's own (no flight stream: `replay` neither writes nor reads
/// it); a failed write ends the run in error as a stream's does.
fn write_truth(fly: &mut FlySummary, text: &str) {
    let path = fly.run_dir.join(crate::sim::truth::FILE);
    if let Err(e) = std::fs::write(&path, text) {
        let why = format!("cannot write {}: {e}", path.display());
        tracing::error!("{why}");
        fly.error.get_or_insert(why);
    }
}

/// The pre-arm inputs of a simulation: real time waived.
fn prearm(cfg: &crate::config::Config) -> (PreArm, tokio::sync::watch::Sender<Option<String>>) {
    let (tx, rx) = tokio::sync::watch::channel(None);
    let prearm = PreArm {
        log_problem: rx,
        realtime_waived: true,
        gps_required: cfg.gps.mode == GpsMode::Gpsd,
        gps_max_eph_m: cfg.commander.gps_max_eph_m,
        gps_timeout_us: (cfg.control.gps_hold_timeout_s * 1e6).round() as i64,
        addresses: cfg.esc.addresses,
        verdict: Default::default(),
    };
    (prearm, tx)
}

impl<'a> FastSim<'a> {
    /// The vehicle at rest, its run folder `run_dir` (created, its configuration written);
    /// `links`: a paced run's loggers and the link's notices (none: the streams are kept in
    /// memory and written at the end).
    pub(crate) fn new(
        profile: &Profile,
        opts: &'a SimOptions,
        seed: u64,
        run_dir: PathBuf,
        run_id: String,
        links: Option<(LogHub, Notices)>,
    ) -> Self {
        let cfg = &profile.config;
        let (plant, imu) = crate::sim::vehicle(profile, seed);
        let map = profile.motor_map();
        let (estimator, controller) = live_sides(profile);
        let faults = FaultSchedule::new(&opts.inject);
        let mut out = FastOutputs::new(faults.at_us(Fault::LogStall), cfg.log.queue_records);
        let served = links.is_some();
        if let Some((hub, notices)) = links {
            out.hub = Some(hub);
            out.notices = notices;
        }
        out.log(Record::note(format!(
            "uquad {} simulation, seed {seed}, run {}",
            env!("CARGO_PKG_VERSION"),
            run_dir.display()
        )));
        out.log(Record::RunId(run_id.clone()));
        let gps_live = cfg.gps.mode == GpsMode::Gpsd;
        if gps_live {
            out.log(Record::GpsHeader(run_id));
        }
        for line in faults.notes() {
            out.log(Record::note(line));
        }
        FastSim {
            opts,
            cfg: cfg.clone(),
            wire: WireFaults::new(seed),
            step_us: 1_000_000 / i64::from(cfg.sim.physics_hz),
            gps_live,
            t_us: 0,
            plant,
            imu,
            frames_sent: 0,
            decoder: FrameDecoder::new(),
            bytes: BytesMut::with_capacity(64),
            gps: SimGps::new(&cfg.sim, seed),
            pending_fix: None,
            flight: Flight::new(estimator, controller),
            escs: EscModel::new(map),
            driver: EscDriver::new(map, cfg.esc_timing()),
            runner: CycleRunner::default(),
            cycles: Vec::with_capacity(8),
            watchdog: Watchdog::new(cfg.watchdog.params()),
            trip: None,
            out,
            fly: FlySummary::empty(run_dir),
            hover: HoverWindow::new(cfg.sim.settle_s),
            operator: {
                let script = crate::app::sim::script(opts, profile);
                let operator = SimOperator::new(&script, faults.at_us(Fault::LinkLoss));
                if served {
                    operator.with_links()
                } else {
                    operator
                }
            },
            transmitter: {
                let script = crate::app::sim::script(opts, profile);
                let lost_us = faults.at_us(Fault::RcLoss);
                let timeout_s = cfg.failsafe.rc_timeout_s;
                crate::sim::transmitter::Transmitter::new(&cfg.rc, timeout_s, &script.1, lost_us)
            },
            kills: Vec::new(),
            kill_on: false,
            last_vz_m_s: 0.0,
            inputs: Vec::with_capacity(4),
            newest_fix: None,
            prearm: prearm(cfg),
            quit: false,
            armed_once: false,
            started_up_at: None,
            trace: CycleTrace::default(),
            track: TrackTrace::default(),
            safety: SafetyTrace::default(),
            truth: TruthTrace::default(),
            truth_text: String::new(),
            live: None,
            served: None,
            faults,
        }
    }

    /// One physics step; `false` when the run is over (a halt or an abort, motors stopped).
    pub(crate) fn step(&mut self) -> bool {
        let t = self.t_us;
        self.out.now_us = t;
        // A paced run's links: stamped as they arrive, applied at the next frame (an input
        // that waits past commander.input_expiry_s for one is refused, as in `fly`).
        if let Some(served) = &mut self.served {
            served.take_inputs(t, &mut self.inputs);
        }
        // The pilot's radio: its inputs are applied at the next frame, but its kill switch
        // goes straight to the ESCs' stop, as fly's RC task sends it.
        if let Some(tx) = &mut self.transmitter
            && let Some(kill) = tx.due(t, &mut self.inputs)
        {
            if kill {
                self.driver
                    .stop(StopReason::KillSwitch, t, &mut self.cycles);
            }
            if kill && !self.kill_on {
                self.kills.push(crate::app::report::KillFigures {
                    frame_s: t as f64 / 1e6,
                    confirmed_s: None,
                    height_m: Some(self.plant.position_m()[2]),
                    impact_v_m_s: None,
                });
            }
            self.kill_on = kill;
        }
        self.escs.failing = self.faults.active(Fault::EscNack, t);
        if self.faults.active(Fault::ThrustLoss, t) {
            self.plant.thrust_scale[0] = 0.7;
        }
        self.plant.push_n = crate::sim::gust_n(&self.faults, &self.cfg.sim, t);
        self.imu.gyro_step_rad_s = crate::sim::gyro_step_rad_s(&self.faults, &self.cfg.sim, t);
        // The motors follow what the ESCs were last told, then the physics advances.
        self.plant.w_cmd_rad_s = self.escs.commands_rad_s(t);
        self.plant.step(self.step_us);
        if t % FRAME_US == FRAME_US / 2 {
            self.imu.first_half(&self.plant);
        }
        let seen_m =
            crate::sim::gps_seen_m(&self.faults, &self.cfg.sim, t, self.plant.position_m());
        let fix = self.gps.step(t, seen_m, self.plant.velocity_m_s(), t);
        if self.gps_live && fix.is_some() && !self.faults.active(Fault::GpsLoss, t) {
            self.pending_fix = fix;
            self.newest_fix = fix;
            // The commander hears of it at the next frame, as `fly`'s estimator task does.
            self.inputs.push((t, OperatorInput::GpsFix));
        }
        if self.faults.active(Fault::GpsLoss, t) {
            self.pending_fix = None;
        }
        let imu_silent = self.faults.active(Fault::ImuStall, t);
        if t % FRAME_US == 0 && self.trip.is_none() && self.fly.error.is_none() && !imu_silent {
            self.send_frame();
        }
        self.run_escs();
        self.follow_kill();
        self.decide(|wd, t| wd.tick(t));
        self.execute_halt();
        self.sample_hover();
        if self.opts.progress && t % 5_000_000 == 0 {
            let mode = self.flight.estimator.mode().name();
            let steps = self.flight.estimator.counts().steps;
            eprintln!("{}", progress_line(t, &self.plant, mode, steps));
        }
        // The run ends once the motors' stop has settled (confirmed, or out of retries): after
        // a halt, an error, or a landing once the script is done.
        let landed = self.armed_once
            && self.flight.estimator.mode() == Mode::Disarmed
            && self.operator.done(t);
        let ended = self.trip.is_some() || self.fly.error.is_some() || landed || self.quit;
        !(ended && self.driver.stop_outcome().is_some())
    }

    /// The newest kill switch's stop: when every ESC confirmed it, and how fast the vehicle
    /// reached the ground.
    fn follow_kill(&mut self) {
        let vz_m_s = self.plant.velocity_m_s()[2];
        let on_ground = self.plant.on_ground;
        if let Some(k) = self.kills.last_mut() {
            if k.confirmed_s.is_none()
                && let Some(o) = self.driver.stop_outcome().filter(|o| o.confirmed())
            {
                k.confirmed_s = Some(o.settled_us as f64 / 1e6);
            }
            if k.impact_v_m_s.is_none() && on_ground && k.height_m.is_some_and(|h| h > 0.05) {
                k.impact_v_m_s = Some(self.last_vz_m_s);
            }
        }
        self.last_vz_m_s = vz_m_s;
    }

    /// The operator's inputs due now (the script's, and a paced run's links'), into the
    /// flight sequence before the frame; a ground station's is answered with its outcome.
    fn operate(&mut self) {
        let t = self.t_us;
        self.operator.due(t, &mut self.inputs);
        if self.inputs.is_empty() {
            return;
        }
        for (due_us, input) in std::mem::take(&mut self.inputs) {
            let asked = crate::tasks::estimator::notice_of(&input, None).map(|_| input.clone());
            // Due while no frame came (a garbled IMU): past commander.input_expiry_s, refused.
            let input = self.flight.estimator.commander().aged(input, t - due_us);
            let facts = if input.checked_against_facts() {
                self.arm_facts()
            } else {
                ArmFacts::default()
            };
            let check = ArmCheck::Facts(&facts);
            let mut escs = SimEscs {
                t_us: t,
                driver: &mut self.driver,
                cycles: &mut self.cycles,
                armed_once: &mut self.armed_once,
                quit: &mut self.quit,
            };
            self.flight
                .operate(input, t, check, &mut escs, &mut self.out);
            if let Some(asked) = asked {
                let refused = self.flight.estimator.last_refusal().map(str::to_string);
                if let Some(n) = crate::tasks::estimator::notice_of(&asked, refused) {
                    self.out.notices.send(n);
                }
            }
        }
        self.dispatch_events();
    }

    /// Simulated time now, and one physics step, µs.
    pub(crate) fn clock_us(&self) -> (i64, i64) {
        (self.t_us, self.step_us)
    }

    /// Advances the clock by one physics step and runs it; `false` once the run is over.
    pub(crate) fn advance(&mut self) -> bool {
        self.t_us += self.step_us;
        self.step()
    }

    /// A signal: the motors stopped at once, the run ends (err.log says why).
    pub(crate) fn shut_down(&mut self) {
        self.out.log(Record::note(
            "signal: stopping the motors and ending the run",
        ));
        self.quit = true;
        self.driver
            .stop(StopReason::Shutdown, self.t_us, &mut self.cycles);
        self.execute_cycles();
    }

    /// What an `arm` would be told now by the commander's rules and the pre-arm checks
    /// (nothing recorded): a ground station's pre-arm bit.
    pub(crate) fn prearm_passes(&self) -> bool {
        let facts = self.arm_facts();
        let side = &self.flight.estimator;
        side.commander().may_arm() && side.prearm_verdict(&facts, self.t_us).is_ok()
    }

    /// The vehicle's status as a watcher reads it (a paced run's link and console).
    pub(crate) fn status(
        &self,
        mode: Mode,
        prearm_ok: Option<bool>,
    ) -> crate::core::status::VehicleStatus {
        let live = self.live.map(|mut l| {
            let c = &self.flight.controller;
            l.flying_steps = c.counts().flying_steps;
            l.setpoint_m = c.setpoint_m().unwrap_or(l.setpoint_m);
            l
        });
        crate::core::status::VehicleStatus {
            mode,
            live,
            fix: self.newest_fix,
            gps_used: self.gps_live,
            imu_frames: self.fly.frames,
            escs_answering: self.driver.silent_addresses().is_empty(),
            halt: self.trip.map(|t| t.reason),
            log_problem: self.prearm.1.borrow().clone(),
            control_cpu_ns: None,
            prearm_ok,
            rc: self.transmitter.as_ref().and_then(|t| t.status()),
        }
    }

    /// At the run's end, the operator's inputs that waited past `commander.input_expiry_s`
    /// for a frame (a garbled IMU) are recorded refused, as `fly` records them.
    fn expire_unapplied(&mut self) {
        let t = self.t_us;
        self.operator.due(t, &mut self.inputs);
        for (due_us, input) in std::mem::take(&mut self.inputs) {
            let input = self.flight.estimator.commander().aged(input, t - due_us);
            if matches!(input, OperatorInput::Expired { .. }) {
                let facts = ArmFacts::default();
                self.flight
                    .estimator
                    .operator(input, t, ArmCheck::Facts(&facts), &mut self.out);
            }
        }
    }

    /// The pre-arm facts as the simulator observes them (real time is waived: a simulation).
    fn arm_facts(&self) -> ArmFacts {
        let (prearm, tx) = &self.prearm;
        tx.send_replace(crate::tasks::prearm::log_dir_problem(&self.fly.run_dir));
        prearm.facts(
            self.driver.silent_addresses(),
            self.newest_fix.as_ref(),
            self.t_us,
        )
    }

    /// The IMU's next frame, through the byte decoder, into the flight sequence.
    fn send_frame(&mut self) {
        let frame = self.imu.frame(&self.plant, FRAME_US as u32);
        let start = frame_start_byte(self.frames_sent);
        let bytes = self.wire.bytes(&self.faults, self.t_us, frame, start);
        self.bytes.extend_from_slice(&bytes);
        self.frames_sent += 1;
        while let Some(frame) = self.decoder.next_frame(&mut self.bytes) {
            self.fly.frames += 1;
            let t = self.t_us;
            self.decide(|wd, t| wd.on_event(Event::Frame(t), t));
            self.on_frame(&frame, FrameTimes::at(t));
        }
    }

    /// The flight step (`core::flight::drive`), in lock-step: the operator's inputs due, then
    /// the frame; an abort ends the run, the motors stopped.
    fn on_frame(&mut self, frame: &RawFrame, times: FrameTimes) {
        self.operate();
        let mut edges = SimEdges {
            escs: SimEscs {
                t_us: self.t_us,
                driver: &mut self.driver,
                cycles: &mut self.cycles,
                armed_once: &mut self.armed_once,
                quit: &mut self.quit,
            },
            pending_fix: &mut self.pending_fix,
            judge: Judge {
                watchdog: &mut self.watchdog,
                trip: &mut self.trip,
                safety: &mut self.safety,
            },
            plant: &self.plant,
            truth: &mut self.truth,
            truth_text: &mut self.truth_text,
            receiver_bias_m: self.gps_live.then(|| self.gps.bias_m()),
            live: &mut self.live,
        };
        if let Err(why) = self.flight.frame(frame, times, &mut edges, &mut self.out) {
            self.fly.error = Some(why.to_string());
            self.driver
                .stop(StopReason::Shutdown, self.t_us, &mut self.cycles);
        }
    }

    /// The ESC driver's due work, executed on the simulated ESCs.
    fn run_escs(&mut self) {
        if let Some(trip) = self.trip {
            self.driver
                .stop(StopReason::Halt(trip.reason), self.t_us, &mut self.cycles);
        }
        self.driver.poll(self.t_us, &mut self.cycles);
        self.execute_cycles();
    }

    /// The one ESC write loop, with its results reported as `fly`'s writer reports them.
    fn execute_cycles(&mut self) {
        let t = self.t_us;
        let mut done_cycles = Vec::new();
        let escs = &mut self.escs;
        self.runner.execute(
            &mut self.driver,
            &mut self.cycles,
            |addr, reg, value| escs.write(addr, reg, value, t),
            || t,
            |done, _| done_cycles.push(done),
        );
        for done in done_cycles {
            for e in done.watchdog_events() {
                self.decide(|wd, t| wd.on_event(e, t));
            }
            if done.kind == CycleKind::Command {
                self.fly.esc_commands += 1;
                let e = Event::Command {
                    frame_us: t,
                    written_us: t,
                };
                self.decide(|wd, t| wd.on_event(e, t));
            }
        }
    }

    /// The watchdog events the flight reported during this frame.
    fn dispatch_events(&mut self) {
        let mut judge = Judge {
            watchdog: &mut self.watchdog,
            trip: &mut self.trip,
            safety: &mut self.safety,
        };
        judge.dispatch(&mut self.out.events, &self.plant, self.t_us);
    }

    /// Asks the watchdog policy; a trip is kept (the first one decides).
    fn decide(&mut self, ask: impl FnOnce(&mut Watchdog, i64) -> Option<Trip>) {
        let mut judge = Judge {
            watchdog: &mut self.watchdog,
            trip: &mut self.trip,
            safety: &mut self.safety,
        };
        judge.decide(&self.plant, self.t_us, ask);
    }

    /// A decided halt is executed in the same step: zero, then disable (retried by the driver
    /// until acknowledged); it is recorded once the stop has settled.
    fn execute_halt(&mut self) {
        let Some(trip) = self.trip else {
            return;
        };
        // Between flights the motors are off already: the halt makes that stop final.
        if self.driver.phase() != EscPhase::Stopped || self.driver.restartable() {
            self.driver
                .stop(StopReason::Halt(trip.reason), self.t_us, &mut self.cycles);
            self.execute_cycles();
        }
        if let Some(o) = self.driver.stop_outcome() {
            self.flight.estimator.on_halt(o.halt(trip), &mut self.out);
        }
    }

    fn sample_hover(&mut self) {
        if self.t_us % FRAME_US != 0 {
            return;
        }
        let mode = self.flight.estimator.mode();
        let flight = FlightView {
            ramp_done: self.flight.controller.counts().flying_steps >= u64::from(FLIGHT_RAMP_STEPS),
            setpoint_m: self.flight.controller.setpoint_m().unwrap_or_default(),
            flying: self.trip.is_none() && matches!(mode, Mode::Takeoff | Mode::Hold),
        };
        let truth = TrueState::of(&self.plant);
        self.hover.sample(self.t_us, flight, truth);
        let guidance = self.flight.estimator.commander().guidance();
        self.trace
            .sample(self.t_us, mode, guidance.height_m, &self.plant);
        let est_m = self
            .flight
            .estimator
            .ekf()
            .map_or([f64::NAN; 3], |e| [e.x[0], e.x[1], e.x[2]]);
        self.track.sample(&guidance, self.plant.position_m(), est_m);
        // The start-up (the ESCs' ramp, a calibration after it) is over once the flight's
        // phases begin: under an estimate that ran before arming, steps come earlier. It
        // stays over until the next flight's ESC start (the motors spin down after a
        // disarm).
        let flying_phase = matches!(
            self.flight.estimator.phase(),
            crate::core::flight::Phase::FlightRamp | crate::core::flight::Phase::Flight
        );
        let starts = self.driver.starts();
        if flying_phase {
            self.started_up_at = Some(starts);
        }
        let started_up = self.started_up_at == Some(starts);
        self.safety
            .sample(self.t_us, &mut self.plant, mode, started_up);
    }

    /// The end of the run: zero and disable, as fly's shutdown does; the closing lines; the
    /// streams written into the run folder.
    pub(crate) fn finish(mut self) -> anyhow::Result<SimSummary> {
        self.expire_unapplied();
        self.driver
            .stop(StopReason::Shutdown, self.t_us, &mut self.cycles);
        self.execute_cycles();
        // Its retries, on the simulated clock (the physics no longer matters).
        while self.driver.stop_outcome().is_none() {
            let Some(next_us) = self.driver.next_wake_us() else {
                break;
            };
            self.t_us = next_us.max(self.t_us);
            self.driver.poll(self.t_us, &mut self.cycles);
            self.execute_cycles();
        }
        let est = self.flight.estimator.counts();
        let fly = &mut self.fly;
        fly.steps = est.steps;
        fly.gps_updates = est.gps_updates;
        fly.ekf_errors = est.ekf_errors;
        fly.ekf_gated = est.gated;
        fly.saturated_commands = self.flight.controller.counts().saturated;
        fly.esc_writes = self.runner.writes;
        fly.esc_failed_writes = self.runner.failed_writes;
        fly.esc_stop_reason = self.driver.stop_reason().map(|r| r.name().to_string());
        fly.deadline_misses = self.watchdog.deadline_misses();
        fly.halt = self
            .trip
            .zip(self.driver.stop_outcome())
            .map(|(trip, o)| o.halt(trip));
        fly.log_drops = self.out.drops;
        fly.commander = self.flight.estimator.summary(self.trace.flight_figures());
        if fly.error.is_none() {
            fly.error = self.flight.estimator.start_failure(self.t_us);
        }
        fly.discarded_bytes = self.decoder.stats().discarded_bytes;
        fly.rejected_frames = self.decoder.stats().rejected_frames;
        fly.rc = self
            .transmitter
            .as_ref()
            .map(crate::sim::transmitter::Transmitter::counts);
        for r in fly.closing_records() {
            self.out.log(r);
        }
        match &self.out.hub {
            // A paced run's loggers have written as it went; they end with the run.
            Some(hub) => fly.log_drops = hub.dropped(),
            None => write_streams(fly, &self.out.text),
        }
        write_truth(fly, &self.truth_text);
        fly.log_records = self.out.records;
        let mission = self.flight.estimator.commander().mission_figures();
        let safety = self.safety.finish(&mut self.plant, self.step_us);
        Ok(SimSummary {
            safety: Some(safety),
            fly: self.fly,
            hover: self.hover.stats(),
            track: self.track.stats(mission),
            truth: self.truth.figures(),
            simulated_s: self.t_us as f64 / 1e6,
            esc_end: self.escs.end_state(),
            kill_switch: self.kills,
        })
    }
}

/// The watchdog policy, the halt it decided, and the safety trace that notes the vehicle at
/// the decision.
struct Judge<'b> {
    watchdog: &'b mut Watchdog,
    trip: &'b mut Option<Trip>,
    safety: &'b mut SafetyTrace,
}

impl Judge<'_> {
    /// Asks the watchdog policy at `t_us`; a trip is kept (the first one decides).
    fn decide(
        &mut self,
        plant: &Plant,
        t_us: i64,
        ask: impl FnOnce(&mut Watchdog, i64) -> Option<Trip>,
    ) {
        if let Some(trip) = ask(self.watchdog, t_us) {
            if self.trip.is_none() {
                self.safety.halt(plant);
            }
            self.trip.get_or_insert(trip);
        }
    }

    /// The watchdog events the flight reported, in order.
    fn dispatch(&mut self, events: &mut Vec<Event>, plant: &Plant, t_us: i64) {
        for e in std::mem::take(events) {
            self.decide(plant, t_us, |wd, t| wd.on_event(e, t));
        }
    }
}

/// The simulated ESC driver as the flight's edges: what an input or a frame asks of it.
struct SimEscs<'b> {
    t_us: i64,
    driver: &'b mut EscDriver,
    cycles: &'b mut Vec<(CycleKind, crate::core::esc::Cycle)>,
    armed_once: &'b mut bool,
    quit: &'b mut bool,
}

impl EscEdges for SimEscs<'_> {
    fn escs(&mut self, ask: EscAsk) {
        match ask {
            EscAsk::Start => {
                *self.armed_once = true;
                self.driver.start(self.t_us);
            }
            EscAsk::Stop(reason) => self.driver.stop(reason, self.t_us, self.cycles),
            EscAsk::TestMotor(test) => {
                self.driver.test_motor(test, self.t_us, self.cycles);
            }
        }
    }

    fn quit(&mut self) {
        *self.quit = true;
        self.driver
            .stop(StopReason::Shutdown, self.t_us, self.cycles);
    }
}

/// The simulator's edges for one frame: its ESCs, the fix simulated gpsd gave, its truth
/// (sampled at each estimate) and its watchdog (the estimate's events, before the control).
struct SimEdges<'b> {
    escs: SimEscs<'b>,
    pending_fix: &'b mut Option<LiveFix>,
    judge: Judge<'b>,
    plant: &'b Plant,
    truth: &'b mut TruthTrace,
    truth_text: &'b mut String,
    /// The simulated receiver's bias, north, west, up (with a receiver), m.
    receiver_bias_m: Option<[f64; 3]>,
    /// The newest step as a watcher sees it.
    live: &'b mut Option<Live>,
}

impl EscEdges for SimEdges<'_> {
    fn escs(&mut self, ask: EscAsk) {
        self.escs.escs(ask);
    }

    fn quit(&mut self) {
        self.escs.quit();
    }
}

impl Edges<FastOutputs> for SimEdges<'_> {
    fn esc_state(&self) -> EscState {
        EscState {
            phase: self.escs.driver.phase(),
            stop_reason: self.escs.driver.stop_reason(),
            starts: self.escs.driver.starts(),
        }
    }

    fn take_fix(&mut self) -> Option<LiveFix> {
        self.pending_fix.take()
    }

    fn estimated(&mut self, est: &Estimate, ekf: Option<&Ekf>, out: &mut FastOutputs) {
        let t_us = self.escs.t_us;
        if let Some(ekf) = ekf {
            let row = self
                .truth
                .sample(est, ekf, self.plant, self.receiver_bias_m);
            crate::logs::format::write_values_row(self.truth_text, Some(t_us), &row);
        }
        self.judge.dispatch(&mut out.events, self.plant, t_us);
        let g = est.guidance;
        *self.live = Some(Live {
            step: est.step,
            x: est.x.into(),
            w_rad_s: self.live.map_or([0.0; 4], |l| l.w_rad_s),
            setpoint_m: g.pos_m,
            mode: g.mode,
            height_m: g.height_m,
            flying_steps: 0,
            ratios: est.ratios,
            home_m: g.home_m,
            mission_item: g.mission_item,
        });
    }

    fn command(&mut self, c: &Command) {
        if let Some(l) = self.live.as_mut() {
            l.w_rad_s = c.w_rad_s;
        }
        let t = self.escs.t_us;
        self.escs.driver.command(&c.w_rad_s, t, t, self.escs.cycles);
    }
}

/// The shortest link timeout the configuration allows, s: a slowed run's scaled one is not
/// shorter (the simulated operator beats once a simulated second).
const LINK_TIMEOUT_MIN_S: f64 = 1.5;

/// A paced run's operators and watchers, as the simulator thread sees them.
pub(crate) struct Served {
    pub(crate) operator: tokio::sync::mpsc::Receiver<OperatorInput>,
    pub(crate) status: tokio::sync::watch::Sender<crate::core::status::VehicleStatus>,
    pub(crate) mode: crate::tasks::notices::ModeSource,
    pub(crate) next_prearm_us: i64,
    pub(crate) prearm_ok: Option<bool>,
    /// Simulated seconds per wall second.
    pub(crate) speed: f64,
}

impl Served {
    /// The links' inputs that arrived since the last step, due now. A link timeout is the
    /// ground station's wall-clock one: scaled by the speed (at least the shortest the
    /// configuration allows).
    pub(crate) fn take_inputs(&mut self, t_us: i64, out: &mut Vec<(i64, OperatorInput)>) {
        while let Ok(mut input) = self.operator.try_recv() {
            if let OperatorInput::Param { key, value } = &mut input
                && *key == "failsafe.link_timeout_s"
            {
                *value = (*value * self.speed).max(LINK_TIMEOUT_MIN_S);
            }
            out.push((t_us, input));
        }
    }
}
