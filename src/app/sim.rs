//! What both ways of simulating share: their options and the choice between them.

use crate::sim::faults::Fault;
use std::path::PathBuf;

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
    /// The simulated operator's commands (None: the profile's default, [`default_script`]).
    pub script: Option<crate::sim::operator::Script>,
}

/// The operator's script of a simulation: the given one, else the whole cycle for a vehicle
/// that starts disarmed (arm, then `start` with a mission) and none for one that starts flying
/// (the original's way).
pub fn script(opts: &SimOptions, profile: &crate::config::Profile) -> crate::sim::operator::Script {
    use crate::sim::operator::{
        DEFAULT_SCRIPT, DEFAULT_SCRIPT_AFTER_ARM, MISSION_SCRIPT, MISSION_SCRIPT_AFTER_ARM, Script,
    };
    let at_rest = profile.config.calibrates_before_arm();
    let default = match (profile.mission.is_some(), at_rest) {
        (true, true) => MISSION_SCRIPT,
        (true, false) => MISSION_SCRIPT_AFTER_ARM,
        (false, true) => DEFAULT_SCRIPT,
        (false, false) => DEFAULT_SCRIPT_AFTER_ARM,
    };
    match (&opts.script, profile.config.commander.start) {
        (Some(s), _) => s.clone(),
        (None, crate::core::commander::Start::Flying) => Script::default(),
        (None, crate::core::commander::Start::Disarmed) => {
            Script::parse(default).unwrap_or_default()
        }
    }
}

/// Simulated seconds: the given, else `sim.duration_s`, else for a mission long enough to fly
/// it twice over (the run ends at its touchdown anyway).
pub fn duration_s(opts: &SimOptions, profile: &crate::config::Profile) -> f64 {
    let configured = profile.config.sim.duration_s;
    match (opts.duration_s, &profile.mission) {
        (Some(d), _) => d,
        (None, Some(m)) => configured.max(10.0 + 60.0 + 2.0 * m.nominal_s),
        (None, None) => configured,
    }
}

/// The ways of flying the real code against the models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SimMode {
    /// The flight's state machines in lock-step with the physics on a simulated clock.
    #[default]
    Fast,
    /// `fly`'s own tasks and threads against the simulated edges, on the wall clock.
    Realtime,
    /// The lock-step flight paced to the wall clock, a ground station and the console served.
    Paced,
}
