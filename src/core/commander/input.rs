//! The operator's words: the commander's commands (`arm`, `takeoff [ALT_M]`, `hold [X Y Z]`,
//! `land`, `disarm`, `kill`, the stick modes `position` and `altitude`, and for missions
//! `start`, `pause`, `resume`, `return`), where an
//! input came from (the link sources the `link-loss` failsafe counts), a typed line as
//! inputs, a ground station's uploaded mission, and what became of a manual key (spec 5.2).

use super::Mode;
use crate::core::control::ManualCommand;
use std::fmt;

/// An operator's command: the same words from stdin, the console and the ground station.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    Arm,
    /// Climb to this height, m (default: the profile's hover height).
    Takeoff(Option<f64>),
    /// Hover here: (x, y) from the takeoff point and z above it, m (default: where the vehicle
    /// is).
    Hold(Option<[f64; 3]>),
    Land,
    Disarm,
    Kill,
    /// Fly the loaded mission (from the ground: its takeoff first).
    Start,
    /// Hold where the mission has got to.
    Pause,
    /// Go on with a paused mission.
    Resume,
    /// Fly back above the takeoff point, then land.
    Return,
    /// The sticks fly (`position`, `altitude`): in the air at once; on the ground the mode
    /// a raised throttle takes off into.
    Sticks(super::StickMode),
    /// In `hold`, move the hold point to (x, y) from the takeoff point and z above it, m
    /// (refused in any other mode): a companion computer's position target.
    Move([f64; 3]),
    /// Calibrate the IMU at rest again (the gyros' offsets and the level), disarmed on the
    /// ground: a ground station's preflight calibration.
    Calibrate,
    /// Spin one motor alone, disarmed on the ground: motor 1–4 (m0–m3 of the motor map) at
    /// a throttle in % of the ESC's range above idle, for a time in s (a ground station's
    /// motor test; `disarm` ends it early).
    MotorTest {
        motor: u8,
        throttle_pct: f64,
        duration_s: f64,
    },
}

impl Command {
    /// Parses `arm`, `takeoff [ALT_M]`, `hold [X Y Z]`, `land`, `disarm`, `kill`, `start`,
    /// `pause`, `resume`, `return`, `position`, `altitude`, `calibrate`, `move X Y Z`,
    /// `motor M PCT S`.
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
            ("start", []) => Ok(Command::Start),
            ("pause", []) => Ok(Command::Pause),
            ("resume", []) => Ok(Command::Resume),
            ("return", []) => Ok(Command::Return),
            ("position", []) => Ok(Command::Sticks(super::StickMode::Position)),
            ("altitude", []) => Ok(Command::Sticks(super::StickMode::Altitude)),
            ("calibrate", []) => Ok(Command::Calibrate),
            ("move", [x, y, z]) => Ok(Command::Move([*x, *y, *z])),
            ("move", _) => Err("move takes X Y Z in metres".into()),
            ("motor", [m, pct, s]) if m.fract() == 0.0 && (0.0..=255.0).contains(m) => {
                Ok(Command::MotorTest {
                    motor: *m as u8,
                    throttle_pct: *pct,
                    duration_s: *s,
                })
            }
            ("motor", _) => Err("motor takes MOTOR (1-4) THROTTLE_PCT SECONDS".into()),
            (
                "arm" | "land" | "disarm" | "kill" | "start" | "pause" | "resume" | "return"
                | "calibrate" | "position" | "altitude",
                _,
            ) => Err(format!("{verb} takes no arguments")),
            _ => Err(format!(
                "unknown command {verb:?}: arm, takeoff [ALT_M], hold [X Y Z], land, disarm, \
                 kill, start, pause, resume, return, position, altitude, calibrate, move X Y Z, \
                 motor M PCT S"
            )),
        }
    }

    /// `line` starts with a command word (not manual keys, though `hold` is made of keys).
    pub fn is_word(line: &str) -> bool {
        let verb = line.split_whitespace().next().unwrap_or("");
        [
            "arm",
            "takeoff",
            "hold",
            "land",
            "disarm",
            "kill",
            "start",
            "pause",
            "resume",
            "return",
            "position",
            "altitude",
            "calibrate",
            "move",
            "motor",
        ]
        .contains(&verb)
    }

    pub fn word(self) -> &'static str {
        match self {
            Command::Arm => "arm",
            Command::Takeoff(_) => "takeoff",
            Command::Hold(_) => "hold",
            Command::Land => "land",
            Command::Disarm => "disarm",
            Command::Kill => "kill",
            Command::Start => "start",
            Command::Pause => "pause",
            Command::Resume => "resume",
            Command::Return => "return",
            Command::Sticks(m) => m.name(),
            Command::Calibrate => "calibrate",
            Command::Move(_) => "move",
            Command::MotorTest { .. } => "motor",
        }
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Command::Takeoff(Some(a)) => write!(f, "takeoff {a}"),
            Command::Hold(Some([x, y, z])) => write!(f, "hold {x} {y} {z}"),
            Command::Move([x, y, z]) => write!(f, "move {x} {y} {z}"),
            Command::MotorTest {
                motor,
                throttle_pct,
                duration_s,
            } => write!(f, "motor {motor} {throttle_pct} {duration_s}"),
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
    /// The pilot's radio (`rc.*`): not a link of `failsafe.link_sources` (its loss is
    /// `rc-loss`).
    Rc,
}

impl LinkSource {
    pub const ALL: [LinkSource; 3] = [LinkSource::Terminal, LinkSource::Console, LinkSource::Gcs];

    pub fn name(self) -> &'static str {
        match self {
            LinkSource::Terminal => "terminal",
            LinkSource::Console => "console",
            LinkSource::Gcs => "gcs",
            LinkSource::Rc => "rc",
        }
    }

    /// A link of `failsafe.link_sources` by its name.
    pub fn from_name(s: &str) -> Option<LinkSource> {
        LinkSource::ALL.into_iter().find(|l| l.name() == s)
    }

    /// Any source by its name (mode.log's), the pilot's radio too.
    pub fn from_any_name(s: &str) -> Option<LinkSource> {
        LinkSource::from_name(s).or((s == "rc").then_some(LinkSource::Rc))
    }
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

/// One input from the operator's side, as the flight applies and records it.
#[derive(Debug, Clone, PartialEq)]
pub enum OperatorInput {
    Command(Command, LinkSource),
    Beat(LinkSource),
    Key(ManualCommand),
    /// A ground station's mission, its gains designed: it replaces the loaded one.
    Mission(std::sync::Arc<crate::core::mission::MissionPlan>),
    /// The GPS receiver delivered a fix (gps.mode = "gpsd"): not the operator's, but an input
    /// of the commander's like a link's beat, recorded so that a replay judges the same.
    GpsFix,
    /// The ESCs finished the start-up ramp an `arm` began, under a running estimate
    /// (`imu.calibrate = "before-arm"`): the motors idle, a takeoff may follow. The
    /// actuator's, recorded so that a replay (which has no ESCs) sees it at the same step.
    EscsRunning,
    /// The pilot's radio (`core::rc::link`): its kill switch and sticks, or its receiver's
    /// failsafe; each report says the receiver is heard.
    Rc(super::RcReport),
    /// A ground station's joystick (MANUAL_CONTROL): roll, pitch, yaw, throttle, each −1…1
    /// (throttle −1 low); the sticks while no radio is heard.
    Sticks([f64; 4]),
    /// A ground station's change of a parameter that takes effect in flight
    /// ([`super::IN_FLIGHT`]), checked and kept by the link: applied between two steps.
    Param {
        key: &'static str,
        value: f64,
    },
    /// An input that waited `waited_us` for the flight, longer than
    /// `commander.input_expiry_s` (the IMU silent, the flight stalled): refused, never
    /// applied, and recorded so that a replay refuses it too.
    Expired {
        input: Box<OperatorInput>,
        waited_us: i64,
    },
}

impl OperatorInput {
    /// Whether the input is the operator's asking (a command, a key, a mission, a joystick's
    /// sticks), which is
    /// refused once stale; a link's beat and a fix are facts of their arrival and never are.
    pub fn expires(&self) -> bool {
        matches!(
            self,
            OperatorInput::Command(..)
                | OperatorInput::Key(_)
                | OperatorInput::Mission(_)
                | OperatorInput::Sticks(_)
        )
    }

    /// An `arm` or a motor test: checked against what the driver observes (the pre-arm
    /// checks; the ESCs answering).
    pub fn checked_against_facts(&self) -> bool {
        matches!(
            self,
            OperatorInput::Command(Command::Arm | Command::MotorTest { .. }, _)
        )
    }

    /// What a refusal of this input names: the command, the key or the mission.
    pub fn what(&self) -> String {
        match self {
            OperatorInput::Command(c, _) => c.to_string(),
            OperatorInput::Key(k) => format!("key {}", char::from(k.key())),
            OperatorInput::Mission(plan) => format!("mission {}", plan.name),
            OperatorInput::Beat(src) => format!("beat {}", src.name()),
            OperatorInput::GpsFix => "fix".into(),
            OperatorInput::EscsRunning => "escs running".into(),
            OperatorInput::Param { key, .. } => format!("param {key}"),
            OperatorInput::Rc(_) => "rc".into(),
            OperatorInput::Sticks(_) => "sticks".into(),
            OperatorInput::Expired { input, .. } => input.what(),
        }
    }

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
