//! Controller task: carries estimates into the flight sequence's controller side and its motor
//! commands to the ESC writer; what a step computes is decided by `core::flight::sequence`.
//!
//! In: estimates from the estimator; manual-mode commands (stdin keys, console).
//! Out: motor commands to the ESC writer; feedback (the next EKF input) to the estimator;
//! `w` and `int` records; the newest step for the console.
//! Rate: one control step per estimate (100 Hz). Ends: when the estimator ends (on cancel or
//! a quit command, which cancels), after the estimates it already sent.

use crate::core::flight::drive::hand_off;
use crate::core::flight::{Command, ControllerSide, Feedback};
use crate::tasks::TaskOutputs;
use crate::tasks::esc_writer::{EscMailbox, HaltOnPanic, MailboxEscs, MotorCommand};
use crate::tasks::estimator::EstimateMsg;
use crate::tasks::latency::Stamps;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// Counters of the controller.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ControllerReport {
    pub steps: u64,
    pub saturated: u64,
    pub manual_commands: u64,
}

pub struct ControllerTask {
    pub side: ControllerSide,
    pub estimates: mpsc::Receiver<EstimateMsg>,
    pub feedback: watch::Sender<Feedback>,
    pub esc: Arc<EscMailbox>,
    pub out: TaskOutputs,
    pub cancel: CancellationToken,
    /// Fault injection: from this step on, each control step takes this long.
    pub delay: Option<(u32, std::time::Duration)>,
    /// Fault injection (tests): the control step of this number panics.
    pub panic_at_step: Option<u32>,
    /// The newest estimate, command and set point, for the console and the simulator.
    pub live: watch::Sender<Option<Live>>,
}

pub use crate::core::status::Live;

impl ControllerTask {
    pub async fn run(mut self) -> ControllerReport {
        let _halt = HaltOnPanic {
            mailbox: self.esc.clone(),
            cancel: self.cancel.clone(),
        };
        self.feedback.send_replace(self.side.first_feedback());
        // Ends when the estimator does (it drops its sender on cancel), after the estimates
        // already sent: every step the estimator logged is also controlled and logged here.
        while let Some(msg) = self.estimates.recv().await {
            let est = &msg.est;
            if let Some((from, d)) = self.delay
                && est.step >= from
            {
                tokio::time::sleep(d).await;
            }
            if self.panic_at_step == Some(est.step) {
                panic!("injected controller panic at step {}", est.step);
            }
            let esc = &self.esc;
            let mut escs = MailboxEscs {
                esc,
                cancel: &self.cancel,
            };
            let send = |c: &Command| {
                if hand_off(c, &mut escs) {
                    esc.command(MotorCommand {
                        w_rad_s: c.w_rad_s,
                        stamps: Stamps {
                            decoded: msg.frame_at,
                            estimated: msg.estimated_at,
                            commanded: Instant::now(),
                        },
                    })
                }
            };
            let c = self.side.control(est, send, &mut self.out);
            self.feedback.send_replace(c.feedback);
            self.live.send_replace(Some(Live {
                step: c.step,
                x: est.x.into(),
                w_rad_s: c.w_rad_s,
                setpoint_m: self.side.setpoint_m().unwrap_or_default(),
                mode: est.guidance.mode,
                height_m: est.guidance.height_m,
                flying_steps: self.side.counts().flying_steps,
                ratios: est.ratios,
                home_m: est.guidance.home_m,
                mission_item: est.guidance.mission_item,
            }));
        }
        let c = self.side.counts();
        ControllerReport {
            steps: c.steps,
            saturated: c.saturated,
            manual_commands: c.manual_commands,
        }
    }
}
