//! A ground station's commands: the link's own requests answered at once; the commander's
//! queued for the flight and acknowledged once the commander has taken or refused them; a
//! sender that may not command denied.

use super::{Connection, Window};
use crate::core::commander::{Command, LinkSource, Mode, OperatorInput};
use crate::gcs::commands::{self, Args, Refusal, Request};
use mavlink::dialects::common::*;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The flight takes its operator queue at every IMU frame (10 ms); an outcome that has not
/// come within this never will (the flight has ended): the command is acknowledged FAILED.
pub const OUTCOME_TIMEOUT: Duration = Duration::from_secs(5);
/// Commands taken from the link each second, as from the console and stdin.
pub const COMMANDS_PER_S: u64 = 20;
/// Commander's commands waiting for their outcome at most (beyond: refused).
pub const PENDING_MAX: usize = 64;

/// A command sent on to the commander, waiting for its outcome.
struct Pending {
    command: Command,
    mav_cmd: MavCmd,
    from: (u8, u8),
    at: Instant,
}

/// The commands' state: those waiting for the flight, and the second's count.
pub(super) struct Commands {
    pending: VecDeque<Pending>,
    window: Window,
}

impl Commands {
    pub(super) fn new(now: Instant) -> Self {
        Commands {
            pending: VecDeque::new(),
            window: Window::new(now),
        }
    }

    /// When the oldest waiting command times out.
    pub(super) fn next_expiry(&self) -> Option<Instant> {
        self.pending.front().map(|p| p.at + OUTCOME_TIMEOUT)
    }
}

impl Connection {
    pub(super) fn on_command(&mut self, now: Instant, cmd: MavCmd, args: Args, from: (u8, u8)) {
        self.counts.commands += 1;
        match commands::map(cmd, args).and_then(|r| self.in_context(cmd, args, r)) {
            Ok(Request::Commander(c)) => self.forward_command(now, c, cmd, from),
            Ok(Request::Message(id)) => {
                // REQUEST_MESSAGE's param 2: which one of a listed message (AVAILABLE_MODES'
                // mode index; 0: all).
                let index = if cmd == MavCmd::MAV_CMD_REQUEST_MESSAGE {
                    args.p[1]
                } else {
                    0.0
                };
                let result = self.send_by_id(now, id, index);
                self.ack(cmd, result, from);
            }
            Ok(Request::Interval {
                msg_id,
                interval_us,
            }) => {
                let result = self.streams.set_interval(now, msg_id, interval_us);
                self.ack(cmd, result, from);
            }
            // An unsupported command is only acknowledged so: ground stations probe with
            // them, and a text for each would drown the ones that matter.
            Err((MavResult::MAV_RESULT_UNSUPPORTED, _)) => {
                self.counts.commands_refused += 1;
                self.ack(cmd, MavResult::MAV_RESULT_UNSUPPORTED, from);
            }
            Err((result, why)) => self.refuse(cmd, result, &why, from),
        }
    }

    /// A request read in the vehicle's situation, where the same words mean different things:
    /// a NAV_TAKEOFF's param 7 given above sea level (PX4's clients: the ground's altitude
    /// plus the height) or above the takeoff point (ArduPilot's); a hold asked for as a mode
    /// while a mission flies (PX4's pause), the Mission mode asked for while one is paused
    /// (PX4's resume).
    fn in_context(&self, cmd: MavCmd, args: Args, r: Request) -> Result<Request, Refusal> {
        let mode_request = matches!(
            cmd,
            MavCmd::MAV_CMD_DO_SET_MODE | MavCmd::MAV_CMD_DO_SET_STANDARD_MODE
        );
        let c = match r {
            Request::Commander(c) => c,
            other => return Ok(other),
        };
        let c = match c {
            Command::Takeoff(Some(h))
                if cmd == MavCmd::MAV_CMD_NAV_TAKEOFF && args.frame.is_none() =>
            {
                Command::Takeoff(Some(self.takeoff_height(h)?))
            }
            Command::Hold(None) if mode_request && self.status.mode == Mode::Mission => {
                Command::Pause
            }
            Command::Start if mode_request && self.mission_paused() => Command::Resume,
            c => c,
        };
        Ok(Request::Commander(c))
    }

    /// NAV_TAKEOFF's param 7 as a height above the takeoff point: as it is, or, when the
    /// ground's altitude above sea level is known and only the difference is a height a
    /// takeoff may go to, that difference. Both readings possible (a site near sea level):
    /// refused, rather than guessed.
    fn takeoff_height(&self, p7: f64) -> Result<f64, Refusal> {
        let (lo, hi) = self.s.takeoff_heights_m;
        let height = |h: f64| (lo..=hi).contains(&h);
        let Some(ground) = self.ground_alt_m else {
            return Ok(p7);
        };
        let above_ground = p7 - ground;
        match (height(p7), height(above_ground)) {
            (true, true) => Err((
                MavResult::MAV_RESULT_DENIED,
                format!(
                    "takeoff {p7} m: a height above the takeoff point, or an altitude {:.1} m \
                     above the ground here ({ground:.1} m above sea level)? Send NaN for the \
                     profile's height, or COMMAND_INT in a relative frame",
                    above_ground
                ),
            )),
            (false, true) => Ok(above_ground),
            _ => Ok(p7),
        }
    }

    /// A mission is paused where it got to (hold, its item kept).
    fn mission_paused(&self) -> bool {
        self.status.live.is_some_and(|l| {
            let flying = matches!(l.mode, Mode::Mission | Mode::Land);
            self.mission_status(l.mission_item, flying)
                .is_some_and(|m| m.state == MissionState::MISSION_STATE_PAUSED)
        })
    }

    fn ack(&mut self, cmd: MavCmd, result: MavResult, to: (u8, u8)) {
        let msg = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: cmd,
            result,
            target_system: to.0,
            target_component: to.1,
            ..COMMAND_ACK_DATA::DEFAULT
        });
        self.send(&msg);
    }

    fn refuse(&mut self, cmd: MavCmd, result: MavResult, why: &str, to: (u8, u8)) {
        self.counts.commands_refused += 1;
        self.ack(cmd, result, to);
        self.text(MavSeverity::MAV_SEVERITY_WARNING, why);
    }

    /// A command, a parameter set or a mission written by a sender that may not command:
    /// counted, answered DENIED addressed to it (a parameter set has no answer; the answer
    /// goes out on the link as every message does), with no text, and logged once in a
    /// hundred (a stranger's flood must not flood err.log).
    pub(super) fn deny_sender(&mut self, m: &MavMessage, from: (u8, u8)) {
        self.counts.senders_denied += 1;
        if self.counts.senders_denied % 100 == 1 {
            self.err_log(format!(
                "MAVLink system {} may not command (not a ground station, or not in \
                 gcs.allowed_systems): {} denied so far",
                from.0, self.counts.senders_denied
            ));
        }
        let denied = MavResult::MAV_RESULT_DENIED;
        #[allow(deprecated)]
        match m {
            MavMessage::COMMAND_LONG(c) => self.ack(c.command, denied, from),
            MavMessage::COMMAND_INT(c) => self.ack(c.command, denied, from),
            MavMessage::SET_MODE(_) => self.ack(MavCmd::MAV_CMD_DO_SET_MODE, denied, from),
            MavMessage::PARAM_SET(_) => {}
            _ => self.mission_deny(from),
        }
    }

    /// A commander's command: queued for the flight, acknowledged once it is taken or
    /// refused (the refusal's reason arrives as the commander's own text).
    fn forward_command(&mut self, now: Instant, c: Command, cmd: MavCmd, from: (u8, u8)) {
        let busy = MavResult::MAV_RESULT_TEMPORARILY_REJECTED;
        if !self.commands.window.allows(now, 1, COMMANDS_PER_S) {
            let why = format!("{c} refused: more than {COMMANDS_PER_S} commands a second");
            return self.refuse(cmd, busy, &why, from);
        }
        if self.commands.pending.len() >= PENDING_MAX {
            let why = format!("{c} refused: {PENDING_MAX} commands already wait for the flight");
            return self.refuse(cmd, busy, &why, from);
        }
        self.operator
            .push_back(OperatorInput::Command(c, LinkSource::Gcs));
        self.commands.pending.push_back(Pending {
            command: c,
            mav_cmd: cmd,
            from,
            at: now,
        });
    }

    /// The flight's queue could not take command `c`: the newest such command waiting is
    /// refused at once.
    pub(super) fn command_not_taken(&mut self, c: Command) {
        let Some(i) = self.commands.pending.iter().rposition(|p| p.command == c) else {
            return;
        };
        let Some(p) = self.commands.pending.remove(i) else {
            return;
        };
        let busy = MavResult::MAV_RESULT_TEMPORARILY_REJECTED;
        let why = format!("{c} refused: the flight is not taking commands now");
        self.refuse(p.mav_cmd, busy, &why, p.from);
    }

    /// The commander took or refused a command of this link: its acknowledgement.
    pub(super) fn on_outcome(&mut self, command: Command, refused: bool) {
        let Some(i) = self
            .commands
            .pending
            .iter()
            .position(|p| p.command == command)
        else {
            return;
        };
        let Some(p) = self.commands.pending.remove(i) else {
            return;
        };
        let result = if refused {
            self.counts.commands_refused += 1;
            MavResult::MAV_RESULT_DENIED
        } else {
            MavResult::MAV_RESULT_ACCEPTED
        };
        self.ack(p.mav_cmd, result, p.from);
    }

    pub(super) fn expire_pending(&mut self, now: Instant) {
        while let Some(p) = self
            .commands
            .pending
            .pop_front_if(|p| now.saturating_duration_since(p.at) >= OUTCOME_TIMEOUT)
        {
            let why = format!("{}: no answer from the flight", p.command);
            self.refuse(p.mav_cmd, MavResult::MAV_RESULT_FAILED, &why, p.from);
        }
    }
}
