//! The flight sequence (`core::flight::sequence`) on its own, without time passing: the
//! start-up order, the reactions to the ESCs' states, a failed start-up, and a watchdog halt
//! in every phase. Frames come from the simulated IMU at rest; nothing reads a clock.

mod common;
use common::*;
use uquad::core::esc::{EscPhase, StopReason};
use uquad::core::flight::{
    Abort, ControllerSide, EscState, EstimatorSide, Feedback, FlightRecord, FrameAction,
    FrameTimes, Outputs, Phase,
};
use uquad::core::watchdog::{Event, Halt, Trip, TripReason};

/// Records and watchdog events, kept for the checks.
#[derive(Default)]
struct Kept {
    records: Vec<FlightRecord>,
    events: Vec<Event>,
}

impl Outputs for Kept {
    fn record(&mut self, r: FlightRecord) {
        self.records.push(r);
    }
    fn watchdog(&mut self, e: Event) {
        self.events.push(e);
    }
}

impl Kept {
    /// The sequence's notes (the commander's mode lines left out).
    fn notes(&self) -> Vec<&str> {
        self.records
            .iter()
            .filter_map(|r| match r {
                FlightRecord::Note(n) if !n.starts_with("mode ") => Some(n.as_str()),
                _ => None,
            })
            .collect()
    }
}

/// A vehicle at rest on the ground, its IMU, the two sides, and a stand-in ESC driver whose
/// ramp takes `ramp_frames` frames.
struct Bench {
    plant: uquad::sim::physics::Plant,
    imu: uquad::sim::imu::SimImu,
    estimator: EstimatorSide,
    controller: ControllerSide,
    feedback: Feedback,
    esc: EscPhase,
    esc_reason: Option<StopReason>,
    ramp_left: u32,
    t_us: i64,
    out: Kept,
    start_requests: u32,
    commands: Vec<[f64; 4]>,
    aborts: Vec<Abort>,
}

impl Bench {
    fn new(ramp_frames: u32) -> Self {
        // Armed at start: these tests are about the sequence's order, not the commander's (and
        // without a receiver, whose silence from arming would disarm on the ground).
        Bench::with(
            ramp_frames,
            &["commander.start=flying", "gps.mode=\"fake-zero\""],
        )
    }

    fn with(ramp_frames: u32, sets: &[&str]) -> Self {
        let sets: Vec<_> = sets
            .iter()
            .map(|s| uquad::config::parse_set(s).unwrap())
            .collect();
        let profile = uquad::config::load(&root().join("config/uquad.toml"), &sets).unwrap();
        let (plant, imu) = uquad::sim::vehicle(&profile, 7);
        let (estimator, controller) = uquad::app::flight::live_sides(&profile);
        Bench {
            plant,
            imu,
            feedback: controller.first_feedback(),
            estimator,
            controller,
            esc: EscPhase::Disabled,
            esc_reason: None,
            ramp_left: ramp_frames,
            t_us: 0,
            out: Kept::default(),
            start_requests: 0,
            commands: Vec::new(),
            aborts: Vec::new(),
        }
    }

    /// One frame, `period_us` after the previous, through the order every mode follows.
    fn frame_after(&mut self, period_us: i64) -> FrameAction {
        self.t_us += period_us;
        self.imu.first_half(&self.plant);
        let frame = self.imu.frame(&self.plant, period_us as u32);
        let times = FrameTimes::at(self.t_us);
        if self.esc == EscPhase::Ramping {
            self.ramp_left = self.ramp_left.saturating_sub(1);
            if self.ramp_left == 0 {
                self.esc = EscPhase::Running;
            }
        }
        let esc = EscState {
            phase: self.esc,
            stop_reason: self.esc_reason,
            starts: self.start_requests,
        };
        let action = self.estimator.on_frame(&frame, times, esc, &mut self.out);
        match &action {
            FrameAction::StartEscs => {
                self.start_requests += 1;
                self.esc = EscPhase::Ramping;
            }
            FrameAction::Step(sample) => {
                let est = self
                    .estimator
                    .estimate(*sample, times, &self.feedback, None, &mut self.out)
                    .expect("a step after calibration");
                let commands = &mut self.commands;
                let send = |c: &uquad::core::flight::Command| commands.push(c.w_rad_s);
                self.feedback = self.controller.control(&est, send, &mut self.out).feedback;
            }
            FrameAction::Abort(a) => self.aborts.push(a.clone()),
            FrameAction::StopEscs => {
                self.esc = EscPhase::Stopped;
                self.esc_reason = Some(StopReason::Disarmed);
            }
            FrameAction::Wait | FrameAction::Ended => {}
        }
        action
    }

    fn frame(&mut self) -> FrameAction {
        self.frame_after(10_000)
    }

    /// Frames until the sequence reaches `phase` (at most `limit`).
    fn until(&mut self, phase: Phase, limit: usize) {
        for _ in 0..limit {
            if self.estimator.phase() == phase {
                return;
            }
            self.frame();
        }
        panic!("{phase:?} not reached; at {:?}", self.estimator.phase());
    }
}

#[test]
fn start_up_runs_settle_esc_start_calibration_flight_ramp_flight_in_order() {
    let mut b = Bench::new(30);
    let mut phases = vec![b.estimator.phase()];
    let mut flight_from_step = None;
    for _ in 0..800 {
        b.frame();
        if phases.last() != Some(&b.estimator.phase()) {
            phases.push(b.estimator.phase());
            if b.estimator.phase() == Phase::Flight {
                flight_from_step = Some(b.estimator.counts().steps);
            }
        }
    }
    assert_eq!(
        phases,
        [
            Phase::Settle,
            Phase::EscStart,
            Phase::Calibration,
            Phase::FlightRamp,
            Phase::Flight
        ]
    );
    assert_eq!(b.start_requests, 1, "the ESCs are started once");
    assert_eq!(
        b.out.notes()[..3],
        [
            "IMU sampling period stable; ESC start-up ramp",
            "ESC ramp done; IMU calibration",
            b.out.notes()[2],
        ]
    );
    assert!(b.out.notes()[2].starts_with("IMU calibration completed"));
    // The flight ramp is the first 100 control steps; every command is a speed the motors take.
    assert_eq!(flight_from_step, Some(100));
    assert!(b.commands.len() > 100);
    assert!(
        b.commands
            .iter()
            .flatten()
            .all(|w| w.is_finite() && (100.0..=368.0).contains(w)),
        "{:?}",
        b.commands
    );
    // Every step reported its sanity inputs to the watchdog and logged its records.
    let steps = b.estimator.counts().steps as usize;
    assert_eq!(steps, b.commands.len());
    let estimates = b
        .out
        .events
        .iter()
        .filter(|e| matches!(e, Event::Estimate { .. }))
        .count();
    assert_eq!(estimates, steps);
    let count = |f: fn(&FlightRecord) -> bool| b.out.records.iter().filter(|r| f(r)).count();
    assert_eq!(count(|r| matches!(r, FlightRecord::KalmanIn { .. })), steps);
    assert_eq!(count(|r| matches!(r, FlightRecord::XHat(_))), steps);
    assert_eq!(count(|r| matches!(r, FlightRecord::Command { .. })), steps);
    assert_eq!(count(|r| matches!(r, FlightRecord::Int { .. })), steps);
}

#[test]
fn escs_stopped_during_their_ramp_abort_the_start_up() {
    let mut b = Bench::new(1_000);
    b.until(Phase::EscStart, 200);
    b.frame();
    assert_eq!(b.esc, EscPhase::Ramping);
    b.esc = EscPhase::Stopped;
    b.esc_reason = Some(StopReason::Halt(TripReason::EscAck));
    let action = b.frame();
    assert_eq!(
        action,
        FrameAction::Abort(Abort::EscStopped("esc-ack".into()))
    );
    assert_eq!(
        b.aborts[0].to_string(),
        "the ESCs stopped during their start-up ramp: esc-ack"
    );
    assert_eq!(b.estimator.phase(), Phase::Ended);
    assert_eq!(b.frame(), FrameAction::Ended, "nothing is stepped after");
    assert!(b.commands.is_empty());
}

#[test]
fn an_unstable_imu_period_fails_the_start_up_before_the_escs_start() {
    let mut b = Bench::new(30);
    let mut action = FrameAction::Wait;
    for _ in 0..100 {
        // 20 ms between frames: outside the accepted period.
        action = b.frame_after(20_000);
        if matches!(action, FrameAction::Abort(_)) {
            break;
        }
    }
    let FrameAction::Abort(Abort::Startup(e)) = action else {
        panic!("no abort: {action:?}");
    };
    assert!(e.to_string().contains("not stable"), "{e}");
    assert_eq!(b.start_requests, 0, "the ESCs never start");
    assert_eq!(b.frame(), FrameAction::Ended);
}

#[test]
fn a_watchdog_halt_ends_the_sequence_in_every_phase() {
    for phase in [
        Phase::Settle,
        Phase::EscStart,
        Phase::Calibration,
        Phase::FlightRamp,
        Phase::Flight,
    ] {
        let mut b = Bench::new(30);
        b.until(phase, 800);
        let commands = b.commands.len();
        let halt = Halt {
            trip: Trip {
                reason: TripReason::ImuTimeout,
                event_us: b.t_us,
                decided_us: b.t_us + 12_000,
            },
            halt_us: b.t_us + 13_000,
            unconfirmed: [None; 4],
        };
        b.estimator.on_halt(halt, &mut b.out);
        b.estimator.on_halt(halt, &mut b.out);
        let halts: Vec<_> = b
            .out
            .records
            .iter()
            .filter(|r| matches!(r, FlightRecord::Halt(_)))
            .collect();
        assert_eq!(
            halts,
            [&FlightRecord::Halt(halt)],
            "{phase:?}: recorded once"
        );
        assert_eq!(b.estimator.phase(), Phase::Ended, "{phase:?}");
        assert_eq!(b.frame(), FrameAction::Ended, "{phase:?}");
        assert_eq!(b.commands.len(), commands, "{phase:?}: no command after");
        assert_eq!(b.start_requests, u32::from(phase != Phase::Settle));
    }
}

#[test]
fn the_quit_key_ends_the_run_in_any_mode_and_keys_wait_for_their_planner() {
    use uquad::core::commander::{LinkSource, OperatorInput};
    use uquad::core::control::{Dir, ManualCommand};
    use uquad::core::flight::{ArmCheck, OperatorAction};
    let mut b = Bench::new(30);
    let ok = Ok(());
    let key = |b: &mut Bench, k| {
        let input = OperatorInput::Key(k);
        b.estimator
            .operator(input, b.t_us, ArmCheck::Recorded(&ok), &mut b.out)
    };
    // Before the flight (armed at start, still settling): a roll key is noted when its
    // planner exists; the quit key ends the run at once.
    assert_eq!(
        key(&mut b, ManualCommand::Roll(Dir::Up)),
        OperatorAction::Nothing
    );
    assert_eq!(key(&mut b, ManualCommand::Quit), OperatorAction::Quit);
    assert!(
        b.out.notes().contains(&"manual quit: stopping"),
        "{:?}",
        b.out.notes()
    );
    // An operator's command in the flight's records, as a replay reads it back.
    let arm = OperatorInput::Command(uquad::core::commander::Command::Arm, LinkSource::Console);
    b.estimator
        .operator(arm.clone(), b.t_us, ArmCheck::Recorded(&ok), &mut b.out);
    assert!(
        b.out
            .records
            .iter()
            .any(|r| matches!(r, FlightRecord::Operator { input, .. } if *input == arm)),
        "the input is recorded"
    );
}

/// A bench of `frames` calibrating at rest before arming (fake fixes), and the facts of a
/// driver whose IMU is stable.
fn before_arm_bench(frames: u32) -> (Bench, uquad::core::commander::ArmFacts) {
    let b = Bench::with(
        frames,
        &["imu.calibrate=\"before-arm\"", "gps.mode=\"fake-zero\""],
    );
    let facts = uquad::core::commander::ArmFacts {
        imu_stable: true,
        realtime: true,
        ..Default::default()
    };
    (b, facts)
}

#[test]
fn calibrated_before_arming_the_estimate_runs_and_an_arm_starts_the_escs_under_it() {
    use uquad::core::commander::{Command, LinkSource, Mode, OperatorInput};
    use uquad::core::flight::{ArmCheck, OperatorAction};
    let (mut b, facts) = before_arm_bench(30);
    let arm = |b: &mut Bench| {
        let input = OperatorInput::Command(Command::Arm, LinkSource::Console);
        let f = facts.clone();
        let action = b
            .estimator
            .operator(input, b.t_us, ArmCheck::Facts(&f), &mut b.out);
        (action, b.estimator.last_refusal().map(str::to_string))
    };
    b.until(Phase::Calibration, 200);
    let (action, why) = arm(&mut b);
    assert_eq!(action, OperatorAction::Nothing);
    assert_eq!(why.as_deref(), Some("estimator: IMU calibrating at rest"));
    // Calibrated at rest: the estimate runs while disarmed, nothing asks for the ESCs, and
    // no estimate reaches the watchdog's sanity rules as one of a flight.
    b.until(Phase::Estimating, 600);
    let mut steps = 0;
    while !b.estimator.ready_to_arm(b.t_us) {
        assert!(matches!(b.frame(), FrameAction::Step(_)));
        steps += 1;
        if steps == 500 {
            panic!("the estimator check never passed: {:?}", arm(&mut b).1);
        }
    }
    assert_eq!(b.start_requests, 0);
    assert_eq!(b.estimator.mode(), Mode::Disarmed);
    let (action, why) = arm(&mut b);
    assert_eq!((action, why), (OperatorAction::StartEscs, None));
    assert_eq!(b.estimator.phase(), Phase::EscStart);
    // The ESC writer takes the start.
    b.start_requests += 1;
    b.esc = EscPhase::Ramping;
    // Every frame of the ramp is still a Kalman step; its end is told and recorded.
    for _ in 0..40 {
        assert!(matches!(b.frame(), FrameAction::Step(_)));
    }
    assert_eq!(b.estimator.phase(), Phase::Flight);
    let told = b.out.records.iter().any(|r| {
        matches!(
            r,
            FlightRecord::Operator {
                input: OperatorInput::EscsRunning,
                ..
            }
        )
    });
    assert!(told, "{:?}", b.out.notes());
    assert!(b.out.notes().contains(&"ESC ramp done; idling"));
    assert_eq!(b.estimator.mode(), Mode::Armed);
}

/// The radio's reader stops the ESCs at a kill frame before its report reaches the flight:
/// a start-up ramp stopped so is the pilot's kill, not a failed start-up. The run goes on,
/// disarmed, the kill recorded as the radio's report (a replay takes it at the same step).
#[test]
fn escs_stopped_by_the_kill_switch_during_their_ramp_disarm_and_the_run_goes_on() {
    use uquad::core::commander::{Command, LinkSource, Mode, OperatorInput};
    use uquad::core::flight::ArmCheck;
    let (mut b, facts) = before_arm_bench(1_000);
    b.until(Phase::Estimating, 800);
    while !b.estimator.ready_to_arm(b.t_us) {
        b.frame();
    }
    let input = OperatorInput::Command(Command::Arm, LinkSource::Console);
    b.estimator
        .operator(input, b.t_us, ArmCheck::Facts(&facts), &mut b.out);
    b.start_requests += 1;
    b.esc = EscPhase::Ramping;
    b.frame();
    b.esc = EscPhase::Stopped;
    b.esc_reason = Some(StopReason::KillSwitch);
    for _ in 0..10 {
        assert!(!matches!(b.frame(), FrameAction::Abort(_)));
    }
    assert!(b.aborts.is_empty(), "{:?}", b.aborts);
    assert_eq!(b.estimator.mode(), Mode::Disarmed);
    let kills = b
        .out
        .records
        .iter()
        .filter(|r| {
            matches!(
                r,
                FlightRecord::Operator {
                    input: OperatorInput::Rc(rc),
                    ..
                } if rc.kill
            )
        })
        .count();
    assert_eq!(kills, 1, "{:?}", b.out.notes());
    let why = b.out.records.iter().rev().find_map(|r| match r {
        FlightRecord::Commander(uquad::core::commander::Event::Mode {
            mode: Mode::Disarmed,
            why,
            ..
        }) => Some(why.clone()),
        _ => None,
    });
    assert_eq!(why.as_deref(), Some("kill switch"));
}
