//! Estimator task: carries frames into the flight sequence's estimator side and its estimates
//! to the controller task. What happens to a frame (settle, ESC start, calibration, the Kalman
//! step, the GPS feed) is decided by `core::flight::sequence`; this task only moves messages.
//!
//! In: stamped frames from the IMU reader; the controller's [`Feedback`]; the ESC writer's
//! phase; the newest live GPS fix (gps.mode = gpsd).
//! Out: estimates to the controller; the ESC start request; `imu_raw`, `kalman_in`, `x_hat`,
//! `innov` and `gps` records; sanity events for the watchdog.
//! Rate: one Kalman step per frame once calibrated. Ends: when frames stop, on a start-up
//! abort (an error), or on cancel.

use crate::core::commander::Summary as CommanderSummary;
use crate::core::commander::{ArmFacts, Command, LinkSource, OperatorInput};
use crate::core::esc::EscPhase;
use crate::core::flight::{
    ArmCheck, EscState, Estimate, EstimatorSide, Feedback, FrameAction, FrameTimes, GatedCounts,
    OperatorAction, Phase,
};
use crate::core::gps::LiveFix;
use crate::tasks::TaskOutputs;
use crate::tasks::esc_writer::{EscMailbox, EscStatus};
use crate::tasks::imu_reader::StampedFrame;
use crate::tasks::notices::Notice;
use crate::tasks::prearm::PreArm;
use crate::tasks::watchdog::WatchdogStatus;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// An estimate on its way to the controller.
#[derive(Debug, Clone)]
pub struct EstimateMsg {
    pub est: Estimate,
    /// When the frame arrived and when its estimate was made (the latency's first stamps).
    pub frame_at: Instant,
    pub estimated_at: Instant,
}

/// After this long without the previous step's feedback the wait is counted as late (it still
/// waits: the EKF input must be the previous command, and a stuck controller is the
/// watchdog's to catch as a missed deadline).
const FEEDBACK_LATE: Duration = Duration::from_millis(5);

/// Counters of the estimator, and what its commander did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EstimatorReport {
    pub frames: u64,
    pub steps: u64,
    pub late_feedback: u64,
    pub ekf_errors: u64,
    pub gps_updates: u64,
    pub commander: CommanderSummary,
    /// Steps that left a measurement group out of their update.
    pub ekf_gated: GatedCounts,
}

pub struct EstimatorTask {
    pub side: EstimatorSide,
    /// Live fixes (gps.mode = gpsd).
    pub gps_live: Option<watch::Receiver<Option<LiveFix>>>,
    pub frames: mpsc::Receiver<StampedFrame>,
    pub feedback: watch::Receiver<Feedback>,
    pub estimates: mpsc::Sender<EstimateMsg>,
    pub esc: Arc<EscMailbox>,
    pub esc_status: Arc<EscStatus>,
    pub out: TaskOutputs,
    pub cancel: CancellationToken,
    /// The operator's commands, link beats and keys (stdin, consoles, a ground station).
    pub operator: mpsc::Receiver<OperatorInput>,
    pub prearm: PreArm,
    /// `fly --arm`: arm once the IMU has settled.
    pub auto_arm: bool,
    /// The watchdog's state: a halt ends the run, and the commander records its `kill`.
    pub watchdog: Arc<WatchdogStatus>,
    /// The newest live fix not yet offered to a Kalman step.
    pub pending_fix: Option<LiveFix>,
}

impl EstimatorTask {
    pub async fn run(mut self) -> anyhow::Result<EstimatorReport> {
        let mut late_feedback = 0;
        loop {
            let f = tokio::select! {
                _ = self.cancel.cancelled() => break,
                f = self.frames.recv() => match f {
                    Some(f) => f,
                    None => break,
                },
            };
            let times = FrameTimes::at(f.stamp_us);
            self.operate(f.stamp_us);
            self.poll_fix(f.stamp_us);
            let phase = self.esc_status.phase();
            let stop_reason = (phase == EscPhase::Stopped)
                .then(|| self.esc_status.stop_reason())
                .flatten();
            let esc = EscState {
                phase,
                stop_reason: stop_reason.as_deref(),
            };
            let sample = match self.side.on_frame(&f.frame, times, esc, &mut self.out) {
                FrameAction::Wait => continue,
                FrameAction::StartEscs => {
                    self.esc.start();
                    continue;
                }
                FrameAction::Abort(why) => return Err(why.into()),
                FrameAction::StopEscs => {
                    self.esc.halt("disarmed");
                    continue;
                }
                FrameAction::Ended => break,
                FrameAction::Step(sample) => sample,
            };
            if phase == EscPhase::Running {
                // A command follows this step: the ESC writer wakes while it is computed.
                self.esc.expect_command();
            }
            let step = self.side.counts().steps as u32;
            let Some(fb) = self.wait_feedback(step, &mut late_feedback).await else {
                break;
            };
            let live = self.pending_fix.take();
            let Some(est) = self.side.estimate(sample, times, &fb, live, &mut self.out) else {
                continue;
            };
            if let Some(e) = est.ekf_error {
                tracing::warn!(step = est.step, "{e}");
            }
            let msg = EstimateMsg {
                est,
                frame_at: f.at,
                estimated_at: Instant::now(),
            };
            if self.estimates.send(msg).await.is_err() {
                break;
            }
        }
        if let Some(h) = self.watchdog.halt() {
            self.side
                .note_halt(h.halt_us, h.trip.reason.name(), &mut self.out);
        }
        let c = self.side.counts();
        Ok(EstimatorReport {
            frames: c.frames,
            steps: c.steps,
            late_feedback,
            ekf_errors: c.ekf_errors,
            gps_updates: c.gps_updates,
            commander: self.side.summary(self.side.commander().figures()),
            ekf_gated: c.gated,
        })
    }

    /// The operator's inputs that arrived since the previous frame, never waited for; `fly
    /// --arm` arms once the IMU has settled.
    fn operate(&mut self, t_us: i64) {
        if self.auto_arm && self.side.phase() == Phase::EscStart {
            self.auto_arm = false;
            self.apply(
                OperatorInput::Command(Command::Arm, LinkSource::Terminal),
                t_us,
            );
        }
        while let Ok(input) = self.operator.try_recv() {
            self.apply(input, t_us);
        }
    }

    fn apply(&mut self, input: OperatorInput, t_us: i64) {
        let facts = if matches!(input, OperatorInput::Command(Command::Arm, _)) {
            let silent = self.esc_status.silent_addresses(&self.prearm.addresses);
            let fix = self.gps_live.as_ref().and_then(|rx| *rx.borrow());
            self.prearm.facts(silent, fix.as_ref(), t_us)
        } else {
            ArmFacts::default()
        };
        // A ground station's command or mission is acknowledged with its outcome.
        let notice = match &input {
            OperatorInput::Command(command, source @ LinkSource::Gcs) => {
                Some((Some((*command, *source)), None))
            }
            OperatorInput::Mission(plan) => Some((None, Some(plan.name.clone()))),
            _ => None,
        };
        let action = self
            .side
            .operator(input, t_us, ArmCheck::Facts(&facts), &mut self.out);
        if let Some(about) = notice {
            let refused = self.side.last_refusal().map(str::to_string);
            self.out.notices.send(match about {
                (Some((command, source)), _) => Notice::Outcome {
                    command,
                    source,
                    refused,
                },
                (None, name) => Notice::Mission {
                    name: name.unwrap_or_default(),
                    refused,
                },
            });
        }
        match action {
            OperatorAction::StopEscs => self.esc.halt("disarmed"),
            OperatorAction::Quit => self.cancel.cancel(),
            OperatorAction::Nothing => {}
        }
    }

    /// A live fix published since the previous frame (never waited for): the commander
    /// hears of it at once, from arming on; the next Kalman step fuses it if still current.
    fn poll_fix(&mut self, t_us: i64) {
        let Some(rx) = self.gps_live.as_mut() else {
            return;
        };
        if !rx.has_changed().unwrap_or(false) {
            return;
        }
        let Some(fix) = *rx.borrow_and_update() else {
            return;
        };
        self.pending_fix = Some(fix);
        self.apply(OperatorInput::GpsFix, t_us);
    }

    /// The controller's feedback for `step`; `None` when the controller is gone or on cancel.
    async fn wait_feedback(&mut self, step: u32, late: &mut u64) -> Option<Feedback> {
        let ready = |fb: &Feedback| fb.step >= step;
        if !ready(&self.feedback.borrow()) {
            let t0 = Instant::now();
            let cancel = self.cancel.clone();
            let got = tokio::select! {
                _ = cancel.cancelled() => false,
                r = self.feedback.wait_for(|fb| ready(fb)) => r.is_ok(),
            };
            if t0.elapsed() > FEEDBACK_LATE {
                *late += 1;
            }
            if !got {
                return None;
            }
        }
        Some(*self.feedback.borrow())
    }
}
