//! The commander's rules checked exhaustively (`core::commander`, pure): a breadth-first search over abstract inputs
//! (every command, a link that beats or falls silent, fixes that come or stop, a vehicle
//! that climbs, is stuck on the ground or flips, an estimator that goes bad, a halt), each
//! followed by a second of flight on a simple vehicle, to a bounded depth. States that look
//! alike (mode, the environment, the vehicle's height and the timers to the second) are
//! explored once. Along every path it asserts: no disarm or motor stop in the air except for
//! the causes on the one list (`kill`, `crash`, the watchdog's halts); a failsafe condition
//! that persists leads to a landing or a disarm; nothing stays armed on the ground.

use std::collections::{HashSet, VecDeque};
use uquad::core::commander::{
    Action, ArmFacts, Command, Commander, EscRequest, LinkSource, Mode, Observation, Params, Start,
    StickLimits, StickMode,
};
use uquad::core::ekf::TestRatios;
use uquad::core::model::GRAVITY_M_S2;

/// One abstract input, applied at the start of a second of flight.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Input {
    Command(Command),
    /// Toggles of the environment.
    LinkSilent,
    FixesLost,
    StuckOnGround,
    Flipped,
    EstimatorBad,
    /// The watchdog's halt (one of its own causes).
    Halt,
    Wait,
}

const INPUTS: [Input; 18] = [
    Input::Command(Command::Arm),
    Input::Command(Command::Takeoff(None)),
    Input::Command(Command::Land),
    Input::Command(Command::Disarm),
    Input::Command(Command::Kill),
    Input::Command(Command::Return),
    Input::Command(Command::Hold(None)),
    Input::Command(Command::Start),
    Input::Command(Command::Sticks(StickMode::Position)),
    Input::Command(Command::Sticks(StickMode::Altitude)),
    Input::Command(Command::MotorTest {
        motor: 1,
        throttle_pct: 10.0,
        duration_s: 5.0,
    }),
    Input::LinkSilent,
    Input::FixesLost,
    Input::StuckOnGround,
    Input::Flipped,
    Input::EstimatorBad,
    Input::Halt,
    Input::Wait,
];

/// The world around the commander.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct World {
    link_silent: bool,
    fixes_lost: bool,
    stuck: bool,
    flipped: bool,
    estimator_bad: bool,
    z_m: f64,
    t_us: i64,
    /// How long each persistent condition has held while armed, s.
    silent_s: f64,
    no_fix_s: f64,
    bad_s: f64,
    flipped_s: f64,
    grounded_s: f64,
    motors: bool,
}

/// Short times, so that a few seconds of depth reach every timer.
fn params() -> Params {
    Params {
        start: Start::Disarmed,
        hover_z_m: 1.0,
        climb_m_s: 1.0,
        climb_acc_m_s2: 2.0,
        takeoff_tolerance_m: 0.1,
        land_m_s: 1.0,
        land_slow_m_s: 0.5,
        touchdown_v_m_s: 0.15,
        touchdown_thrust: 0.8,
        touchdown_s: 0.3,
        link_sources: [true; 3],
        link_timeout_s: 1.5,
        link_action: Action::Land,
        gps_timeout_s: 1.0,
        gps_loss_land_s: 1.0,
        gps_loss_action: Action::Land,
        fence_radius_m: 50.0,
        fence_alt_max_m: 10.0,
        fence_action: Action::Land,
        ekf_bad_s: 1.0,
        ekf_action: Action::Land,
        gps_live: true,
        disarm_ground_s: 2.0,
        crash_tilt_rad: 1.0,
        crash_s: 0.5,
        takeoff_timeout_s: 4.0,
        input_expiry_s: 1.0,
        rearm: true,
        z_min_m: 0.2,
        z_max_m: 3.0,
        mission: uquad::core::mission::Limits {
            acc_m_s2: 0.5,
            yaw_rate_rad_s: 0.8,
            yaw_acc_rad_s2: 1.0,
            return_m_s: 1.0,
        },
        rc: None,
        sticks: StickLimits {
            max_speed_m_s: 3.0,
            max_climb_m_s: 1.0,
            max_yaw_rate_rad_s: 1.0,
            max_tilt_rad: 0.27,
        },
    }
}

const STEP_US: i64 = 10_000;
const SECOND_STEPS: i64 = 100;

/// The vehicle this step: on its height set point unless stuck (then on the ground), pressed
/// onto the ground by a set point below it, tilted when flipped.
fn observe(c: &Commander, w: &World) -> Observation {
    let g = c.guidance();
    let pressing = w.z_m <= 0.0 && g.pos_m[2] < -0.2;
    let thrust = if !w.motors {
        0.0
    } else if pressing {
        0.6
    } else {
        1.0
    };
    Observation {
        t_us: w.t_us,
        pos_m: [0.0, 0.0, w.z_m],
        vz_m_s: 0.0,
        thrust_ratio: thrust,
        acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
        tilt_rad: if w.flipped { 2.0 } else { 0.0 },
        baro_alt_m: w.z_m,
        gyro_lost: false,
        gps_fused: !w.fixes_lost && w.t_us % 1_000_000 == 0,
        gps_velocity_fused: !w.fixes_lost && w.t_us % 1_000_000 == 0,
        gps_velocity_ratio: None,
        vertical_observed: true,
        ratios: TestRatios {
            attitude: if w.estimator_bad { 10.0 } else { 0.0 },
            altitude: 0.0,
            gps: None,
        },
        yaw_cal_rad: 0.0,
        pos_sigma_m: 0.0,
        bias_unaided_rad_s: 0.0,
        acc_rest_m_s2: 9.81,
    }
}

/// What a transition did that the rules judge.
#[derive(Debug, Default)]
struct Seen {
    stop_in_air: Option<String>,
}

fn request(req: Option<EscRequest>, w: &mut World, seen: &mut Seen, why: &str) {
    match req {
        Some(EscRequest::Start) => w.motors = true,
        // A motor test spins one motor, only with the motors off (disarmed, on the ground).
        Some(EscRequest::MotorTest(_)) if w.motors || w.z_m > 0.0 => {
            seen.stop_in_air = Some(format!(
                "motor test with the motors on at {} m ({why})",
                w.z_m
            ));
        }
        Some(EscRequest::MotorTest(_)) => {}
        Some(EscRequest::Stop | EscRequest::EndMotorTest) => {
            if w.z_m > 0.3 && w.motors {
                seen.stop_in_air = Some(format!("stop at {} m ({why})", w.z_m));
            }
            w.motors = false;
        }
        // Both on the one list of causes that may cut the motors in the air.
        Some(EscRequest::Kill | EscRequest::Crash | EscRequest::KillSwitch) => w.motors = false,
        None => {}
    }
}

/// Applies `input`, then flies one second.
fn transition(c: &mut Commander, w: &mut World, input: Input) -> Seen {
    let mut seen = Seen::default();
    let mut ev = Vec::new();
    match input {
        Input::Command(cmd) => {
            let facts = ArmFacts {
                imu_stable: true,
                gps_required: true,
                gps_eph_m: (!w.fixes_lost).then_some(1.0),
                gps_max_eph_m: 5.0,
                log_error: None,
                realtime: true,
                esc_silent: vec![],
                estimator: None,
            };
            if !w.link_silent {
                c.link_beat(LinkSource::Gcs, w.t_us);
                let o = observe(c, w);
                let r = c.command(cmd, w.t_us, facts.verdict(), Some(&o), &mut ev);
                if r == Some(EscRequest::Start) {
                    // The ESCs' ramp, done within the second that follows.
                    c.escs_running();
                }
                request(r, w, &mut seen, "command");
            }
        }
        Input::LinkSilent => w.link_silent = !w.link_silent,
        Input::FixesLost => w.fixes_lost = !w.fixes_lost,
        Input::StuckOnGround => w.stuck = !w.stuck,
        Input::Flipped => w.flipped = !w.flipped,
        Input::EstimatorBad => w.estimator_bad = !w.estimator_bad,
        Input::Halt => {
            c.on_halt(w.t_us, "imu-timeout", &mut ev);
            w.motors = false;
        }
        Input::Wait => {}
    }
    for _ in 0..SECOND_STEPS {
        fly_step(c, w, &mut seen);
    }
    seen
}

fn fly_step(c: &mut Commander, w: &mut World, seen: &mut Seen) {
    let mut ev = Vec::new();
    w.t_us += STEP_US;
    if !w.link_silent && w.t_us % 1_000_000 == 0 {
        c.link_beat(LinkSource::Gcs, w.t_us);
    }
    if !w.fixes_lost && w.t_us % 1_000_000 == 0 {
        c.gps_fix(w.t_us);
    }
    let r = c.tick(w.t_us, &mut ev);
    request(r, w, seen, "tick");
    let o = observe(c, w);
    let (g, r) = c.on_estimate(&o, &mut ev);
    request(r, w, seen, "step");
    // The vehicle follows its set point's height while the motors fly it.
    let flying = w.motors && g.fly && !w.stuck;
    w.z_m = if flying { g.pos_m[2].max(0.0) } else { 0.0 };
    let armed = !matches!(c.mode(), Mode::Disarmed | Mode::Kill);
    let dt_s = STEP_US as f64 / 1e6;
    let held = |on: bool, s: f64| if armed && on { s + dt_s } else { 0.0 };
    w.silent_s = held(w.link_silent, w.silent_s);
    w.no_fix_s = held(w.fixes_lost, w.no_fix_s);
    // On the ground a bad estimator refuses the takeoff; the ground's time then disarms.
    w.bad_s = held(w.estimator_bad && c.mode().airborne(), w.bad_s);
    w.flipped_s = held(w.flipped && w.motors, w.flipped_s);
    let idle_on_ground = armed && w.motors && w.z_m <= 0.0 && c.mode() != Mode::Takeoff;
    w.grounded_s = if idle_on_ground {
        w.grounded_s + dt_s
    } else {
        0.0
    };
}

/// What makes two states alike for the search.
fn signature(c: &Commander, w: &World) -> String {
    let g = c.guidance();
    format!(
        "{:?} {} {} {} {} {} {} {:.1} {:.1} {:.0} {:.0} {:.0} {:.0} {:.0} {}",
        c.mode(),
        w.link_silent,
        w.fixes_lost,
        w.stuck,
        w.flipped,
        w.estimator_bad,
        w.motors,
        w.z_m,
        g.pos_m[2],
        w.silent_s,
        w.no_fix_s,
        w.bad_s,
        w.flipped_s,
        w.grounded_s,
        g.hold_xy,
    )
}

/// The rules every reached state must keep.
fn judge(c: &Commander, w: &World, seen: &Seen, path: &[Input]) {
    let p = params();
    assert!(
        seen.stop_in_air.is_none(),
        "{:?} after {path:?}",
        seen.stop_in_air
    );
    // A condition held past its time and one more second: landing, disarmed or halted.
    let ending = matches!(c.mode(), Mode::Land | Mode::Disarmed | Mode::Kill) || !w.motors;
    for (what, held_s, limit_s) in [
        ("link silent", w.silent_s, p.link_timeout_s),
        ("no fix", w.no_fix_s, p.gps_timeout_s + p.gps_loss_land_s),
        ("estimator bad", w.bad_s, p.ekf_bad_s),
    ] {
        assert!(
            held_s <= limit_s + 1.0 || ending,
            "{what} {held_s} s, mode {:?}, after {path:?}",
            c.mode()
        );
    }
    // Flipped with the motors running: halted (crash) within crash_s and a second.
    assert!(
        w.flipped_s <= p.crash_s + 1.0,
        "flipped {} s with the motors on, mode {:?}, after {path:?}",
        w.flipped_s,
        c.mode()
    );
    // Armed on the ground outside a takeoff: disarmed by disarm_ground_s (and a second).
    assert!(
        w.grounded_s <= p.disarm_ground_s + 1.0,
        "motors idle on the ground {} s in {:?} after {path:?}",
        w.grounded_s,
        c.mode()
    );
}

#[test]
fn no_path_of_abstract_inputs_breaks_the_rules() {
    const DEPTH: usize = 10;
    let mut start = Commander::new(params());
    start.start(0, &mut Vec::new());
    let world = World::default();
    let mut seen_states = HashSet::new();
    let mut queue = VecDeque::from([(start, world, Vec::<Input>::new())]);
    let mut transitions = 0u64;
    while let Some((c, w, path)) = queue.pop_front() {
        if path.len() == DEPTH {
            continue;
        }
        for input in INPUTS {
            let (mut c2, mut w2) = (c.clone(), w);
            let seen = transition(&mut c2, &mut w2, input);
            transitions += 1;
            let mut p2 = path.clone();
            p2.push(input);
            judge(&c2, &w2, &seen, &p2);
            if seen_states.insert(signature(&c2, &w2)) {
                queue.push_back((c2, w2, p2));
            }
        }
    }
    eprintln!(
        "commander explored to depth {DEPTH}: {} states, {transitions} transitions",
        seen_states.len()
    );
    assert!(seen_states.len() > 1000, "{}", seen_states.len());
}
