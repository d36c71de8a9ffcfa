//! The pilot's radio as operator inputs (spec: none): each frame of channels read through the
//! map (`sticks`) and turned into what the commander takes, so that a replay of mode.log
//! flies the same: a report of the kill switch and the sticks when they change (and
//! [`REPORTS_PER_TIMEOUT`] times a timeout anyway: the receiver is heard), the arm switch's
//! moves as `arm` and
//! `disarm`, the mode switch's as the command of its new position, and the receiver's
//! failsafe as a loss. A switch found on at the first frame (or after a loss) is not a move:
//! it must go off and on again to arm.

use super::RcFrame;
use super::sticks::{RcInput, RcMap};
use crate::core::commander::{Command, LinkSource, OperatorInput, RcReport};

/// The receiver is reported heard at least this many times within `failsafe.rc_timeout_s`:
/// a frame or two lost in between is not a loss.
pub const REPORTS_PER_TIMEOUT: f64 = 2.5;

/// Sticks are reported to this resolution (a share of their half travel).
const STICK_STEP: f64 = 0.001;

/// What a position of the mode switch selects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RcMode {
    /// Sticks → horizontal velocity, climb rate and yaw rate; centred sticks hold the point.
    Position,
    /// Sticks → tilt and yaw rate, throttle → climb rate; no GPS needed.
    Altitude,
    Hold,
    Mission,
    Return,
    Land,
}

impl RcMode {
    pub fn name(self) -> &'static str {
        match self {
            RcMode::Position => "position",
            RcMode::Altitude => "altitude",
            RcMode::Hold => "hold",
            RcMode::Mission => "mission",
            RcMode::Return => "return",
            RcMode::Land => "land",
        }
    }

    /// The commander's command for this mode, where it has one.
    pub fn command(self) -> Option<Command> {
        match self {
            RcMode::Hold => Some(Command::Hold(None)),
            RcMode::Mission => Some(Command::Start),
            RcMode::Return => Some(Command::Return),
            RcMode::Land => Some(Command::Land),
            RcMode::Position | RcMode::Altitude => None,
        }
    }
}

/// Frames in, operator inputs out.
#[derive(Debug, Clone)]
pub struct RcLink {
    map: RcMap,
    modes: Vec<RcMode>,
    /// The previous frame as read (none at the start and after a loss).
    last: Option<RcInput>,
    /// The last report sent, and when.
    reported: Option<(RcReport, i64)>,
    lost: bool,
    /// An unchanged report is sent again this often, µs.
    report_period_us: i64,
}

impl RcLink {
    /// A link whose receiver's loss is judged after `timeout_s` of silence
    /// (`failsafe.rc_timeout_s`).
    pub fn new(map: RcMap, modes: Vec<RcMode>, timeout_s: f64) -> Self {
        RcLink {
            map,
            modes,
            last: None,
            reported: None,
            lost: false,
            report_period_us: (timeout_s / REPORTS_PER_TIMEOUT * 1e6).max(10_000.0) as i64,
        }
    }

    pub fn map(&self) -> &RcMap {
        &self.map
    }

    /// The mode switch's position that selects `mode`, if one does.
    pub fn position_of(&self, mode: RcMode) -> Option<usize> {
        self.modes.iter().position(|&m| m == mode)
    }

    /// A frame at `t_us`: the inputs it makes, appended to `out`. True when its kill switch
    /// has just turned on (the caller stops the motors at once, before the commander hears
    /// of it). A frame the receiver marks lost is not a frame of the pilot's.
    pub fn frame(&mut self, f: &RcFrame, t_us: i64, out: &mut Vec<OperatorInput>) -> bool {
        if f.failsafe {
            if !self.lost {
                self.lost = true;
                self.last = None;
                self.reported = None;
                out.push(OperatorInput::Rc(RcReport {
                    lost: true,
                    kill: false,
                    sticks: [0.0, 0.0, 0.0, -1.0],
                }));
            }
            return false;
        }
        if f.frame_lost {
            return false;
        }
        self.lost = false;
        let input = self.map.read(f);
        let q = |x: f64| (x / STICK_STEP).round() * STICK_STEP;
        let s = input.sticks;
        let report = RcReport {
            lost: false,
            kill: input.kill,
            sticks: [q(s.roll), q(s.pitch), q(s.yaw), q(s.throttle)],
        };
        let due = self
            .reported
            .is_none_or(|(r, at)| r != report || t_us - at >= self.report_period_us);
        let kill_edge = input.kill && self.last.is_some_and(|l| !l.kill);
        if due {
            self.reported = Some((report, t_us));
            out.push(OperatorInput::Rc(report));
        }
        if let Some(last) = self.last {
            self.moves(&last, &input, out);
        }
        self.last = Some(input);
        kill_edge
    }

    /// The switches' moves since `last` as commands.
    fn moves(&self, last: &RcInput, now: &RcInput, out: &mut Vec<OperatorInput>) {
        let rc = |c| OperatorInput::Command(c, LinkSource::Rc);
        if now.arm != last.arm {
            out.push(rc(if now.arm {
                Command::Arm
            } else {
                Command::Disarm
            }));
        }
        if now.mode != last.mode
            && let Some(c) = self.modes.get(now.mode).and_then(|m| m.command())
        {
            out.push(rc(c));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::rc::sticks::{ChannelCal, Sticks};

    fn link() -> RcLink {
        let cal = |channel, deadband| ChannelCal {
            channel,
            min: 172,
            center: 992,
            max: 1811,
            reversed: false,
            deadband,
        };
        let map = RcMap {
            roll: cal(1, 0.05),
            pitch: cal(2, 0.05),
            throttle: cal(3, 0.05),
            yaw: cal(4, 0.05),
            arm: cal(5, 0.0),
            kill: cal(6, 0.0),
            mode: cal(7, 0.0),
            mode_positions: 3,
        };
        RcLink::new(map, vec![RcMode::Position, RcMode::Hold, RcMode::Land], 0.5)
    }

    fn frame(l: &RcLink, arm: bool, kill: bool, mode: usize, throttle: f64) -> RcFrame {
        let input = RcInput {
            sticks: Sticks {
                throttle,
                ..Sticks::default()
            },
            arm,
            kill,
            mode,
        };
        RcFrame {
            channels: l.map().frame_for(&input),
            frame_lost: false,
            failsafe: false,
        }
    }

    fn commands(out: &[OperatorInput]) -> Vec<String> {
        out.iter()
            .filter_map(|i| match i {
                OperatorInput::Command(c, LinkSource::Rc) => Some(c.to_string()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn switches_move_the_commander_and_reports_keep_the_receiver_heard() {
        let mut l = link();
        let mut out = Vec::new();
        // On at the start: not a move.
        assert!(!l.frame(&frame(&l, true, false, 1, -1.0), 0, &mut out));
        assert_eq!(commands(&out), Vec::<String>::new());
        assert_eq!(out.len(), 1, "the first report");
        out.clear();
        l.frame(&frame(&l, true, false, 1, -1.0), 10_000, &mut out);
        assert!(out.is_empty(), "nothing changed, a report is not due");
        l.frame(&frame(&l, false, false, 1, -1.0), 20_000, &mut out);
        l.frame(&frame(&l, true, false, 1, -1.0), 30_000, &mut out);
        l.frame(&frame(&l, true, false, 2, -1.0), 40_000, &mut out);
        l.frame(&frame(&l, true, false, 0, -1.0), 50_000, &mut out);
        assert_eq!(
            commands(&out),
            ["disarm", "arm", "land"],
            "position has no command"
        );
        out.clear();
        l.frame(&frame(&l, true, false, 0, -1.0), 250_000, &mut out);
        assert_eq!(out.len(), 1, "a report every 0.2 s");
        out.clear();
        l.frame(&frame(&l, true, false, 0, 0.5), 260_000, &mut out);
        let OperatorInput::Rc(r) = out[0] else {
            panic!("{out:?}")
        };
        assert_eq!((r.kill, r.sticks[3]), (false, 0.5), "the throttle as sent");
        assert!(
            l.frame(&frame(&l, true, true, 0, 0.5), 270_000, &mut out),
            "kill"
        );
        assert!(
            !l.frame(&frame(&l, true, true, 0, 0.5), 280_000, &mut out),
            "once"
        );
    }

    #[test]
    fn the_receivers_failsafe_is_a_loss_and_the_switches_start_afresh_after_it() {
        let mut l = link();
        let mut out = Vec::new();
        l.frame(&frame(&l, false, false, 1, -1.0), 0, &mut out);
        let mut lost = frame(&l, false, false, 1, -1.0);
        lost.failsafe = true;
        l.frame(&lost, 10_000, &mut out);
        l.frame(&lost, 20_000, &mut out);
        let losses = out
            .iter()
            .filter(|i| matches!(i, OperatorInput::Rc(r) if r.lost))
            .count();
        assert_eq!(losses, 1);
        out.clear();
        // Back with the arm switch on: not an arm.
        l.frame(&frame(&l, true, false, 1, -1.0), 30_000, &mut out);
        assert_eq!(commands(&out), Vec::<String>::new());
        assert!(matches!(out[0], OperatorInput::Rc(r) if !r.lost));
        // A frame the receiver marks lost is no frame: no report, no move.
        out.clear();
        let mut dropped = frame(&l, false, false, 1, -1.0);
        dropped.frame_lost = true;
        l.frame(&dropped, 40_000, &mut out);
        assert!(out.is_empty());
    }
}
