//! The simulated operator: a script of commands at simulated times (`uquad sim --script`) and
//! the link heartbeats of the ground station it stands for, which `--inject link-loss@T`
//! silences; without a script (`none`) there is no simulated operator and no heartbeat. Both
//! ways of simulating read it.

use crate::core::commander::{Command, LinkSource, OperatorInput};
use crate::sim::transmitter::RcMove;
use std::collections::VecDeque;

/// The whole cycle, as `uquad sim` flies it without `--script`: arm once the estimator check
/// can pass (the default profile calibrates at rest by 5.7 s, the check passes by 6.2 s on
/// every seed), take off once the ESCs' ramp is done (2.4 s), hover, land.
pub const DEFAULT_SCRIPT: &str = "arm@7,takeoff@10,land@45";

/// With a mission: arm, then `start` (its takeoff, its items, its landing).
pub const MISSION_SCRIPT: &str = "arm@7,start@10";

/// Both for a profile that calibrates after the arm (`imu.calibrate = "after-arm"`): arm once
/// settled, take off or start once the ESCs' ramp and the calibration are done (about 8.5 s).
pub const DEFAULT_SCRIPT_AFTER_ARM: &str = "arm@2,takeoff@10,land@45";
pub const MISSION_SCRIPT_AFTER_ARM: &str = "arm@2,start@10";

/// Heartbeat period of the simulated ground station, µs.
pub const BEAT_PERIOD_US: i64 = 1_000_000;

/// Commands at simulated times, in time order; and the pilot's moves of a simulated radio
/// transmitter (`sticks`, `switch`), in time order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Script(pub Vec<(i64, Command)>, pub Vec<(i64, RcMove)>);

impl Script {
    /// Parses `COMMAND@T,...` (T in simulated seconds; a command may carry its arguments:
    /// `takeoff 1.5@10`; the pilot's moves too: `switch arm on@8`), or `none`.
    pub fn parse(text: &str) -> Result<Script, String> {
        if text.trim() == "none" {
            return Ok(Script::default());
        }
        let (mut items, mut moves) = (Vec::new(), Vec::new());
        for item in text.split(',') {
            let (word, at) = item.rsplit_once('@').ok_or_else(|| {
                format!("{item:?}: expected COMMAND@T, e.g. arm@7,takeoff@10,land@45, or none")
            })?;
            let t_s = crate::config::parse_fault_time_s(at)
                .map_err(|e| format!("{item:?}: the time {e}"))?;
            let t_us = (t_s * 1e6).round() as i64;
            match RcMove::parse(word) {
                Some(m) => moves.push((t_us, m.map_err(|e| format!("{item:?}: {e}"))?)),
                None => {
                    let cmd = Command::parse(word).map_err(|e| format!("{item:?}: {e}"))?;
                    items.push((t_us, cmd));
                }
            }
        }
        items.sort_by_key(|(t, _)| *t);
        moves.sort_by_key(|(t, _)| *t);
        Ok(Script(items, moves))
    }

    /// When the last command or move is due, µs.
    pub fn end_us(&self) -> Option<i64> {
        let last = |v: &[(i64, _)]| v.last().map(|(t, _)| *t);
        last(&self.0).max(self.1.last().map(|(t, _)| *t))
    }
}

/// The operator's inputs as simulated time passes.
#[derive(Debug, Clone)]
pub struct SimOperator {
    script: VecDeque<(i64, Command)>,
    /// When the pilot's last move of the radio is due (the transmitter makes them), µs.
    moves_end_us: Option<i64>,
    next_beat_us: i64,
    /// `link-loss`: no heartbeats (and no commands) from this time on.
    silent_from_us: Option<i64>,
    /// Without a script there is no simulated operator: no heartbeats either (a real ground
    /// station or console may be the link).
    present: bool,
    /// A ground station or a console may fly the vehicle too (`--realtime`, `--mode paced`).
    links: bool,
}

impl SimOperator {
    pub fn new(script: &Script, silent_from_us: Option<i64>) -> Self {
        SimOperator {
            script: script.0.iter().copied().collect(),
            moves_end_us: script.1.last().map(|(t, _)| *t),
            next_beat_us: BEAT_PERIOD_US,
            silent_from_us,
            present: !script.0.is_empty() || !script.1.is_empty(),
            links: false,
        }
    }

    /// A ground station or a console may fly the vehicle too.
    pub fn with_links(mut self) -> Self {
        self.links = true;
        self
    }

    /// Every command of the script was sent (or the link went silent for good): a landing
    /// after it ends the run. With links and no script (`none`) never: a ground station or a
    /// console flies the vehicle, as many flights as it likes, until `--duration` or a
    /// signal.
    pub fn done(&self, t_us: i64) -> bool {
        let moved = self.moves_end_us.is_none_or(|end| t_us >= end);
        (self.present || !self.links) && (self.script.is_empty() && moved || self.silent(t_us))
    }

    fn silent(&self, t_us: i64) -> bool {
        self.silent_from_us.is_some_and(|s| t_us >= s)
    }

    /// The inputs due by `t_us`, in order, with when each was due, into `out`.
    pub fn due(&mut self, t_us: i64, out: &mut Vec<(i64, OperatorInput)>) {
        if !self.present || self.silent(t_us) {
            return;
        }
        if t_us >= self.next_beat_us {
            out.push((self.next_beat_us, OperatorInput::Beat(LinkSource::Gcs)));
            self.next_beat_us += BEAT_PERIOD_US;
        }
        while let Some(&(at, cmd)) = self.script.front()
            && at <= t_us
        {
            self.script.pop_front();
            out.push((at, OperatorInput::Command(cmd, LinkSource::Gcs)));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scripts_parse_with_arguments_and_in_time_order() {
        let s = Script::parse("land@45,arm@2,takeoff 1.5@10").unwrap();
        assert_eq!(
            s.0,
            vec![
                (2_000_000, Command::Arm),
                (10_000_000, Command::Takeoff(Some(1.5))),
                (45_000_000, Command::Land),
            ]
        );
        assert_eq!(Script::parse("none").unwrap(), Script::default());
        assert!(Script::parse("arm").unwrap_err().contains("COMMAND@T"));
        assert!(Script::parse("fly@2").is_err());
        assert!(Script::parse("arm@-1").is_err());
    }

    #[test]
    fn beats_each_second_until_the_link_is_lost() {
        let mut op = SimOperator::new(&Script::parse("arm@2").unwrap(), Some(3_500_000));
        let mut got = Vec::new();
        for t_ms in (0..=5000).step_by(10) {
            op.due(t_ms * 1000, &mut got);
        }
        let beats = got
            .iter()
            .filter(|(_, i)| matches!(i, OperatorInput::Beat(_)))
            .count();
        assert_eq!(beats, 3, "{got:?}");
        // Each with the time it was due, not when it was asked for.
        let arm = OperatorInput::Command(Command::Arm, LinkSource::Gcs);
        assert!(got.contains(&(2_000_000, arm)), "{got:?}");
        assert!(got.contains(&(1_000_000, OperatorInput::Beat(LinkSource::Gcs))));
        assert!(op.done(4_000_000));
    }

    #[test]
    fn no_script_is_no_operator_and_no_heartbeat() {
        let mut op = SimOperator::new(&Script::default(), None);
        let mut got = Vec::new();
        for t_ms in (0..=5000).step_by(10) {
            op.due(t_ms * 1000, &mut got);
        }
        assert!(got.is_empty(), "{got:?}");
    }
}
