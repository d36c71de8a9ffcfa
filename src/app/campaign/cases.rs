//! The safety campaign's runs: three scripted flights (a hover, a mission, a return), the
//! phases of a flight as windows of simulated time in them, and every fault struck in every
//! phase alone and in pairs; each run drawn from its seed, and written as the `uquad sim`
//! command line that reruns it.

use crate::core::gps::SplitMix64;
use crate::sim::faults::Fault;
use std::path::Path;

/// A scripted flight the faults strike into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flight {
    /// Arm, take off to 1 m, hold, land (the main job's cycle).
    Hover,
    /// Arm, then the mission (`--mission`): its takeoff, legs and landing.
    Mission,
    /// Arm, take off, fly 6 m out, `return`.
    Return,
}

/// When every flight's script takes off (`takeoff@10`, `start@10`), s.
pub const TAKEOFF_S: f64 = 10.0;

impl Flight {
    pub fn script(self) -> &'static str {
        match self {
            Flight::Hover => "arm@7,takeoff@10,land@45",
            Flight::Mission => "arm@7,start@10",
            Flight::Return => "arm@7,takeoff@10,hold 6 0 1@14,return@24",
        }
    }
}

/// A phase of the flight: where a fault strikes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phase {
    pub name: &'static str,
    pub flight: Flight,
    /// The window of simulated time, s, the strike is drawn from (the default profile's
    /// start-up: settled at 0.5 s, calibrated at rest by 5.7 s, armed at 7 s, the ESCs'
    /// ramp until 9.4 s).
    pub from_s: f64,
    pub to_s: f64,
}

/// Every phase, in flight order.
pub const PHASES: [Phase; 9] = [
    phase("calibration", Flight::Hover, 0.6, 5.6),
    phase("disarmed", Flight::Hover, 5.8, 6.9),
    phase("esc-ramp", Flight::Hover, 7.1, 9.2),
    phase("armed-ground", Flight::Hover, 9.5, 9.95),
    phase("takeoff", Flight::Hover, 10.05, 13.9),
    phase("hold", Flight::Hover, 14.5, 44.5),
    phase("mission-leg", Flight::Mission, 17.0, 75.0),
    phase("return", Flight::Return, 24.2, 37.5),
    phase("landing", Flight::Hover, 45.2, 48.8),
];

const fn phase(name: &'static str, flight: Flight, from_s: f64, to_s: f64) -> Phase {
    Phase {
        name,
        flight,
        from_s,
        to_s,
    }
}

/// What a run strikes: one fault or two, in one phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Case {
    pub phase: Phase,
    pub faults: (Fault, Option<Fault>),
}

/// The faults a campaign strikes: every one but `rc-loss` (the campaign's profile flies
/// without a radio, on which it does nothing).
fn campaign_faults() -> Vec<Fault> {
    Fault::NAMES
        .iter()
        .map(|&(_, f)| f)
        .filter(|&f| f != Fault::RcLoss)
        .collect()
}

/// Every case: each fault alone in each phase, then each pair of faults in each phase.
pub fn cases() -> Vec<Case> {
    let faults = campaign_faults();
    let mut out = Vec::new();
    for phase in PHASES {
        for &f in &faults {
            out.push(Case {
                phase,
                faults: (f, None),
            });
        }
    }
    for phase in PHASES {
        for (i, &a) in faults.iter().enumerate() {
            for &b in &faults[i + 1..] {
                out.push(Case {
                    phase,
                    faults: (a, Some(b)),
                });
            }
        }
    }
    out
}

/// One run: a case, its seed and the strike times drawn from it.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub case: Case,
    pub seed: u64,
    /// Each fault and when it strikes, s (whole milliseconds, so the command line is exact).
    pub inject: Vec<(Fault, f64)>,
}

impl Run {
    /// The run `index` of a campaign seeded with `seed`: the cases in turn, a seed each.
    pub fn nth(cases: &[Case], index: u64, seed: u64) -> Run {
        let case = cases[(index % cases.len() as u64) as usize];
        let run_seed = seed.wrapping_add(index) & (u64::MAX >> 1);
        let mut rng = SplitMix64::new(run_seed ^ 0xca3f_a161);
        let mut strike = || {
            let u = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
            let t_s = case.phase.from_s + u * (case.phase.to_s - case.phase.from_s);
            (t_s * 1000.0).round() / 1000.0
        };
        let mut inject = vec![(case.faults.0, strike())];
        if let Some(b) = case.faults.1 {
            inject.push((b, strike()));
        }
        Run {
            case,
            seed: run_seed,
            inject,
        }
    }

    /// The faults' names, joined by `+`.
    pub fn fault_names(&self) -> String {
        match self.case.faults {
            (a, None) => a.name().to_string(),
            (a, Some(b)) => format!("{}+{}", a.name(), b.name()),
        }
    }

    /// The command line that reruns it.
    pub fn command_line(&self, config: &Path, sets: &[String], mission: &Path) -> String {
        let mut s = format!("uquad sim --fast --config {}", config.display());
        for set in sets {
            s += &format!(" --set '{set}'");
        }
        s += &format!(
            " --seed {} --script '{}'",
            self.seed,
            self.case.phase.flight.script()
        );
        if self.case.phase.flight == Flight::Mission {
            s += &format!(" --mission {}", mission.display());
        }
        for (f, t_s) in &self.inject {
            s += &format!(" --inject {}@{t_s}", f.name());
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_flight_takes_off_at_takeoff_s() {
        let at = format!("@{TAKEOFF_S}");
        for flight in [Flight::Hover, Flight::Mission, Flight::Return] {
            let script = flight.script();
            let takeoff = script
                .split(',')
                .find(|w| w.starts_with("takeoff") || w.starts_with("start"));
            assert!(takeoff.is_some_and(|w| w.ends_with(&at)), "{script}");
        }
    }

    #[test]
    fn every_fault_in_every_phase_alone_and_in_pairs() {
        let all = cases();
        let n = campaign_faults().len();
        assert_eq!(all.len(), PHASES.len() * (n + n * (n - 1) / 2));
        let r = Run::nth(&all, all.len() as u64 + 3, 7);
        assert_eq!(
            r.case, all[3],
            "the cases come round again with other seeds"
        );
        assert_eq!(r.seed, 7 + all.len() as u64 + 3);
        for i in 0..all.len() as u64 {
            let r = Run::nth(&all, i, 1);
            for (_, t_s) in &r.inject {
                assert!(*t_s >= r.case.phase.from_s - 1e-3 && *t_s <= r.case.phase.to_s + 1e-3);
            }
            assert_eq!(r.inject.len(), 1 + usize::from(r.case.faults.1.is_some()));
        }
    }

    #[test]
    fn the_command_line_names_everything_the_run_used() {
        let all = cases();
        let pair = all.iter().position(|c| c.faults.1.is_some()).unwrap_or(0);
        let r = Run::nth(&all, pair as u64, 5);
        let line = r.command_line(Path::new("c.toml"), &["a.b=1".into()], Path::new("m.toml"));
        assert!(line.starts_with("uquad sim --fast --config c.toml --set 'a.b=1' --seed "));
        assert_eq!(line.matches("--inject").count(), 2, "{line}");
        assert!(line.contains(r.case.phase.flight.script()), "{line}");
    }
}
