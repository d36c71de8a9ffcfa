//! A ground station's commands: the link's own requests answered at once; the commander's
//! queued for the flight and acknowledged once the commander has taken or refused them.

use super::link::Link;
use super::state::{Gcs, Pending};
use crate::core::commander::{Command, LinkSource, OperatorInput};
use crate::gcs::commands::{self, Args, Request};
use mavlink::dialects::common::*;
use std::time::{Duration, Instant};

/// The flight takes its operator queue at every IMU frame (10 ms); an outcome that has not
/// come within this never will (the flight has ended): the command is acknowledged FAILED.
const OUTCOME_TIMEOUT: Duration = Duration::from_secs(5);
/// Commands taken from the link each second, as from the console and stdin.
const COMMANDS_PER_S: u64 = 20;
/// Commander's commands waiting for their outcome at most (beyond: refused).
const PENDING_MAX: usize = 64;

impl Gcs {
    pub(super) fn on_command(&mut self, cmd: MavCmd, args: Args, from: (u8, u8), link: &mut Link) {
        self.report.commands += 1;
        match commands::map(cmd, args) {
            Ok(Request::Commander(c)) => self.forward_command(c, cmd, from, link),
            Ok(Request::Message(id)) => {
                let result = self.send_by_id(id, link);
                self.ack(cmd, result, from, link);
            }
            Ok(Request::Interval {
                msg_id,
                interval_us,
            }) => {
                let result = self.set_interval(msg_id, interval_us);
                self.ack(cmd, result, from, link);
            }
            // An unsupported command is only acknowledged so: ground stations probe with
            // them, and a text for each would drown the ones that matter.
            Err((MavResult::MAV_RESULT_UNSUPPORTED, _)) => {
                self.report.commands_refused += 1;
                self.ack(cmd, MavResult::MAV_RESULT_UNSUPPORTED, from, link);
            }
            Err((result, why)) => self.refuse(cmd, result, &why, from, link),
        }
    }

    fn ack(&mut self, cmd: MavCmd, result: MavResult, to: (u8, u8), link: &mut Link) {
        let msg = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: cmd,
            result,
            target_system: to.0,
            target_component: to.1,
            ..COMMAND_ACK_DATA::DEFAULT
        });
        self.send(&msg, link);
    }

    fn refuse(&mut self, cmd: MavCmd, result: MavResult, why: &str, to: (u8, u8), link: &mut Link) {
        self.report.commands_refused += 1;
        self.ack(cmd, result, to, link);
        self.text(MavSeverity::MAV_SEVERITY_WARNING, why, link);
    }

    /// A command, a parameter set or a mission written by a sender that may not command:
    /// counted, answered DENIED addressed to it (a parameter set has no answer; the answer
    /// goes out on the link as every message does), with no text, and logged once in a
    /// hundred (a stranger's flood must not flood err.log).
    pub(super) fn deny_sender(&mut self, m: &MavMessage, from: (u8, u8), link: &mut Link) {
        self.report.senders_denied += 1;
        if self.report.senders_denied % 100 == 1 {
            self.ctx.store.logs.err(format!(
                "MAVLink system {} may not command (not a ground station, or not in \
                 gcs.allowed_systems): {} denied so far",
                from.0, self.report.senders_denied
            ));
        }
        let denied = MavResult::MAV_RESULT_DENIED;
        #[allow(deprecated)]
        match m {
            MavMessage::COMMAND_LONG(c) => self.ack(c.command, denied, from, link),
            MavMessage::COMMAND_INT(c) => self.ack(c.command, denied, from, link),
            MavMessage::SET_MODE(_) => self.ack(MavCmd::MAV_CMD_DO_SET_MODE, denied, from, link),
            MavMessage::PARAM_SET(_) => {}
            _ => self.mission_deny(from, link),
        }
    }

    /// A commander's command: queued for the flight, acknowledged once it is taken or
    /// refused (the refusal's reason arrives as the commander's own text).
    fn forward_command(&mut self, c: Command, cmd: MavCmd, from: (u8, u8), link: &mut Link) {
        let busy = MavResult::MAV_RESULT_TEMPORARILY_REJECTED;
        let now = Instant::now();
        if !self.commands.allows(now, 1, COMMANDS_PER_S) {
            let why = format!("{c} refused: more than {COMMANDS_PER_S} commands a second");
            return self.refuse(cmd, busy, &why, from, link);
        }
        if self.pending.len() >= PENDING_MAX {
            let why = format!("{c} refused: {PENDING_MAX} commands already wait for the flight");
            return self.refuse(cmd, busy, &why, from, link);
        }
        match self
            .ctx
            .operator
            .try_send(OperatorInput::Command(c, LinkSource::Gcs))
        {
            Ok(()) => self.pending.push_back(Pending {
                command: c,
                mav_cmd: cmd,
                from,
                at: now,
            }),
            Err(_) => {
                self.report.input_drops += 1;
                let why = format!("{c} refused: the flight is not taking commands now");
                self.refuse(cmd, busy, &why, from, link);
            }
        }
    }

    /// The commander took or refused a command of this link: its acknowledgement.
    pub(super) fn on_outcome(&mut self, command: Command, refused: bool, link: &mut Link) {
        let Some(i) = self.pending.iter().position(|p| p.command == command) else {
            return;
        };
        let Some(p) = self.pending.remove(i) else {
            return;
        };
        let result = if refused {
            self.report.commands_refused += 1;
            MavResult::MAV_RESULT_DENIED
        } else {
            MavResult::MAV_RESULT_ACCEPTED
        };
        self.ack(p.mav_cmd, result, p.from, link);
    }

    pub(super) fn expire_pending(&mut self, now: Instant, link: &mut Link) {
        while self
            .pending
            .front()
            .is_some_and(|p| now.duration_since(p.at) >= OUTCOME_TIMEOUT)
        {
            let Some(p) = self.pending.pop_front() else {
                break;
            };
            let why = format!("{}: no answer from the flight", p.command);
            self.refuse(p.mav_cmd, MavResult::MAV_RESULT_FAILED, &why, p.from, link);
        }
    }
}
