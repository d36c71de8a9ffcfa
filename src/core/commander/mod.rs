//! The commander: the vehicle's mode, the operator's commands, the pre-arm verdict, the takeoff
//! and landing profiles, touchdown detection and the graded failsafes, as a pure state machine.
//! Time, observations and commands come in as arguments; mode changes, failsafes, refusals and
//! the guidance for the controller (set point, motors idle or flying) come out. Not in the
//! original, except its link rule (spec 8.2, `check_net`), which here lands instead of cutting.
//!
//! Modes: `disarmed` → `arm` → `armed` (ESC start-up ramp, IMU calibration, motors idling) →
//! `takeoff` → `hold` → `land` → touchdown → `disarmed`; `kill` (the watchdog's halt) from any
//! mode. Heights are above the point where the takeoff started (the ground).

mod figures;

pub use figures::{ClimbTrace, DescentTrace, Figures, Takeoff, Touchdown};

use crate::core::control::{Dir, ManualCommand};
use crate::core::model::GRAVITY_M_S2;
use std::fmt;

/// The vehicle's mode; [`Mode::name`] is what logs, the console and reports show.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Disarmed,
    Armed,
    Takeoff,
    Hold,
    Land,
    Kill,
}

impl Mode {
    pub fn name(self) -> &'static str {
        match self {
            Mode::Disarmed => "disarmed",
            Mode::Armed => "armed",
            Mode::Takeoff => "takeoff",
            Mode::Hold => "hold",
            Mode::Land => "land",
            Mode::Kill => "kill",
        }
    }

    /// The motors carry the vehicle (it may be off the ground).
    pub fn airborne(self) -> bool {
        matches!(self, Mode::Takeoff | Mode::Hold | Mode::Land)
    }
}

/// An operator's command: the same words from stdin, the console and the ground station.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    Arm,
    /// Climb to this height, m (default: the profile's hover height).
    Takeoff(Option<f64>),
    /// Hover here (x, y, z), m (default: where the vehicle is).
    Hold(Option<[f64; 3]>),
    Land,
    Disarm,
    Kill,
}

impl Command {
    /// Parses `arm`, `takeoff [ALT_M]`, `hold [X Y Z]`, `land`, `disarm`, `kill`.
    pub fn parse(line: &str) -> Result<Command, String> {
        let mut words = line.split_whitespace();
        let verb = words.next().unwrap_or("");
        let args: Vec<&str> = words.collect();
        let nums = args
            .iter()
            .map(|a| a.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| format!("{verb}: arguments must be finite numbers, got {args:?}"))?;
        match (verb, nums.as_slice()) {
            ("arm", []) => Ok(Command::Arm),
            ("takeoff", []) => Ok(Command::Takeoff(None)),
            ("takeoff", [alt]) if *alt > 0.0 => Ok(Command::Takeoff(Some(*alt))),
            ("takeoff", _) => Err("takeoff takes one height above 0 m, or none".into()),
            ("hold", []) => Ok(Command::Hold(None)),
            ("hold", [x, y, z]) => Ok(Command::Hold(Some([*x, *y, *z]))),
            ("hold", _) => Err("hold takes X Y Z in metres, or nothing".into()),
            ("land", []) => Ok(Command::Land),
            ("disarm", []) => Ok(Command::Disarm),
            ("kill", []) => Ok(Command::Kill),
            ("arm" | "land" | "disarm" | "kill", _) => Err(format!("{verb} takes no arguments")),
            _ => Err(format!(
                "unknown command {verb:?}: arm, takeoff [ALT_M], hold [X Y Z], land, disarm, kill"
            )),
        }
    }

    /// `line` starts with a command word (not manual keys, though `hold` is made of keys).
    pub fn is_word(line: &str) -> bool {
        let verb = line.split_whitespace().next().unwrap_or("");
        ["arm", "takeoff", "hold", "land", "disarm", "kill"].contains(&verb)
    }

    pub fn word(self) -> &'static str {
        match self {
            Command::Arm => "arm",
            Command::Takeoff(_) => "takeoff",
            Command::Hold(_) => "hold",
            Command::Land => "land",
            Command::Disarm => "disarm",
            Command::Kill => "kill",
        }
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Command::Takeoff(Some(a)) => write!(f, "takeoff {a}"),
            Command::Hold(Some([x, y, z])) => write!(f, "hold {x} {y} {z}"),
            c => f.write_str(c.word()),
        }
    }
}

/// Where an operator's input came from; which sources keep the link alive is configurable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkSource {
    /// The terminal `fly` runs in (ssh).
    Terminal,
    /// An attached `uquad console`.
    Console,
    /// A ground station (and the simulator's scripted operator, which stands for one).
    Gcs,
}

impl LinkSource {
    pub const ALL: [LinkSource; 3] = [LinkSource::Terminal, LinkSource::Console, LinkSource::Gcs];

    pub fn name(self) -> &'static str {
        match self {
            LinkSource::Terminal => "terminal",
            LinkSource::Console => "console",
            LinkSource::Gcs => "gcs",
        }
    }

    pub fn from_name(s: &str) -> Option<LinkSource> {
        LinkSource::ALL.into_iter().find(|l| l.name() == s)
    }
}

/// What a failsafe does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    Land,
    Hold,
    Kill,
}

impl Action {
    pub fn name(self) -> &'static str {
        match self {
            Action::Land => "land",
            Action::Hold => "hold",
            Action::Kill => "kill",
        }
    }
}

/// The graded failsafes; the watchdog's causes stay halts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failsafe {
    LinkLoss,
    GpsLoss,
    Geofence,
    Estimator,
}

impl Failsafe {
    pub fn name(self) -> &'static str {
        match self {
            Failsafe::LinkLoss => "link-loss",
            Failsafe::GpsLoss => "gps-loss",
            Failsafe::Geofence => "geofence",
            Failsafe::Estimator => "estimator",
        }
    }
}

/// How the commander starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Start {
    /// Wait for `arm` (every modern stack).
    Disarmed,
    /// Arm and take off at start with a step set point, as the original did.
    Flying,
}

/// The commander's parameters (`commander.*`, `failsafe.*`, `fence.*`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    pub start: Start,
    /// The default takeoff height, m.
    pub hover_z_m: f64,
    pub climb_m_s: f64,
    pub climb_acc_m_s2: f64,
    /// Takeoff ends (→ hold) once the estimate is this close to the target, m.
    pub takeoff_tolerance_m: f64,
    pub land_m_s: f64,
    /// Descent speed in the last metre, m/s.
    pub land_slow_m_s: f64,
    /// Touchdown: vertical speed under this, thrust under `touchdown_thrust` of hover, for
    /// `touchdown_s`.
    pub touchdown_v_m_s: f64,
    pub touchdown_thrust: f64,
    pub touchdown_s: f64,
    /// Which link sources count, by [`LinkSource`] order.
    pub link_sources: [bool; 3],
    pub link_timeout_s: f64,
    pub link_action: Action,
    /// A fix older than this is lost (the controller lets position hold go too), s.
    pub gps_timeout_s: f64,
    pub gps_loss_land_s: f64,
    pub gps_loss_action: Action,
    pub fence_radius_m: f64,
    pub fence_alt_max_m: f64,
    pub fence_action: Action,
    pub ekf_bad_s: f64,
    pub ekf_action: Action,
    /// The manual altitude keys' bounds, m.
    pub z_min_m: f64,
    pub z_max_m: f64,
}

/// The checks that must pass before arming, as the driver observed them; the first failing
/// one is named in the refusal.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ArmFacts {
    /// The IMU frames arrive at a stable period (settled).
    pub imu_stable: bool,
    /// GPS is required (gps.mode = "gpsd"); then the newest fix's horizontal error, m (None:
    /// no fix, or one without an error estimate).
    pub gps_required: bool,
    pub gps_eph_m: Option<f64>,
    pub gps_max_eph_m: f64,
    /// Why the log folder cannot be written, if it cannot.
    pub log_error: Option<String>,
    /// Real-time priority held, or waived (`--allow-no-rt`, the simulator).
    pub realtime: bool,
    /// The ESC addresses that did not acknowledge the last probe.
    pub esc_silent: Vec<u8>,
}

impl ArmFacts {
    /// The first failing check, named.
    pub fn verdict(&self) -> Result<(), String> {
        if !self.imu_stable {
            return Err("imu: frames are not arriving at a stable period yet".into());
        }
        if self.gps_required {
            match self.gps_eph_m {
                None => return Err("gps: no fix with a horizontal error estimate".into()),
                Some(e) if e > self.gps_max_eph_m => {
                    return Err(format!(
                        "gps: horizontal error {e:.1} m above commander.gps_max_eph_m = {} m",
                        self.gps_max_eph_m
                    ));
                }
                Some(_) => {}
            }
        }
        if let Some(e) = &self.log_error {
            return Err(format!("log: {e}"));
        }
        if !self.realtime {
            return Err(
                "realtime: SCHED_FIFO not held (run as the service or use --allow-no-rt)".into(),
            );
        }
        if !self.esc_silent.is_empty() {
            let a: Vec<String> = self
                .esc_silent
                .iter()
                .map(|a| format!("0x{a:02x}"))
                .collect();
            return Err(format!("esc: no acknowledgement from {}", a.join(", ")));
        }
        Ok(())
    }
}

/// What the commander reports; the flight turns these into records.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    Mode {
        t_us: i64,
        mode: Mode,
        why: String,
    },
    Failsafe {
        t_us: i64,
        kind: Failsafe,
        action: Action,
    },
    Refusal {
        t_us: i64,
        command: String,
        why: String,
    },
}

/// What became of a manual key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KeyOutcome {
    /// Not the commander's: the planner applies it.
    Planner,
    /// The hold's target height is now this, m above the takeoff point.
    Moved(f64),
    OutOfBounds,
    /// Only a hold's height moves.
    Ignored(Mode),
}

/// What the commander asks of the ESCs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EscRequest {
    /// Enable and run the start-up ramp (armed).
    Start,
    /// Zero, then disable (disarmed on the ground).
    Stop,
    /// The watchdog's halt (kill).
    Kill,
}

/// One Kalman step as the commander sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    pub t_us: i64,
    pub pos_m: [f64; 3],
    /// Vertical speed, up positive, m/s.
    pub vz_m_s: f64,
    /// Thrust of the last command over the weight.
    pub thrust_ratio: f64,
    /// The accelerometer's specific force along the body's vertical, m/s².
    pub acc_z_m_s2: f64,
    /// A GPS fix was fused in this step.
    pub gps_fused: bool,
    /// The largest innovation test ratio of this step (above 1: rejected).
    pub test_ratio_max: f64,
}

/// What the controller does this step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Guidance {
    pub mode: Mode,
    /// The control law runs (takeoff, hold, land); otherwise the motors idle (armed) or stop.
    pub fly: bool,
    /// The set point: position, m, and vertical speed, m/s.
    pub pos_m: [f64; 3],
    pub vz_m_s: f64,
    /// Hold the horizontal position (false: attitude only, as without GPS).
    pub hold_xy: bool,
    /// The height above the takeoff point the vehicle is sent to, m.
    pub height_m: f64,
}

impl Guidance {
    /// No control law: the motors are not the controller's.
    pub const OFF: Guidance = Guidance {
        mode: Mode::Disarmed,
        fly: false,
        pos_m: [0.0; 3],
        vz_m_s: 0.0,
        hold_xy: false,
        height_m: 0.0,
    };
}

/// What the commander did in a run, for its report.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    pub events: Vec<Event>,
    /// `fly`: the estimate's figures; `sim`: the true vehicle's.
    pub figures: Figures,
}

/// The ground's push felt at touchdown: the accelerometer reads at least this share of the
/// weight more than the thrust gives.
const GROUND_PUSH: f64 = 0.1;

/// A takeoff spools the motors up on the ground (the flight ramp, 100 steps) before its set
/// point climbs: a climb begun earlier leaves the vehicle behind it, and the integrators wind
/// up while it catches up (an overshoot).
const SPOOL_UP_STEPS: u32 = crate::core::motor::FLIGHT_RAMP_STEPS;

/// A landing is slow over this last height, m.
const LAST_METRE_M: f64 = 1.0;

/// The share of the acceleration limit the profile brakes with.
const BRAKE_SHARE: f64 = 0.9;

/// The vertical set point's profile: speed and acceleration limited, ends at rest.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Profile {
    z_m: f64,
    vz_m_s: f64,
}

impl Profile {
    /// Moves toward `target_m` by `dt_s` with speed ≤ `v_max`, acceleration ≤ `a_max`, braking
    /// in time to stop at the target.
    fn advance(&mut self, target_m: f64, v_max: f64, a_max: f64, dt_s: f64) {
        let dist = target_m - self.z_m;
        // Braking on a curve a little gentler than the limit, so that the limited
        // deceleration can follow it.
        let v_brake = (2.0 * BRAKE_SHARE * a_max * dist.abs()).sqrt();
        let v_want = dist.signum() * v_max.min(v_brake);
        let dv_max = a_max * dt_s;
        self.vz_m_s += (v_want - self.vz_m_s).clamp(-dv_max, dv_max);
        let step = self.vz_m_s * dt_s;
        // Never past the target: there, the last of the speed decays within the limit.
        if (dist - step) * dist <= 0.0 {
            self.z_m = target_m;
        } else {
            self.z_m += step;
        }
    }
}

/// The commander's state.
#[derive(Debug, Clone)]
pub struct Commander {
    p: Params,
    mode: Mode,
    /// Where the takeoff started (the ground and the fence's centre), m.
    home_m: Option<[f64; 3]>,
    target_m: [f64; 3],
    hold_xy: bool,
    profile: Profile,
    last_t_us: Option<i64>,
    link_seen_us: Option<i64>,
    last_fix_us: Option<i64>,
    gps_lost_us: Option<i64>,
    ekf_bad_since_us: Option<i64>,
    touchdown_since_us: Option<i64>,
    /// Failsafes recorded, and those whose action was taken (once each per run, so the
    /// operator can choose another mode afterwards).
    fired: Vec<Failsafe>,
    acted: Vec<Failsafe>,
    /// Disarmed after a flight: the ESCs cannot be started again in this run.
    spent: bool,
    /// The takeoff's overshoot and the touchdown, on the estimate.
    climb: ClimbTrace,
    descent: DescentTrace,
    touchdown: Option<Touchdown>,
    /// Steps since the takeoff began (its spool-up).
    takeoff_steps: u32,
}

impl Commander {
    pub fn new(p: Params) -> Self {
        Commander {
            p,
            mode: Mode::Disarmed,
            home_m: None,
            target_m: [0.0, 0.0, p.hover_z_m],
            hold_xy: true,
            profile: Profile {
                z_m: 0.0,
                vz_m_s: 0.0,
            },
            last_t_us: None,
            link_seen_us: None,
            last_fix_us: None,
            gps_lost_us: None,
            ekf_bad_since_us: None,
            touchdown_since_us: None,
            fired: Vec::new(),
            acted: Vec::new(),
            spent: false,
            climb: ClimbTrace::default(),
            descent: DescentTrace::default(),
            touchdown: None,
            takeoff_steps: 0,
        }
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    pub fn params(&self) -> &Params {
        &self.p
    }

    pub fn figures(&self) -> Figures {
        Figures {
            takeoff: self.climb.takeoff(),
            touchdown: self.touchdown,
        }
    }

    /// Where the vehicle is sent (x, y, z), m.
    pub fn target_m(&self) -> [f64; 3] {
        self.target_m
    }

    /// The start: `flying` arms at once (its refusals are the driver's, at start-up).
    pub fn start(&mut self, t_us: i64, out: &mut Vec<Event>) -> Option<EscRequest> {
        self.set_mode(Mode::Disarmed, t_us, "start", out);
        if self.p.start == Start::Flying {
            self.set_mode(Mode::Armed, t_us, "commander.start = flying", out);
            return Some(EscRequest::Start);
        }
        None
    }

    fn set_mode(&mut self, mode: Mode, t_us: i64, why: &str, out: &mut Vec<Event>) {
        self.mode = mode;
        out.push(Event::Mode {
            t_us,
            mode,
            why: why.to_string(),
        });
    }

    fn refuse(&self, cmd: Command, t_us: i64, why: String, out: &mut Vec<Event>) {
        out.push(Event::Refusal {
            t_us,
            command: cmd.to_string(),
            why,
        });
    }

    /// A link source was heard from.
    pub fn link_beat(&mut self, source: LinkSource, t_us: i64) {
        if self.p.link_sources[source as usize] {
            self.link_seen_us = Some(t_us);
        }
    }

    /// An operator's command at `t_us`; `arm_verdict` is the pre-arm checks' (only `arm`
    /// reads it). `est` is the newest estimate, if any.
    pub fn command(
        &mut self,
        cmd: Command,
        t_us: i64,
        arm_verdict: Result<(), String>,
        est: Option<&Observation>,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        match self.check(cmd, arm_verdict, est) {
            Err(why) => {
                self.refuse(cmd, t_us, why, out);
                None
            }
            Ok(()) => self.accept(cmd, t_us, est, out),
        }
    }

    /// Why `cmd` cannot be done now, if it cannot.
    fn check(
        &self,
        cmd: Command,
        arm_verdict: Result<(), String>,
        est: Option<&Observation>,
    ) -> Result<(), String> {
        let m = self.mode;
        match cmd {
            Command::Kill => Ok(()),
            _ if m == Mode::Kill => Err("killed: restart uquad to fly again".into()),
            Command::Arm if m != Mode::Disarmed => Err(format!("already {}", m.name())),
            Command::Arm if self.spent => Err("landed: restart uquad to fly again".into()),
            Command::Arm => arm_verdict,
            Command::Disarm if m.airborne() => {
                Err(format!("in the air ({}): land first, or kill", m.name()))
            }
            Command::Disarm if m == Mode::Disarmed => Err("already disarmed".into()),
            Command::Disarm => Ok(()),
            Command::Takeoff(_) if m != Mode::Armed => {
                Err(format!("{}: takeoff needs armed", m.name()))
            }
            Command::Takeoff(_) => match est {
                None => Err("estimator: not running yet (the IMU calibration is not done)".into()),
                Some(o) if o.test_ratio_max > 1.0 => Err(format!(
                    "estimator: innovation test ratio {:.2} above 1",
                    o.test_ratio_max
                )),
                Some(_) => Ok(()),
            },
            Command::Hold(_) | Command::Land if !m.airborne() => {
                Err(format!("{}: not in the air", m.name()))
            }
            Command::Hold(_) | Command::Land => Ok(()),
        }
    }

    fn accept(
        &mut self,
        cmd: Command,
        t_us: i64,
        est: Option<&Observation>,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let why = format!("command {cmd}");
        match cmd {
            Command::Arm => {
                self.set_mode(Mode::Armed, t_us, &why, out);
                Some(EscRequest::Start)
            }
            Command::Disarm => {
                self.disarm(t_us, &why, out);
                Some(EscRequest::Stop)
            }
            Command::Kill => Some(EscRequest::Kill),
            Command::Takeoff(alt) => {
                let o = est?;
                self.begin_takeoff(o, alt.unwrap_or(self.p.hover_z_m), t_us, &why, out);
                None
            }
            Command::Hold(at) => {
                let here = est.map_or(self.target_m, |o| o.pos_m);
                self.target_m = at.unwrap_or(here);
                self.set_mode(Mode::Hold, t_us, &why, out);
                None
            }
            Command::Land => {
                self.begin_land(est, t_us, &why, out);
                None
            }
        }
    }

    /// Lands where the vehicle is: flying back to the hold point while descending tilts it
    /// hard (and a fence breach is better not crossed again).
    fn begin_land(
        &mut self,
        est: Option<&Observation>,
        t_us: i64,
        why: &str,
        out: &mut Vec<Event>,
    ) {
        if self.mode == Mode::Land {
            return;
        }
        if let Some(o) = est {
            self.target_m[0] = o.pos_m[0];
            self.target_m[1] = o.pos_m[1];
        }
        self.set_mode(Mode::Land, t_us, why, out);
    }

    fn disarm(&mut self, t_us: i64, why: &str, out: &mut Vec<Event>) {
        self.spent = true;
        self.set_mode(Mode::Disarmed, t_us, why, out);
    }

    fn begin_takeoff(
        &mut self,
        o: &Observation,
        alt_m: f64,
        t_us: i64,
        why: &str,
        out: &mut Vec<Event>,
    ) {
        let home = self.p.start == Start::Flying;
        // The original's start: the set point is the hover point at once, over (0, 0).
        let ground = if home { [0.0, 0.0, 0.0] } else { o.pos_m };
        self.home_m = Some(ground);
        self.target_m = [ground[0], ground[1], ground[2] + alt_m];
        self.profile = Profile {
            z_m: if home { self.target_m[2] } else { ground[2] },
            vz_m_s: 0.0,
        };
        self.climb.begin(ground[2], alt_m);
        self.takeoff_steps = 0;
        self.set_mode(Mode::Takeoff, t_us, why, out);
    }

    /// The watchdog halted the motors.
    pub fn on_halt(&mut self, t_us: i64, reason: &str, out: &mut Vec<Event>) {
        if self.mode != Mode::Kill {
            self.set_mode(Mode::Kill, t_us, reason, out);
        }
    }

    /// The ESCs stopped on their own (their ramp failed): nothing spins.
    pub fn on_esc_stopped(&mut self, t_us: i64, why: &str, out: &mut Vec<Event>) {
        if self.mode != Mode::Disarmed && self.mode != Mode::Kill {
            self.disarm(t_us, why, out);
        }
    }

    /// A manual key: the altitude keys move the hold's target height (spec 5.2's step, within
    /// `control.manual.z_min_m`..`z_max_m` above the takeoff point); the others are the
    /// planner's.
    pub fn manual(&mut self, cmd: ManualCommand) -> KeyOutcome {
        let ManualCommand::Altitude(d) = cmd else {
            return KeyOutcome::Planner;
        };
        if self.mode != Mode::Hold {
            return KeyOutcome::Ignored(self.mode);
        }
        let step = crate::core::control::MANUAL_Z_STEP_M * if d == Dir::Up { 1.0 } else { -1.0 };
        let ground = self.home_m.map_or(0.0, |h| h[2]);
        let height_m = self.target_m[2] + step - ground;
        if height_m < self.p.z_min_m - 1e-12 || height_m > self.p.z_max_m + 1e-12 {
            return KeyOutcome::OutOfBounds;
        }
        self.target_m[2] += step;
        KeyOutcome::Moved(height_m)
    }

    /// One Kalman step: timers, failsafes, the profiles, touchdown. The guidance is `None`
    /// while the motors are not the controller's (disarmed, killed).
    pub fn on_estimate(
        &mut self,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> (Guidance, Option<EscRequest>) {
        let dt_s = self
            .last_t_us
            .map_or(0.01, |t| (o.t_us - t) as f64 / 1e6)
            .clamp(0.0, 0.1);
        self.last_t_us = Some(o.t_us);
        if o.gps_fused {
            self.last_fix_us = Some(o.t_us);
        }
        if self.p.start == Start::Flying && self.mode == Mode::Armed && self.home_m.is_none() {
            let alt = self.p.hover_z_m;
            self.begin_takeoff(o, alt, o.t_us, "commander.start = flying", out);
        }
        let request = if self.mode.airborne() {
            self.failsafes(o, out)
        } else {
            None
        };
        let request = request.or_else(|| self.fly(o, dt_s, out));
        self.climb.sample(self.mode, o.pos_m[2], o.vz_m_s);
        (self.guidance(), request)
    }

    pub fn guidance(&self) -> Guidance {
        let p = &self.profile;
        Guidance {
            mode: self.mode,
            fly: self.mode.airborne(),
            pos_m: [self.target_m[0], self.target_m[1], p.z_m],
            vz_m_s: p.vz_m_s,
            hold_xy: self.hold_xy,
            height_m: self.target_m[2] - self.home_m.map_or(0.0, |h| h[2]),
        }
    }

    /// The set point's profile for the mode, and the mode's end.
    fn fly(&mut self, o: &Observation, dt_s: f64, out: &mut Vec<Event>) -> Option<EscRequest> {
        let p = self.p;
        match self.mode {
            Mode::Takeoff => {
                self.takeoff_steps = self.takeoff_steps.saturating_add(1);
                if self.takeoff_steps > SPOOL_UP_STEPS {
                    self.profile
                        .advance(self.target_m[2], p.climb_m_s, p.climb_acc_m_s2, dt_s);
                }
                let reached = self.profile.z_m == self.target_m[2]
                    && (o.pos_m[2] - self.target_m[2]).abs() <= p.takeoff_tolerance_m;
                if reached {
                    self.set_mode(Mode::Hold, o.t_us, "takeoff height reached", out);
                }
                None
            }
            Mode::Hold => {
                self.profile
                    .advance(self.target_m[2], p.climb_m_s, p.climb_acc_m_s2, dt_s);
                None
            }
            Mode::Land => self.land(o, dt_s, out),
            _ => None,
        }
    }

    /// Descend, slower in the last metre, until touchdown; then zero and disable.
    fn land(&mut self, o: &Observation, dt_s: f64, out: &mut Vec<Event>) -> Option<EscRequest> {
        let p = self.p;
        let ground = self.home_m.map_or(0.0, |h| h[2]);
        let height = o.pos_m[2] - ground;
        // Slow from high enough to be at the slow speed by the last metre.
        let brake_m = (p.land_m_s.powi(2) - p.land_slow_m_s.powi(2)).max(0.0)
            / (2.0 * BRAKE_SHARE * p.climb_acc_m_s2);
        let v = if height > LAST_METRE_M + brake_m {
            p.land_m_s
        } else {
            p.land_slow_m_s
        };
        // Aim below the ground so the set point keeps pressing down until touchdown.
        let floor = ground - 2.0;
        self.profile.advance(floor, v, p.climb_acc_m_s2, dt_s);
        // Still: the estimate's vertical speed is near zero, or the accelerometer feels more
        // than the thrust gives (the ground's push). The second is needed because the filter's
        // model has no ground: with the thrust under the weight, its estimate keeps falling
        // after the vehicle has stopped on the ground.
        let ground_push = o.acc_z_m_s2 > (o.thrust_ratio + GROUND_PUSH) * GRAVITY_M_S2;
        let still = o.vz_m_s.abs() < p.touchdown_v_m_s || ground_push;
        let resting = still && o.thrust_ratio < p.touchdown_thrust;
        match (resting, self.touchdown_since_us) {
            (false, _) => {
                self.touchdown_since_us = None;
                self.descent.sample(o.t_us, o.vz_m_s);
            }
            (true, None) => self.touchdown_since_us = Some(o.t_us),
            (true, Some(t0)) if (o.t_us - t0) as f64 / 1e6 >= p.touchdown_s => {
                let home = self.home_m.unwrap_or(o.pos_m);
                self.touchdown = Some(Touchdown {
                    t_us: o.t_us,
                    v_m_s: self.descent.peak_m_s(),
                    from_takeoff_m: (o.pos_m[0] - home[0]).hypot(o.pos_m[1] - home[1]),
                });
                self.disarm(o.t_us, "touchdown", out);
                return Some(EscRequest::Stop);
            }
            (true, Some(_)) => {}
        }
        None
    }

    /// The graded failsafes, in the air.
    fn failsafes(&mut self, o: &Observation, out: &mut Vec<Event>) -> Option<EscRequest> {
        let t = o.t_us;
        let secs = |since: i64| (t - since) as f64 / 1e6;
        let p = self.p;
        let link_lost = self
            .link_seen_us
            .is_some_and(|s| secs(s) > p.link_timeout_s);
        if link_lost {
            return self.fire(Failsafe::LinkLoss, p.link_action, o, out);
        }
        let gps_stale = self.last_fix_us.is_some_and(|s| secs(s) > p.gps_timeout_s);
        self.hold_xy = !gps_stale;
        if gps_stale {
            // Attitude and altitude are held at once; the action comes after a grace time.
            let since = *self.gps_lost_us.get_or_insert(t);
            self.record(Failsafe::GpsLoss, p.gps_loss_action, t, out);
            if secs(since) >= p.gps_loss_land_s && !self.acted.contains(&Failsafe::GpsLoss) {
                self.acted.push(Failsafe::GpsLoss);
                return self.act(p.gps_loss_action, Failsafe::GpsLoss, o, out);
            }
        } else {
            self.gps_lost_us = None;
        }
        if !gps_stale && self.last_fix_us.is_some() && self.outside_fence(o) {
            return self.fire(Failsafe::Geofence, p.fence_action, o, out);
        }
        let bad = o.test_ratio_max > 1.0;
        let since = if bad {
            *self.ekf_bad_since_us.get_or_insert(t)
        } else {
            t
        };
        if !bad {
            self.ekf_bad_since_us = None;
        }
        if bad && secs(since) >= p.ekf_bad_s {
            return self.fire(Failsafe::Estimator, p.ekf_action, o, out);
        }
        None
    }

    fn outside_fence(&self, o: &Observation) -> bool {
        let Some(h) = self.home_m else {
            return false;
        };
        let r = (o.pos_m[0] - h[0]).hypot(o.pos_m[1] - h[1]);
        r > self.p.fence_radius_m || o.pos_m[2] - h[2] > self.p.fence_alt_max_m
    }

    /// Records a failsafe the first time it fires in this run.
    fn record(&mut self, kind: Failsafe, action: Action, t_us: i64, out: &mut Vec<Event>) {
        if !self.fired.contains(&kind) {
            self.fired.push(kind);
            out.push(Event::Failsafe { t_us, kind, action });
        }
    }

    /// A failsafe fires and its action is taken, once per run: the operator may then choose
    /// another mode.
    fn fire(
        &mut self,
        kind: Failsafe,
        action: Action,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        if self.acted.contains(&kind) {
            return None;
        }
        self.acted.push(kind);
        self.record(kind, action, o.t_us, out);
        self.act(action, kind, o, out)
    }

    fn act(
        &mut self,
        action: Action,
        kind: Failsafe,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let (t_us, why) = (o.t_us, format!("failsafe {}", kind.name()));
        match action {
            Action::Kill => return Some(EscRequest::Kill),
            Action::Land => self.begin_land(Some(o), t_us, &why, out),
            Action::Hold if self.mode != Mode::Hold => self.set_mode(Mode::Hold, t_us, &why, out),
            _ => {}
        }
        None
    }
}

/// One input from the operator's side, as the flight applies and records it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OperatorInput {
    Command(Command, LinkSource),
    Beat(LinkSource),
    Key(ManualCommand),
}

impl OperatorInput {
    /// One line an operator typed (stdin, a console): a command word with its arguments,
    /// `quit` (or `esc`), or manual keys (spec 5.2: `e` raises the set point; `eee` three
    /// times). Empty lines give nothing.
    pub fn parse_line(line: &str, source: LinkSource) -> Result<Vec<OperatorInput>, String> {
        let line = line.trim();
        if line.is_empty() {
            return Ok(Vec::new());
        }
        if line == "quit" || line == "esc" {
            return Ok(vec![OperatorInput::Key(ManualCommand::Quit)]);
        }
        let keys: Option<Vec<OperatorInput>> = line
            .bytes()
            .map(|b| ManualCommand::from_key(b).map(OperatorInput::Key))
            .collect();
        match keys {
            Some(k) if !Command::is_word(line) => Ok(k),
            _ => Command::parse(line).map(|c| vec![OperatorInput::Command(c, source)]),
        }
    }
}

#[cfg(test)]
mod tests;
