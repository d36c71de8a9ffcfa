//! Controller task: hover planner, P + I controller, flight ramp and saturation.
//!
//! In: estimates from the estimator; manual-mode commands (stdin keys, console).
//! Out: motor commands to the ESC writer; feedback (the next EKF input) to the estimator;
//! `w` and `int` records.
//! Rate: one control step per estimate (100 Hz). Ends: when the estimator ends (on cancel or
//! a quit command, which cancels), after the estimates it already sent.

use crate::core::control::{ManualCommand, ManualOutcome};
use crate::core::flight::ControllerCore;
use crate::tasks::esc_writer::{EscMailbox, MotorCommand};
use crate::tasks::estimator::{EstimateMsg, Feedback};
use crate::tasks::logger::{LogHub, Record};
use std::sync::Arc;
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
    pub core: ControllerCore,
    pub estimates: mpsc::Receiver<EstimateMsg>,
    pub manual: mpsc::Receiver<ManualCommand>,
    pub feedback: watch::Sender<Feedback>,
    pub esc: Arc<EscMailbox>,
    pub logs: LogHub,
    pub cancel: CancellationToken,
    /// Fault injection: from this step on, each control step takes this long.
    pub delay: Option<(u32, std::time::Duration)>,
    /// The newest estimate, command and set point, for the console.
    pub live: watch::Sender<Option<Live>>,
}

/// What the console shows of the running flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Live {
    pub step: u32,
    pub x: [f64; 15],
    pub w_rad_s: [f64; 4],
    pub setpoint_z_m: f64,
}

impl ControllerTask {
    pub async fn run(mut self) -> ControllerReport {
        let mut rep = ControllerReport::default();
        self.feedback.send_replace(Feedback {
            step: 0,
            u_next: self.core.input_for_step(1),
            mass_kg: self.core.mass_kg(),
            t_cmd_us: None,
        });
        let mut position_hold = false;
        // Ends when the estimator does (it drops its sender on cancel), after the estimates
        // already sent: every step the estimator logged is also controlled and logged here.
        while let Some(msg) = self.estimates.recv().await {
            while let Ok(cmd) = self.manual.try_recv() {
                rep.manual_commands += 1;
                match self.core.apply_manual(cmd) {
                    Some(ManualOutcome::Quit) => {
                        self.logs.err("manual quit: stopping");
                        tracing::info!("manual quit");
                        self.cancel.cancel();
                    }
                    Some(o) => {
                        let sp = self.core.planner().map(|p| p.sp.x);
                        self.logs
                            .err(format!("manual {cmd:?}: {o:?}; set point {sp:?}"));
                    }
                    None => self
                        .logs
                        .err(format!("manual {cmd:?} ignored before flight")),
                }
            }
            let est = &msg.est;
            if let Some((from, d)) = self.delay
                && est.step >= from
            {
                tokio::time::sleep(d).await;
            }
            // Control and command times are the frame's stamp: what the replay consumes.
            let c = self.core.control(est, est.t_us, est.t_us);
            if c.position_hold != position_hold {
                position_hold = c.position_hold;
                let msg = self.core.position_hold_message(position_hold);
                tracing::info!("{msg}");
                self.logs.err(msg);
            }
            self.esc.command(MotorCommand {
                w_rad_s: c.w_sent,
                frame_at: msg.frame_at,
            });
            self.feedback.send_replace(Feedback {
                step: c.step,
                u_next: self.core.input_for_step(c.step + 1),
                mass_kg: self.core.mass_kg(),
                t_cmd_us: Some(c.t_cmd_us),
            });
            self.live.send_replace(Some(Live {
                step: c.step,
                x: est.x.into(),
                w_rad_s: c.w_sent,
                setpoint_z_m: self.core.planner().map_or(0.0, |p| p.sp.x[2]),
            }));
            rep.steps += 1;
            rep.saturated += u64::from(c.saturated);
            self.logs.log(Record::Int(c.t_ctrl_us, c.x_int, c.n_int));
            self.logs.log(Record::W(c.t_cmd_us, c.w_sent));
        }
        rep
    }
}
