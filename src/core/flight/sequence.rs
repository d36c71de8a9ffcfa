//! The flight step, written once: the start-up sequence (settle → ESC start → calibration →
//! flight ramp → flight), the reactions to the ESCs' and the watchdog's states, the GPS feed,
//! and one step (frame → estimate → control → motor command), as a pure state machine: time
//! and data in, actions and records out (spec 8.3 steps 3–11 with ERRATA 3–10; spec 6.4 for
//! the ESC start).
//!
//! It has two sides because `fly` runs the estimator and the controller as separate tasks:
//! [`EstimatorSide`] and [`ControllerSide`]. Every driver (`fly`'s tasks, `sim --fast`,
//! `sim --realtime` through `fly`, `replay`) follows the same order:
//!
//! 1. [`EstimatorSide::on_frame`] with the frame's times and the ESC driver's state →
//!    [`FrameAction`]: wait, start the ESCs, abort, or a Kalman step is due.
//! 2. On a due step: the controller's [`Feedback`] of the previous step (`fly` waits for it)
//!    and the newest live GPS fix, then [`EstimatorSide::estimate`] → [`Estimate`]. The fake-GPS
//!    clock runs on the previous command's time here (ERRATA 10).
//! 3. [`ControllerSide::control`] on the estimate → [`Command`]: the speeds, handed to the ESC
//!    driver before anything is recorded, and the feedback for step 2 of the next frame.
//!
//! A watchdog halt at any point: [`EstimatorSide::on_halt`]; the ESCs are zeroed then disabled
//! and the run ends. Records (what the log streams hold) and watchdog events go to the
//! driver's [`Outputs`].

use super::gps_feed::GpsFeed;
use super::halves::{ControllerCore, Estimate, EstimatorCore, Ground};
use super::imu_watch::ImuWatch;
use crate::core::commander::{
    self, ArmFacts, Commander, EscRequest, KeyOutcome, Mode, Observation, OperatorInput,
};
use crate::core::control::ManualCommand;
use crate::core::ekf::{Ekf, GatedGroups, Input, TestRatios, idx};
use crate::core::esc::{EscPhase, StopReason};
use crate::core::gps::LiveFix;
use crate::core::imu::calib::ImuSample;
use crate::core::imu::frame::RawFrame;
use crate::core::imu::startup::{FrontEndEvent, StartupError};
use crate::core::motor::FLIGHT_RAMP_STEPS;
use crate::core::watchdog::{Event, Halt};
use std::collections::VecDeque;

/// What the flight produces for the log streams; the `logs` module formats it.
#[derive(Debug, Clone, PartialEq)]
pub enum FlightRecord {
    /// A frame the flight consumed (imu_raw), with its times.
    Frame { times: FrameTimes, frame: RawFrame },
    /// The measurement a Kalman step used (kalman_in); `dt_us` is the column the original
    /// printed (0 on the first step).
    KalmanIn {
        t_us: i64,
        dt_us: i64,
        sample: ImuSample,
    },
    /// The state after a Kalman step (x_hat).
    XHat([f64; 15]),
    /// The innovation test ratios of a Kalman step and the groups it left out (innov).
    Innov {
        t_us: i64,
        ratios: TestRatios,
        gated: GatedGroups,
    },
    /// The integrators after a control step (int); the first `n_int` are meaningful.
    Int {
        t_us: i64,
        x_int: [f64; 4],
        n_int: usize,
    },
    /// The motor speeds sent (w).
    Command { t_us: i64, w_rad_s: [f64; 4] },
    /// The set point a control step flew (setpoint): x, y, z (m), ψ, φ, θ (rad).
    Setpoint { t_us: i64, sp: [f64; 6] },
    /// A fake-GPS sample was produced after the command at this time (gps).
    FakeGps(i64),
    /// A live fix fused by the step after `t_us` (gps).
    GpsFix { t_us: i64, fix: LiveFix },
    /// The watchdog halted the motors (err).
    Halt(Halt),
    /// A line for the operator (err).
    Note(String),
    /// A mode change, failsafe or refusal of the commander (mode).
    Commander(commander::Event),
    /// An operator's input as the flight applied it, with the pre-arm verdict an `arm` was
    /// given (mode): what a replay feeds back in.
    Operator {
        t_us: i64,
        input: OperatorInput,
        verdict: Option<Result<(), String>>,
    },
}

/// Where the flight's records and watchdog events go: loggers and the watchdog thread in
/// `fly`, buffers and the policy itself in `sim --fast`, vectors in `replay`.
pub trait Outputs {
    fn record(&mut self, r: FlightRecord);
    fn watchdog(&mut self, e: Event);
}

/// When a frame arrived: the main loop's time and the frame's own stamp, µs since start.
/// Both are the decode stamp in `fly` and `sim`; the original's logs hold two clocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameTimes {
    pub t_main_us: i64,
    pub t_frame_us: i64,
}

impl FrameTimes {
    /// Both clocks at one stamp.
    pub fn at(stamp_us: i64) -> Self {
        FrameTimes {
            t_main_us: stamp_us,
            t_frame_us: stamp_us,
        }
    }
}

/// The ESC driver's state as the estimator side sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EscState {
    pub phase: EscPhase,
    /// Why the ESCs stopped, once they did.
    pub stop_reason: Option<StopReason>,
    /// Start requests the ESC driver has taken: until it took the flight's own, its phase
    /// is the previous flight's.
    pub starts: u32,
}

impl EscState {
    /// A run without ESCs (replay): nothing to wait for.
    pub const ABSENT: EscState = EscState {
        phase: EscPhase::Running,
        stop_reason: None,
        starts: u32::MAX,
    };

    /// The driver has not yet taken the `asked`-th start: what it says is of before it.
    fn before_start(&self, asked: u32) -> bool {
        self.starts < asked
    }
}

/// Where the flight is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Waiting for a stable IMU sampling period; motors off.
    Settle,
    /// The ESCs' enable and start-up ramp.
    EscStart,
    /// Averaging the null sample: with the motors idling (`imu.calibrate = "after-arm"`), or
    /// at rest before arming.
    Calibration,
    /// Calibrated at rest (`imu.calibrate = "before-arm"`): the estimator runs, the motors are
    /// off until an `arm` (then [`Phase::EscStart`] under the running estimate, then
    /// [`Phase::Flight`]).
    Estimating,
    /// The first [`FLIGHT_RAMP_STEPS`] control steps ramp the motors up.
    FlightRamp,
    Flight,
    /// Halted or aborted: nothing more is stepped.
    Ended,
}

/// Why a run cannot go on; the motors must be stopped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Abort {
    #[error("the ESCs stopped during their start-up ramp: {0}")]
    EscStopped(String),
    #[error("IMU start-up failed: {0}")]
    Startup(StartupError),
    #[error("arming refused: {0}")]
    Calibration(String),
}

/// What the driver does after a frame.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameAction {
    /// Nothing more for this frame.
    Wait,
    /// Ask the ESC driver to enable the ESCs and run their start-up ramp.
    StartEscs,
    /// A Kalman step is due on this sample: get the previous step's [`Feedback`], then call
    /// [`EstimatorSide::estimate`].
    Step(ImuSample),
    /// Stop the motors and end the run with this error.
    Abort(Abort),
    /// The run has ended (a halt or an abort): stop feeding frames.
    Ended,
    /// Zero and disable the ESCs: the commander disarmed on the ground (a failsafe during the
    /// start-up or before the takeoff, or no takeoff in time); the run goes on.
    StopEscs,
}

/// What the controller side hands back to the estimator side after each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feedback {
    /// The step this feedback follows (0 before the first).
    pub step: u32,
    /// EKF input for step `step + 1` (ERRATA 6).
    pub u_next: Input,
    pub mass_kg: f64,
    /// Time of the command of `step`, µs since start.
    pub t_cmd_us: Option<i64>,
}

/// A recorded run's clock (replay): Kalman step times and dt columns, control and command
/// times, by 0-based step. Empty: the frames' own times.
#[derive(Debug, Clone, Default)]
pub struct RecordedClock {
    pub kalman_us: Vec<(i64, i64)>,
    pub ctrl_us: Vec<i64>,
    pub cmd_us: Vec<i64>,
}

/// The times of one step, µs since start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct StepTimes {
    t_us: i64,
    dt_col_us: i64,
    t_ctrl_us: i64,
    t_cmd_us: i64,
}

impl RecordedClock {
    fn times(&self, row: usize, frame: FrameTimes, prev_frame_us: Option<i64>) -> StepTimes {
        let (t_us, dt_col_us) = self.kalman_us.get(row).copied().unwrap_or((
            frame.t_main_us,
            prev_frame_us.map_or(0, |p| frame.t_frame_us - p),
        ));
        let t_cmd_us = self.cmd_us.get(row).copied().unwrap_or(t_us);
        let t_ctrl_us = self.ctrl_us.get(row).copied().unwrap_or(t_cmd_us);
        StepTimes {
            t_us,
            dt_col_us,
            t_ctrl_us,
            t_cmd_us,
        }
    }
}

/// Counters of the estimator side.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EstimatorCounts {
    pub frames: u64,
    pub steps: u64,
    pub ekf_errors: u64,
    pub gps_updates: u64,
    pub dt_clamped: u64,
    /// Live fixes older than the GPS timeout when their step came: not fused.
    pub stale_fixes: u64,
    /// Steps that left a measurement group out of their update (outside the innovation gate).
    pub gated: GatedCounts,
}

/// Kalman steps that left a measurement group out of their update, per group.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct GatedCounts {
    pub attitude: u64,
    pub altitude: u64,
    pub gps: u64,
}

impl GatedCounts {
    fn add(&mut self, g: GatedGroups) {
        self.attitude += u64::from(g.attitude);
        self.altitude += u64::from(g.altitude);
        self.gps += u64::from(g.gps);
    }
}

/// The estimator side: start-up sequence, GPS feed, EKF step.
#[derive(Debug, Clone)]
pub struct EstimatorSide {
    core: EstimatorCore,
    gps: GpsFeed,
    clock: RecordedClock,
    phase: Phase,
    esc_start_asked: bool,
    /// The previous step's frame stamp.
    prev_frame_us: Option<i64>,
    /// The live fix offered to the feed and not yet fused.
    offered: Option<LiveFix>,
    counts: EstimatorCounts,
    commander: Commander,
    /// The commander's events not yet recorded.
    events: Vec<commander::Event>,
    /// The newest step as the commander saw it.
    observed: Option<Observation>,
    /// Manual keys for the controller's planner, one per step.
    keys: VecDeque<crate::core::control::ManualCommand>,
    started: bool,
    /// The commander's events so far, for the report: every mode change, failsafe and item
    /// reached; the first [`REFUSALS_MAX`] refusals.
    history: Vec<commander::Event>,
    /// Every refusal counted, and the newest (the report's summary of those not kept).
    refusals: (u64, Option<commander::Event>),
    /// Every re-entry of the current mode counted, and the newest; the mode it was in.
    reentries: (u64, Option<commander::Event>),
    mode_now: Option<Mode>,
    /// Why the last operator input was refused, if it was (a ground station's answer).
    last_refusal: Option<String>,
    /// The commander stopped the ESCs at this frame's tick: the step's command says so.
    stop_pending: bool,
    /// The IMU's arrivals: whether an `arm` may trust its verdict.
    imu: ImuWatch,
    /// An `arm` came (taken, refused or expired).
    arm_asked: bool,
    /// The gyro's loss has been noted.
    gyro_lost_noted: bool,
    /// The IMU calibrates at rest before arming and the estimator runs from then on
    /// (`imu.calibrate = "before-arm"`); an arm then starts the ESCs at once.
    at_rest: bool,
    /// The ESCs' ramp end has been given to the commander ([`OperatorInput::EscsRunning`]).
    escs_running_told: bool,
    /// The ESC starts the driver had taken at the last frame, and the count the flight's own
    /// start makes (one more): until the driver reaches it, its phase is of before.
    esc_starts_seen: u32,
    starts_asked: u32,
    /// Why the last calibration at rest was refused (it is being taken again).
    calibration_refused: Option<String>,
    /// The ESCs' ramp end comes from the run's records (a replay has no ESCs to watch).
    escs_from_records: bool,
    /// The newest fix's test ratio (most steps carry none): the pre-arm check's.
    last_fix_ratio: Option<f64>,
}

/// An `arm`, applied or expired.
fn is_arm(input: &OperatorInput) -> bool {
    match input {
        OperatorInput::Command(commander::Command::Arm, _) => true,
        OperatorInput::Expired { input, .. } => is_arm(input),
        _ => false,
    }
}

/// Refusals (and re-entries of the current mode) a run keeps whole for its report; beyond,
/// they are counted and the newest kept (mode.log has every one). Mode changes, failsafes
/// and halts are never dropped.
pub const REFUSALS_MAX: u64 = 100;

impl EstimatorSide {
    pub fn new(core: EstimatorCore, gps: GpsFeed, commander: Commander) -> Self {
        EstimatorSide {
            core,
            gps,
            clock: RecordedClock::default(),
            phase: Phase::Settle,
            esc_start_asked: false,
            prev_frame_us: None,
            offered: None,
            counts: EstimatorCounts::default(),
            commander,
            events: Vec::with_capacity(4),
            observed: None,
            keys: VecDeque::with_capacity(4),
            started: false,
            history: Vec::with_capacity(32),
            refusals: (0, None),
            reentries: (0, None),
            mode_now: None,
            last_refusal: None,
            stop_pending: false,
            imu: ImuWatch::LENIENT,
            arm_asked: false,
            gyro_lost_noted: false,
            at_rest: false,
            escs_running_told: false,
            esc_starts_seen: 0,
            starts_asked: 0,
            calibration_refused: None,
            escs_from_records: false,
            last_fix_ratio: None,
        }
    }

    /// Calibrates at rest as soon as the IMU has settled and estimates from then on; an `arm`
    /// needs the `estimator` check and starts the ESCs at once (`imu.calibrate =
    /// "before-arm"`; the core must not hold after settling).
    pub fn calibrating_before_arm(mut self) -> Self {
        self.at_rest = true;
        self
    }

    /// A replay of a run calibrated before arming: the ESCs' ramp end is the recorded
    /// `escs running` input, not watched.
    pub fn escs_from_records(mut self) -> Self {
        self.escs_from_records = true;
        self
    }

    /// An `arm` trusts the IMU only with no frame gap over `imu_timeout_us` (the watchdog's)
    /// now or in the last [`STEADY_US`](super::imu_watch::STEADY_US) (a live run; a replay takes the
    /// recorded verdicts).
    pub fn with_imu_timeout(mut self, imu_timeout_us: i64) -> Self {
        self.imu = ImuWatch::new(imu_timeout_us);
        self
    }

    /// Whether the IMU's frames vouch for it at `t_us` (no silence now or just before): an
    /// `arm` now would not be refused as stale.
    pub fn imu_trusted(&self, t_us: i64) -> bool {
        self.imu.stale(t_us).is_none()
    }

    /// Why the flight could not start, judged at the run's end `end_us`: it was asked to fly
    /// (an `arm`, or `commander.start`), never started its ESCs, and the IMU never settled or
    /// is silent (for more than `commander.input_expiry_s`). `None` once the ESCs were asked
    /// to start, or after an abort (its own error).
    pub fn start_failure(&self, end_us: i64) -> Option<String> {
        let params = self.commander.params();
        let asked = self.arm_asked || params.start != commander::Start::Disarmed;
        if self.esc_start_asked || !asked || self.phase == Phase::Ended {
            return None;
        }
        let limit_us = (params.input_expiry_s * 1e6).round() as i64;
        let why = match self.imu.silent_at(end_us, limit_us) {
            Some(silent) => silent,
            None if self.phase == Phase::Settle => format!(
                "the IMU's frames never arrived at a stable period ({} frames)",
                self.counts.frames
            ),
            None => return None,
        };
        Some(format!("the flight could not start: {why}"))
    }

    /// Why the last operator input was refused; `None` when it was taken.
    pub fn last_refusal(&self) -> Option<&str> {
        self.last_refusal.as_deref()
    }

    /// The vehicle's mode.
    pub fn mode(&self) -> Mode {
        self.commander.mode()
    }

    pub fn commander(&self) -> &Commander {
        &self.commander
    }

    /// The commander's events so far.
    pub fn history(&self) -> &[commander::Event] {
        &self.history
    }

    /// The run's commander summary for its report, with each flight's `flights` figures (one
    /// per arming).
    pub fn summary(&self, flights: Vec<commander::Figures>) -> commander::Summary {
        commander::Summary {
            events: self.history.clone(),
            figures: flights.first().copied().unwrap_or_default(),
            flights,
            refusals_total: self.refusals.0,
            refusal_last: self.refusals.1.clone(),
            reentries_total: self.reentries.0,
            reentry_last: self.reentries.1.clone(),
        }
    }

    /// The commander's start, once, before the first frame or input.
    fn start(&mut self, out: &mut impl Outputs) {
        if !self.started {
            self.started = true;
            // At 0 in every mode: a replay starts at the calibration, not at the first frame.
            self.commander.start(0, &mut self.events);
            self.record_events(out);
        }
    }

    /// The commander's events into the mode stream, and a line each into err.log.
    fn record_events(&mut self, out: &mut impl Outputs) {
        let mut events = std::mem::take(&mut self.events);
        for e in events.drain(..) {
            if let Some(kept) = self.kept(&e) {
                self.history.push(kept);
            }
            out.record(FlightRecord::Note(commander_line(&e)));
            out.record(FlightRecord::Commander(e));
        }
        // Its room kept for the next events.
        self.events = events;
    }

    /// `e` for the report's history, or `None` when it is only counted: refusals and
    /// re-entries of the current mode beyond the first [`REFUSALS_MAX`] (the report gives
    /// their count and the newest), and items reached (mode.log has them, the report lists
    /// none). Mode changes and failsafes are always kept.
    fn kept(&mut self, e: &commander::Event) -> Option<commander::Event> {
        let counted = match e {
            commander::Event::Refusal { .. } => &mut self.refusals,
            commander::Event::Mode { mode, .. } if self.mode_now.replace(*mode) == Some(*mode) => {
                &mut self.reentries
            }
            commander::Event::Reached { .. } => return None,
            _ => return Some(e.clone()),
        };
        counted.0 += 1;
        counted.1 = Some(e.clone());
        (counted.0 <= REFUSALS_MAX).then(|| e.clone())
    }

    /// An operator's input at `t_us`. An `arm` is checked against `arm`: the facts the
    /// driver observed (the IMU's settling is this side's own), or a replay's recorded verdict.
    pub fn operator(
        &mut self,
        input: OperatorInput,
        t_us: i64,
        arm: ArmCheck<'_>,
        out: &mut impl Outputs,
    ) -> OperatorAction {
        self.start(out);
        let verdict = self.arm_verdict(&input, arm, t_us);
        self.arm_asked |= is_arm(&input);
        out.record(FlightRecord::Operator {
            t_us,
            input: input.clone(),
            verdict: verdict.clone(),
        });
        let request = match self.apply(input, verdict, t_us, out) {
            Ok(request) => request,
            Err(action) => return action,
        };
        self.last_refusal = self.events.iter().find_map(|e| match e {
            commander::Event::Refusal { why, .. } => Some(why.clone()),
            _ => None,
        });
        self.record_events(out);
        self.act_on(request, t_us, out)
    }

    /// What `input` asks of the commander (and the ESCs); `Err` when it ends the handling
    /// at once (a quit).
    fn apply(
        &mut self,
        input: OperatorInput,
        verdict: Option<Result<(), String>>,
        t_us: i64,
        out: &mut impl Outputs,
    ) -> Result<Option<EscRequest>, OperatorAction> {
        let request = match input {
            OperatorInput::Beat(src) => {
                self.commander.link_beat(src, t_us);
                None
            }
            OperatorInput::Key(ManualCommand::Quit) => {
                if self.commander.quit(t_us, &mut self.events) {
                    out.record(FlightRecord::Note("manual quit: stopping".into()));
                    return Err(OperatorAction::Quit);
                }
                None
            }
            OperatorInput::Key(k) => {
                self.key(k, out);
                None
            }
            OperatorInput::GpsFix => {
                self.commander.gps_fix(t_us);
                None
            }
            OperatorInput::EscsRunning => {
                self.escs_running_told = true;
                self.commander.escs_running();
                None
            }
            OperatorInput::Rc(report) => self.commander.rc_report(report, t_us, &mut self.events),
            OperatorInput::Sticks(sticks) => {
                self.commander.gcs_sticks(sticks, t_us);
                None
            }
            OperatorInput::Param { key, value } => {
                let note = if self.commander.set_param(key, value) {
                    format!("parameter {key} = {value}: in effect from this step")
                } else {
                    format!("parameter {key} = {value}: not a parameter of the flight, ignored")
                };
                out.record(FlightRecord::Note(note));
                None
            }
            // The arm switch turned off on the ground (after a landing's disarm): nothing to do,
            // and no refusal to tell.
            OperatorInput::Command(commander::Command::Disarm, commander::LinkSource::Rc)
                if self.commander.mode() == Mode::Disarmed
                    && !self.commander.motor_test_may_run(t_us) =>
            {
                None
            }
            OperatorInput::Command(cmd, src) => self.command(cmd, src, verdict, t_us, out),
            OperatorInput::Mission(plan) => {
                self.load_mission(plan, t_us, out);
                None
            }
            OperatorInput::Expired { input, .. } => {
                self.commander
                    .refuse_expired(&input, t_us, &mut self.events);
                None
            }
        };
        Ok(request)
    }

    /// An operator's command: its link heard, the commander's verdict, a calibration taken.
    fn command(
        &mut self,
        cmd: commander::Command,
        src: commander::LinkSource,
        verdict: Option<Result<(), String>>,
        t_us: i64,
        out: &mut impl Outputs,
    ) -> Option<EscRequest> {
        // A link that gives a command is an operator link from then on: its silence is a
        // link-loss, whether or not it ever sent a heartbeat.
        self.commander.link_beat(src, t_us);
        let v = verdict.unwrap_or(Ok(()));
        let o = self.observed;
        let request = self
            .commander
            .command(cmd, t_us, v, o.as_ref(), &mut self.events);
        let refused = self
            .events
            .iter()
            .any(|e| matches!(e, commander::Event::Refusal { .. }));
        if cmd == commander::Command::Calibrate && !refused {
            self.calibrate_again(out);
        }
        request
    }

    /// What the ESCs are asked after an input, as the driver's action.
    fn act_on(
        &mut self,
        request: Option<EscRequest>,
        t_us: i64,
        out: &mut impl Outputs,
    ) -> OperatorAction {
        if request == Some(EscRequest::Start) && self.at_rest && !self.esc_start_asked {
            // Under a running estimate the ESCs start with the arm, not at the next settle.
            self.esc_start_asked = true;
            self.starts_asked = self.esc_starts_seen.saturating_add(1);
            self.phase = Phase::EscStart;
            out.record(FlightRecord::Note(
                "armed: ESC start-up ramp under the running estimate".into(),
            ));
            return OperatorAction::StartEscs;
        }
        if request == Some(EscRequest::KillSwitch) {
            // Disarmed as by a disarm's stop; the ESCs' stop is named the kill switch's.
            self.esc_request(Some(EscRequest::Stop), t_us, out);
            return OperatorAction::KillSwitch;
        }
        if let Some(EscRequest::MotorTest(test)) = request {
            out.record(FlightRecord::Note(format!(
                "motor test: m{} alone at I2C {} for {:.1} s",
                test.motor,
                test.value,
                test.duration_us as f64 / 1e6
            )));
            return OperatorAction::TestMotor(test);
        }
        if self.esc_request(request, t_us, out) {
            OperatorAction::StopEscs
        } else {
            OperatorAction::Nothing
        }
    }

    /// A ground station's mission: the commander's, which may refuse it; noted when taken.
    fn load_mission(
        &mut self,
        plan: std::sync::Arc<crate::core::mission::MissionPlan>,
        t_us: i64,
        out: &mut impl Outputs,
    ) {
        let note = format!(
            "mission {} loaded: {} items, gains for {} path kinds",
            plan.name,
            plan.mission.items.len(),
            plan.gains.len()
        );
        let before = self.events.len();
        self.commander.load_mission(plan, t_us, &mut self.events);
        if self.events.len() == before {
            out.record(FlightRecord::Note(note));
        }
    }

    /// An `arm`'s pre-arm verdict or a motor test's checks: the facts' (the IMU's settling is
    /// this side's own), or the one a replay recorded; none for other inputs.
    fn arm_verdict(
        &self,
        input: &OperatorInput,
        arm: ArmCheck<'_>,
        t_us: i64,
    ) -> Option<Result<(), String>> {
        let OperatorInput::Command(cmd, _) = input else {
            return None;
        };
        let test = matches!(cmd, commander::Command::MotorTest { .. });
        if !(test || *cmd == commander::Command::Arm) {
            return None;
        }
        Some(match arm {
            ArmCheck::Recorded(v) => v.clone(),
            ArmCheck::Facts(f) if test => self.motor_test_verdict(f),
            ArmCheck::Facts(f) => self.prearm_verdict(f, t_us),
        })
    }

    /// Whether a motor test may spin a motor now: every ESC answers, and no calibration at
    /// rest is under way or about to begin (a spinning motor would shake it).
    fn motor_test_verdict(&self, facts: &ArmFacts) -> Result<(), String> {
        if self.at_rest && matches!(self.phase, Phase::Settle | Phase::Calibration) {
            return Err(
                "imu: calibrating at rest: a spinning motor would shake it (test once the \
                 estimate runs)"
                    .into(),
            );
        }
        facts.esc_verdict()
    }

    /// The pre-arm checks' verdict at `t_us` on the driver's `facts` and this side's own
    /// (the IMU's settling and its frames, the estimate's health): what an `arm` would be
    /// told now.
    pub fn prearm_verdict(&self, facts: &ArmFacts, t_us: i64) -> Result<(), String> {
        let mut f = facts.clone();
        if self.at_rest {
            f.imu_stable = self.phase != Phase::Settle;
            f.estimator = self.estimator_problem();
        } else {
            f.imu_stable = self.phase == Phase::EscStart;
        }
        match self.imu.stale(t_us) {
            Some(why) if f.imu_stable => Err(why),
            _ => f.verdict(),
        }
    }

    /// A manual key: the commander's (the hold's height, noted here) or the planner's (queued
    /// for the controller, which notes it).
    fn key(&mut self, k: ManualCommand, out: &mut impl Outputs) {
        let note = match self.commander.manual(k) {
            KeyOutcome::Planner => return self.keys.push_back(k),
            KeyOutcome::Moved(h) => format!("manual {k:?}: hold height {h:.2} m"),
            KeyOutcome::OutOfBounds => format!("manual {k:?}: out of bounds"),
            KeyOutcome::Ignored(m) => format!("manual {k:?} ignored in {}", m.name()),
        };
        out.record(FlightRecord::Note(note));
    }

    /// Whether the driver stops the ESCs for the commander's request: a start waits for the
    /// next settled frame; a kill is the watchdog's halt.
    fn esc_request(
        &mut self,
        request: Option<EscRequest>,
        t_us: i64,
        out: &mut impl Outputs,
    ) -> bool {
        match request {
            Some(EscRequest::Stop) => {
                out.watchdog(Event::Disarming(t_us));
                self.between_flights();
                true
            }
            Some(EscRequest::Kill) => {
                out.watchdog(Event::Kill(t_us));
                false
            }
            Some(EscRequest::Crash) => {
                out.watchdog(Event::Crash(t_us));
                false
            }
            // A motor test's motor stopped: no flight ends.
            Some(EscRequest::EndMotorTest) => true,
            Some(EscRequest::Start | EscRequest::MotorTest(_) | EscRequest::KillSwitch) | None => {
                false
            }
        }
    }

    /// A preflight calibration the commander allowed (disarmed, calibrated at rest): the
    /// estimate is dropped and the IMU calibrated again from the next frame, as at start;
    /// one already under way goes on.
    fn calibrate_again(&mut self, out: &mut impl Outputs) {
        let note = if self.at_rest && self.phase == Phase::Estimating {
            self.core.recalibrate();
            self.phase = Phase::Calibration;
            self.observed = None;
            "preflight calibration: calibrating the IMU at rest again, motors off"
        } else {
            "preflight calibration: the IMU's calibration at rest is under way"
        };
        out.record(FlightRecord::Note(note.into()));
    }

    /// Disarmed: when the commander may arm again ([`commander::Params::rearm`]), the next
    /// `arm` starts the ESCs as the first one did, under the estimate that keeps running.
    fn between_flights(&mut self) {
        if self.at_rest && self.commander.params().rearm && self.phase != Phase::Ended {
            self.esc_start_asked = false;
            self.escs_running_told = false;
            self.phase = Phase::Estimating;
        }
    }

    /// Steps on a recorded clock instead of the frames' times (replay).
    pub fn with_clock(mut self, clock: RecordedClock) -> Self {
        self.clock = clock;
        self
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn counts(&self) -> EstimatorCounts {
        self.counts
    }

    pub fn ekf(&self) -> Option<&Ekf> {
        self.core.ekf()
    }

    /// Step 1: one decoded frame.
    pub fn on_frame(
        &mut self,
        frame: &RawFrame,
        times: FrameTimes,
        esc: EscState,
        out: &mut impl Outputs,
    ) -> FrameAction {
        if self.phase == Phase::Ended {
            return FrameAction::Ended;
        }
        self.start(out);
        self.counts.frames += 1;
        self.esc_starts_seen = esc.starts;
        self.imu.on_frame(times.t_frame_us);
        // The commander's clock first: a stop it asks for goes with this frame's action.
        let stop = self.tick(times.t_frame_us, out);
        match self.front_end(frame, times, esc, out) {
            FrameAction::Step(s) => {
                self.stop_pending |= stop;
                FrameAction::Step(s)
            }
            FrameAction::Wait | FrameAction::StartEscs if stop => FrameAction::StopEscs,
            action => action,
        }
    }

    /// The frame through the IMU's front end: settling, the ESC start, the calibration, or a
    /// sample for a Kalman step.
    fn front_end(
        &mut self,
        frame: &RawFrame,
        times: FrameTimes,
        esc: EscState,
        out: &mut impl Outputs,
    ) -> FrameAction {
        let record = FlightRecord::Frame {
            times,
            frame: *frame,
        };
        match self.core.on_frame(frame, times.t_frame_us) {
            FrontEndEvent::Settling { .. } => FrameAction::Wait,
            FrontEndEvent::Holding => {
                if self.phase == Phase::Settle && self.commander.mode() == Mode::Disarmed {
                    out.record(FlightRecord::Note(
                        "IMU sampling period stable; disarmed, waiting for arm".into(),
                    ));
                }
                self.phase = Phase::EscStart;
                if self.commander.mode() != Mode::Armed {
                    return FrameAction::Wait;
                }
                self.esc_start(esc, times.t_frame_us, out)
            }
            FrontEndEvent::Calibrating { .. } => {
                if self.at_rest && self.phase == Phase::Settle {
                    out.record(FlightRecord::Note(
                        "IMU sampling period stable; calibrating at rest, motors off".into(),
                    ));
                }
                self.phase = Phase::Calibration;
                out.record(record);
                FrameAction::Wait
            }
            FrontEndEvent::Failed(e) => self.abort(Abort::Startup(e)),
            FrontEndEvent::Calibrated(null) => {
                out.record(record);
                self.calibrated(&null, times.t_frame_us, out)
            }
            FrontEndEvent::Sample(s) => {
                out.record(record);
                match self.escs_ramping(esc, times.t_frame_us, out) {
                    Some(action) => action,
                    None => FrameAction::Step(s),
                }
            }
        }
    }

    /// The commander's clock at a frame: its timed failsafes and the ground's rules, from
    /// arming on (the ESC ramp and the calibration too). `true`: stop the ESCs (disarmed).
    fn tick(&mut self, t_us: i64, out: &mut impl Outputs) -> bool {
        let request = self.commander.tick(t_us, &mut self.events);
        self.record_events(out);
        self.esc_request(request, t_us, out)
    }

    /// The calibration ended: noted, checked for plausibility (an implausible one refuses the
    /// arming after all), then the first Kalman step on its null sample.
    fn calibrated(
        &mut self,
        null: &crate::core::imu::calib::NullEstimate,
        t_us: i64,
        out: &mut impl Outputs,
    ) -> FrameAction {
        let (n, gyro_null) = (&null.sample, null.reference.gyro_null_rad_s);
        out.record(FlightRecord::Note(format!(
            "IMU calibration completed: acc {:?} m/s2, gyro offset {gyro_null:?} rad/s, euler {:?} rad, temp {} C",
            n.acc_m_s2, n.euler_rad, n.temp_c
        )));
        if self.core.ekf().is_some_and(Ekf::field_unread) {
            out.record(FlightRecord::Note(format!(
                "magnetometer read no field at the calibration ({:?}): the field will not hold \
                 the tilt without fixes or a gyro (ekf.r_field)",
                n.magn
            )));
        }
        if let Some(why) = commander::calibration_problem(&n.acc_m_s2, &gyro_null) {
            if self.at_rest {
                // Disarmed, nothing spins: taken again (the vehicle may have been moved).
                out.record(FlightRecord::Note(format!(
                    "IMU calibration not plausible ({why}): calibrating again"
                )));
                self.calibration_refused = Some(why);
                self.core.recalibrate();
                return FrameAction::Wait;
            }
            self.commander
                .on_calibration_refused(t_us, &why, &mut self.events);
            self.record_events(out);
            return self.abort(Abort::Calibration(why));
        }
        self.calibration_refused = None;
        // After an arm (the original's order) the ESCs have run their ramp already.
        self.commander.escs_running();
        self.phase = if self.at_rest {
            Phase::Estimating
        } else {
            Phase::FlightRamp
        };
        FrameAction::Step(null.sample)
    }

    /// Armed under a running estimate: the ESCs' ramp watched until they run (the commander
    /// told, and recorded for a replay) or stop (the run aborts, as in the original's order).
    /// `None`: the step goes on.
    fn escs_ramping(
        &mut self,
        esc: EscState,
        t_us: i64,
        out: &mut impl Outputs,
    ) -> Option<FrameAction> {
        let watching = self.at_rest
            && !self.escs_from_records
            && self.esc_start_asked
            && !self.escs_running_told
            && !esc.before_start(self.starts_asked);
        if !watching || self.commander.mode() != Mode::Armed {
            return None;
        }
        match esc.phase {
            EscPhase::Running => {
                out.record(FlightRecord::Note("ESC ramp done; idling".into()));
                self.operator(
                    OperatorInput::EscsRunning,
                    t_us,
                    ArmCheck::Recorded(&Ok(())),
                    out,
                );
                self.phase = Phase::Flight;
                None
            }
            EscPhase::Stopped if esc.stop_reason == Some(StopReason::KillSwitch) => {
                self.kill_switch_seen(t_us, out);
                None
            }
            EscPhase::Stopped => {
                let why = esc
                    .stop_reason
                    .map_or("no reason given", StopReason::name)
                    .to_string();
                self.commander.on_esc_stopped(t_us, &why, &mut self.events);
                self.record_events(out);
                Some(self.abort(Abort::EscStopped(why)))
            }
            EscPhase::Disabled | EscPhase::Ramping | EscPhase::Testing => None,
        }
    }

    /// Why the estimate running before arming cannot be flown yet (the `estimator` pre-arm
    /// check), if it cannot.
    fn estimator_problem(&self) -> Option<String> {
        let Some(ekf) = self.core.ekf() else {
            return Some(match (&self.calibration_refused, self.phase) {
                (Some(why), _) => {
                    format!("IMU calibration not plausible ({why}): calibrating again")
                }
                (None, Phase::Settle) => "IMU settling".into(),
                (None, _) => "IMU calibrating at rest".into(),
            });
        };
        let sigma = |i: usize| ekf.p[(i, i)].max(0.0).sqrt();
        let fixes = !matches!(self.gps, GpsFeed::Off);
        let ratios = self.observed.map_or(TestRatios::default(), |o| o.ratios);
        commander::estimator_problem(&commander::EstimatorHealth {
            not_running: None,
            gyro_lost: ekf.gyro_lost,
            tilt_sigma_rad: sigma(idx::PSI).max(sigma(idx::PHI)),
            velocity_sigma_m_s: sigma(idx::VQX).max(sigma(idx::VQY)).max(sigma(idx::VQZ)),
            position_sigma_m: fixes.then(|| ekf.fix_frame_sigma_m()),
            fix_fused: ekf.fix_seen,
            ratios: TestRatios {
                gps: self.last_fix_ratio,
                ..ratios
            },
        })
    }

    /// Whether an `arm` now would pass this side's own checks (`fly --arm` waits for it):
    /// settled (after-arm), or calibrated with the estimate converged (before-arm); the IMU's
    /// frames vouching for it either way.
    pub fn ready_to_arm(&self, t_us: i64) -> bool {
        let ready = if self.at_rest {
            self.phase == Phase::Estimating && self.estimator_problem().is_none()
        } else {
            self.phase == Phase::EscStart
        };
        ready && self.imu_trusted(t_us)
    }

    /// Settled: start the ESCs once, calibrate when their ramp is done, abort if they stopped.
    fn esc_start(&mut self, esc: EscState, t_us: i64, out: &mut impl Outputs) -> FrameAction {
        if !self.esc_start_asked {
            self.esc_start_asked = true;
            self.starts_asked = self.esc_starts_seen.saturating_add(1);
            out.record(FlightRecord::Note(
                "IMU sampling period stable; ESC start-up ramp".into(),
            ));
            return FrameAction::StartEscs;
        }
        if esc.before_start(self.starts_asked) {
            return FrameAction::Wait;
        }
        match esc.phase {
            EscPhase::Running => {
                out.record(FlightRecord::Note("ESC ramp done; IMU calibration".into()));
                self.core.begin_calibration();
                self.phase = Phase::Calibration;
                FrameAction::Wait
            }
            EscPhase::Stopped if esc.stop_reason == Some(StopReason::KillSwitch) => {
                self.kill_switch_seen(t_us, out);
                FrameAction::Wait
            }
            EscPhase::Stopped => {
                let why = esc
                    .stop_reason
                    .map_or("no reason given", StopReason::name)
                    .to_string();
                self.commander.on_esc_stopped(t_us, &why, &mut self.events);
                self.record_events(out);
                self.abort(Abort::EscStopped(why))
            }
            EscPhase::Disabled | EscPhase::Ramping | EscPhase::Testing => FrameAction::Wait,
        }
    }

    /// The ESCs were stopped by the pilot's kill switch before its report reached the
    /// commander (the radio's reader stops them first): the report is taken now, recorded as
    /// the radio's so that a replay takes it at the same step, and the vehicle is disarmed
    /// as the switch does; the run goes on. A report taken already changes nothing.
    fn kill_switch_seen(&mut self, t_us: i64, out: &mut impl Outputs) {
        if self.commander.mode() == Mode::Disarmed {
            return;
        }
        let report = commander::RcReport {
            kill: true,
            ..self.commander.rc_last()
        };
        let recorded = ArmCheck::Recorded(&Ok(()));
        // The ESCs are stopped already: what the input asks of them is done.
        let _ = self.operator(OperatorInput::Rc(report), t_us, recorded, out);
    }

    fn abort(&mut self, why: Abort) -> FrameAction {
        self.phase = Phase::Ended;
        FrameAction::Abort(why)
    }

    /// Step 2: the Kalman step on `sample`, with the controller's feedback of the previous step
    /// and the live fix that arrived since (gpsd), if any.
    pub fn estimate(
        &mut self,
        sample: ImuSample,
        times: FrameTimes,
        fb: &Feedback,
        live: Option<LiveFix>,
        out: &mut impl Outputs,
    ) -> Option<Estimate> {
        if let Some(t_cmd) = fb.t_cmd_us
            && self.gps.after_command(t_cmd)
        {
            out.record(FlightRecord::FakeGps(t_cmd));
        }
        // A fix older than the GPS timeout is not current: fusing it as if it were would pull
        // the estimate to where the vehicle was (a fix held back through the calibration).
        let max_age_us = (self.commander.params().gps_timeout_s * 1e6) as i64;
        if let Some(l) = live {
            if times.t_frame_us - l.stamp_us <= max_age_us {
                self.gps.offer_live(l.sample);
                self.offered = Some(l);
            } else {
                self.counts.stale_fixes += 1;
            }
        }
        // The commander's word of the previous step: the vehicle rests on the ground.
        let ground = Ground {
            height_m: self.commander.ground_contact_m(),
            at_rest: self.commander.at_rest(),
        };
        let row = self.core.steps() as usize;
        let st = self.clock.times(row, times, self.prev_frame_us);
        let gps = self.gps.for_step(st.t_us);
        if gps.is_some()
            && let Some(fix) = self.offered.take()
        {
            // Logged with a time the replay fuses in this same step.
            let t_us = self.prev_frame_us.unwrap_or(times.t_frame_us - 1);
            out.record(FlightRecord::GpsFix { t_us, fix });
        }
        self.prev_frame_us = Some(times.t_frame_us);
        let mut est = self
            .core
            .step(sample, st.t_us, fb.u_next, fb.mass_kg, gps, ground)?;
        est.t_ctrl_us = st.t_ctrl_us;
        est.t_cmd_us = st.t_cmd_us;
        self.count(&est);
        if est.gyro_lost && !self.gyro_lost_noted {
            self.gyro_lost_noted = true;
            out.record(FlightRecord::Note(format!(
                "gyro stuck: its counts repeated for {} frames; left out of the filter (the rates are the model's)",
                crate::core::imu::health::STUCK_FRAMES
            )));
        }
        self.guide(&mut est, fb, out);
        out.watchdog(Event::Estimate {
            step_us: est.t_us,
            temp_c: est.sample.temp_c,
            psi_rad: est.x[idx::PSI],
            phi_rad: est.x[idx::PHI],
            refused: est.ekf_error.is_some(),
        });
        out.record(FlightRecord::KalmanIn {
            t_us: est.t_us,
            dt_us: st.dt_col_us,
            sample: est.sample,
        });
        out.record(FlightRecord::XHat(est.x.into()));
        out.record(FlightRecord::Innov {
            t_us: est.t_us,
            ratios: est.ratios,
            gated: est.gated,
        });
        Some(est)
    }

    /// The commander's step: its guidance and keys for the controller, its ESC request.
    fn guide(&mut self, est: &mut Estimate, fb: &Feedback, out: &mut impl Outputs) {
        let thrust_n: f64 = fb
            .u_next
            .iter()
            .map(|&w| crate::core::model::thrust_n(w))
            .sum();
        let o = Observation {
            t_us: est.t_us,
            pos_m: [est.x[idx::X], est.x[idx::Y], est.x[idx::Z]],
            // Small tilts: the body's vertical speed is the world's.
            vz_m_s: est.x[idx::VQZ],
            thrust_ratio: thrust_n / (fb.mass_kg * crate::core::model::GRAVITY_M_S2),
            acc_m_s2: est.sample.acc_m_s2,
            tilt_rad: (est.x[idx::PSI].cos() * est.x[idx::PHI].cos())
                .clamp(-1.0, 1.0)
                .acos(),
            baro_alt_m: est.sample.alt_m,
            gyro_lost: est.gyro_lost,
            gps_fused: est.gps_used,
            gps_velocity_fused: est.gps_velocity_used,
            gps_velocity_ratio: est.gps_velocity_ratio,
            vertical_observed: est.vertical_observed,
            ratios: est.ratios,
            yaw_cal_rad: est.theta_cal_rad,
            pos_sigma_m: est.pos_sigma_m,
            bias_unaided_rad_s: est.bias_unaided_rad_s,
            acc_rest_m_s2: est.acc_rest_m_s2,
        };
        self.observed = Some(o);
        self.last_fix_ratio = o.ratios.gps.or(self.last_fix_ratio);
        let (guidance, request) = self.commander.on_estimate(&o, &mut self.events);
        self.record_events(out);
        est.guidance = guidance;
        est.gains = Some(self.commander.gains().clone());
        est.manual = self.keys.pop_front();
        let stop = self.esc_request(request, est.t_us, out);
        est.stop_escs = stop || std::mem::take(&mut self.stop_pending);
    }

    fn count(&mut self, est: &Estimate) {
        self.counts.steps += 1;
        self.counts.gps_updates += u64::from(est.gps_used);
        self.counts.ekf_errors += u64::from(est.ekf_error.is_some());
        self.counts.dt_clamped += u64::from(est.dt_clamped);
        self.counts.gated.add(est.gated);
        // Under an estimate that ran before arming the ramp's steps are the controller's own
        // (counted from the takeoff): the phase is the ESCs'.
        if !self.at_rest && matches!(self.phase, Phase::FlightRamp | Phase::Flight) {
            self.phase = if est.step < FLIGHT_RAMP_STEPS {
                Phase::FlightRamp
            } else {
                Phase::Flight
            };
        }
    }

    /// The watchdog halted the motors: record it once; nothing more is stepped.
    pub fn on_halt(&mut self, halt: Halt, out: &mut impl Outputs) {
        if self.phase != Phase::Ended {
            self.note_halt(halt.halt_us, halt.trip.reason.name(), out);
            out.record(FlightRecord::Halt(halt));
        }
    }

    /// A halt the driver recorded elsewhere (`fly`'s watchdog thread; a replay's mode.log):
    /// the commander's `kill`, settled at `t_us`; nothing more is stepped.
    pub fn note_halt(&mut self, t_us: i64, reason: &str, out: &mut impl Outputs) {
        self.phase = Phase::Ended;
        self.commander.on_halt(t_us, reason, &mut self.events);
        self.record_events(out);
    }
}

/// What the driver does after an operator's input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OperatorAction {
    Nothing,
    /// Zero and disable the ESCs (disarmed on the ground); the run goes on.
    StopEscs,
    /// The manual quit key (the original's Esc): end the run, the motors stopped first.
    Quit,
    /// An `arm` taken under a running estimate (`imu.calibrate = "before-arm"`): enable the
    /// ESCs and run their start-up ramp now.
    StartEscs,
    /// A motor test the commander took: spin this motor alone.
    TestMotor(crate::core::esc::MotorTest),
    /// The pilot's kill switch: zero and disable now (named `kill`); the run goes on.
    KillSwitch,
}

/// How an `arm` is checked.
#[derive(Debug, Clone, Copy)]
pub enum ArmCheck<'a> {
    /// Against what the driver observed.
    Facts(&'a ArmFacts),
    /// As the recorded run decided (replay).
    Recorded(&'a Result<(), String>),
}

/// The err.log line of a commander event.
pub fn commander_line(e: &commander::Event) -> String {
    match e {
        commander::Event::Mode { mode, why, .. } => format!("mode {}: {why}", mode.name()),
        commander::Event::Failsafe { kind, action, .. } => {
            format!("failsafe {}: {}", kind.name(), action.name())
        }
        commander::Event::Refusal { command, why, .. } => format!("{command} refused: {why}"),
        commander::Event::Reached { item, name, .. } => {
            format!("mission item {} ({name}) done", item + 1)
        }
    }
}

/// One control step's result for the driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub step: u32,
    /// The speeds for the ESC driver, rad/s (flight ramp and saturation applied).
    pub w_rad_s: [f64; 4],
    /// For the estimator side's next step.
    pub feedback: Feedback,
    pub saturated: bool,
    /// Zero and disable the ESCs instead of sending the speeds (disarmed on the ground).
    pub stop_escs: bool,
}

/// Counters of the controller side.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ControllerCounts {
    pub steps: u64,
    /// Steps under the control law (from the takeoff on).
    pub flying_steps: u64,
    pub saturated: u64,
    pub manual_commands: u64,
}

/// The controller side: manual commands, the control step, position-hold changes.
#[derive(Debug, Clone)]
pub struct ControllerSide {
    core: ControllerCore,
    position_hold: bool,
    counts: ControllerCounts,
}

impl ControllerSide {
    pub fn new(core: ControllerCore) -> Self {
        ControllerSide {
            core,
            position_hold: false,
            counts: ControllerCounts::default(),
        }
    }

    pub fn counts(&self) -> ControllerCounts {
        self.counts
    }

    /// The feedback before the first step.
    pub fn first_feedback(&self) -> Feedback {
        Feedback {
            step: 0,
            u_next: self.core.input_for_step(1),
            mass_kg: self.core.mass_kg(),
            t_cmd_us: None,
        }
    }

    /// The set point (x, y, z), m, once flying.
    pub fn setpoint_m(&self) -> Option<[f64; 3]> {
        self.core
            .planner()
            .map(|p| [p.sp.x[0], p.sp.x[1], p.sp.x[2]])
    }

    /// A manual set-point command for the planner (spec 5.2): attitude and weight keys.
    fn manual(&mut self, cmd: ManualCommand, out: &mut impl Outputs) {
        self.counts.manual_commands += 1;
        let note = match self.core.apply_manual(cmd) {
            Some(o) => format!(
                "manual {cmd:?}: {o:?}; set point {:?}",
                self.core.planner().map(|p| p.sp.x)
            ),
            None => format!("manual {cmd:?} ignored before the takeoff"),
        };
        out.record(FlightRecord::Note(note));
    }

    /// Step 3: one control step on `est`. The command goes to `send` (the ESC driver) before
    /// anything is recorded, so that every command in the `w` log was handed over.
    pub fn control(
        &mut self,
        est: &Estimate,
        send: impl FnOnce(&Command),
        out: &mut impl Outputs,
    ) -> Command {
        if let Some(k) = est.manual {
            self.manual(k, out);
        }
        let c = self.core.control(est, est.t_ctrl_us, est.t_cmd_us);
        let command = Command {
            step: c.step,
            w_rad_s: c.w_sent,
            feedback: Feedback {
                step: c.step,
                u_next: self.core.input_for_step(c.step + 1),
                mass_kg: self.core.mass_kg(),
                t_cmd_us: Some(c.t_cmd_us),
            },
            saturated: c.saturated,
            stop_escs: est.stop_escs,
        };
        send(&command);
        if est.guidance.fly && c.position_hold != self.position_hold {
            self.position_hold = c.position_hold;
            out.record(FlightRecord::Note(
                self.core.position_hold_message(c.position_hold),
            ));
        }
        self.counts.steps += 1;
        self.counts.flying_steps += u64::from(est.guidance.fly);
        self.counts.saturated += u64::from(c.saturated);
        out.record(FlightRecord::Int {
            t_us: c.t_ctrl_us,
            x_int: c.x_int,
            n_int: c.n_int,
        });
        out.record(FlightRecord::Command {
            t_us: c.t_cmd_us,
            w_rad_s: c.w_sent,
        });
        if let Some(sp) = c.setpoint {
            out.record(FlightRecord::Setpoint {
                t_us: c.t_ctrl_us,
                sp,
            });
        }
        command
    }
}
