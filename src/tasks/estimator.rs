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
//!
//! Operator inputs are taken from their queue as they arrive (stamped then) and applied at
//! the next frame; one that waits past `commander.input_expiry_s` (no frames) is answered
//! refused at once and recorded refused at the next frame or the run's end, never applied.

use crate::core::commander::Summary as CommanderSummary;
use crate::core::commander::{ArmFacts, Command, LinkSource, Mode, OperatorInput, expiry_reason};
use crate::core::esc::EscPhase;
use crate::core::flight::drive::{Framed, act, frame_action};
use crate::core::flight::{
    ArmCheck, EscState, Estimate, EstimatorSide, Feedback, FrameTimes, GatedCounts,
};
use crate::core::gps::LiveFix;
use crate::tasks::TaskOutputs;
use crate::tasks::esc_writer::{EscMailbox, EscStatus, MailboxEscs};
use crate::tasks::imu_reader::StampedFrame;
use crate::tasks::notices::Notice;
use crate::tasks::prearm::PreArm;
use crate::tasks::watchdog::WatchdogStatus;
use std::collections::VecDeque;
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
    /// Why the flight could not start (asked to fly, the IMU silent or never settled).
    pub start_failure: Option<String>,
}

/// Operator inputs held for the next frame, at most this many (the operator queue's size:
/// beyond, they wait in the queue itself, whose senders see it full).
const HELD_MAX: usize = 64;

/// An operator input taken from the queue, not yet applied.
#[derive(Debug)]
pub struct Held {
    input: OperatorInput,
    /// When it was taken from the queue.
    at: Instant,
    /// Its refusal was already sent (it expired with no frame to apply it at).
    answered: bool,
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
    /// `fly --arm`: arm once the flight side is ready (settled; calibrated at rest with the
    /// estimate converged).
    pub auto_arm: bool,
    /// The watchdog's state: a halt ends the run, and the commander records its `kill`.
    pub watchdog: Arc<WatchdogStatus>,
    /// The newest live fix not yet offered to a Kalman step.
    pub pending_fix: Option<LiveFix>,
    /// Operator inputs taken, not yet applied (empty at start).
    pub held: VecDeque<Held>,
    /// `commander.input_expiry_s`.
    pub input_expiry: Duration,
    /// When the pre-arm verdict is next checked and published, µs (0 at start).
    pub next_prearm_us: i64,
}

/// The pre-arm verdict is published this often, µs (SYS_STATUS goes out each second).
const PREARM_EVERY_US: i64 = 1_000_000;

impl EstimatorTask {
    pub async fn run(mut self) -> anyhow::Result<EstimatorReport> {
        let mut late_feedback = 0;
        let mut last_frame_us = 0;
        loop {
            let expiry = self.next_expiry();
            let f = tokio::select! {
                _ = self.cancel.cancelled() => break,
                f = self.frames.recv() => match f {
                    Some(f) => f,
                    None => break,
                },
                Some(input) = self.operator.recv(), if self.held.len() < HELD_MAX => {
                    self.hold(input);
                    continue;
                }
                _ = tokio::time::sleep_until(expiry.unwrap_or_else(tokio::time::Instant::now)), if expiry.is_some() => {
                    self.answer_expired();
                    continue;
                }
            };
            last_frame_us = f.stamp_us;
            let times = FrameTimes::at(f.stamp_us);
            self.operate(f.stamp_us);
            self.poll_fix(f.stamp_us);
            self.publish_prearm(f.stamp_us);
            let starts = self.esc_status.starts();
            let phase = self.esc_status.phase();
            let stop_reason = (phase == EscPhase::Stopped)
                .then(|| self.esc_status.stop_reason())
                .flatten();
            let esc = EscState {
                phase,
                stop_reason,
                starts,
            };
            let action = self.side.on_frame(&f.frame, times, esc, &mut self.out);
            let mut escs = MailboxEscs {
                esc: &self.esc,
                cancel: &self.cancel,
            };
            let sample = match frame_action(action, &mut escs) {
                Framed::Step(sample) => sample,
                Framed::Done => continue,
                Framed::Aborted(why) => return Err(why.into()),
                Framed::Ended => break,
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
        self.expire_held(last_frame_us);
        if let Some(h) = self.watchdog.halt() {
            self.side
                .note_halt(h.halt_us, h.trip.reason.name(), &mut self.out);
        }
        let start_failure = self.side.start_failure(self.out.beats.us(Instant::now()));
        let c = self.side.counts();
        Ok(EstimatorReport {
            frames: c.frames,
            steps: c.steps,
            late_feedback,
            ekf_errors: c.ekf_errors,
            gps_updates: c.gps_updates,
            commander: self.side.summary(self.side.commander().flight_figures()),
            ekf_gated: c.gated,
            start_failure,
        })
    }

    /// An operator input taken from the queue, applied at the next frame. A beat or a fix
    /// replaces a held one of its kind (the newest is the fact): while no frame comes they
    /// cannot fill the held inputs and shut the operator's commands out. A radio's report
    /// replaces the last held input only when that is a report too: its order against the
    /// radio's commands (the throttle before an arm) and its newest state both stay.
    fn hold(&mut self, input: OperatorInput) {
        if let OperatorInput::Rc(_) = input {
            match self.held.back_mut() {
                Some(h) if matches!(h.input, OperatorInput::Rc(_)) => {
                    (h.input, h.at) = (input, Instant::now());
                }
                _ => self.held.push_back(Held {
                    input,
                    at: Instant::now(),
                    answered: false,
                }),
            }
            return;
        }
        if !input.expires()
            && let Some(h) = self.held.iter_mut().find(|h| h.input == input)
        {
            h.at = Instant::now();
            return;
        }
        self.held.push_back(Held {
            input,
            at: Instant::now(),
            answered: false,
        });
    }

    /// At the run's end, the held inputs no frame came for: the operator's askings past
    /// `commander.input_expiry_s` recorded refused (after the last frame, where a replay
    /// applies them too); younger ones named in a warning; beats and fixes, facts of a run
    /// now over, dropped.
    fn expire_held(&mut self, last_frame_us: i64) {
        self.answer_expired();
        let end_us = self.out.beats.us(Instant::now()).max(last_frame_us + 1);
        let now = Instant::now();
        for h in std::mem::take(&mut self.held) {
            let (input, _) = self.aged(h, now);
            if !matches!(input, OperatorInput::Expired { .. }) {
                if input.expires() {
                    tracing::warn!("{} not applied: the run ended", input.what());
                }
                continue;
            }
            let facts = ArmFacts::default();
            self.side
                .operator(input, end_us, ArmCheck::Facts(&facts), &mut self.out);
        }
    }

    /// A held input as it reaches the flight at `now` (expired past
    /// `commander.input_expiry_s`), and whether its refusal already went out: an answered
    /// one is refused whatever the clock's rounding says now.
    fn aged(&self, h: Held, now: Instant) -> (OperatorInput, bool) {
        let waited_us = now
            .saturating_duration_since(h.at)
            .as_micros()
            .try_into()
            .unwrap_or(i64::MAX);
        let input = if h.answered {
            OperatorInput::Expired {
                input: Box::new(h.input),
                waited_us,
            }
        } else {
            self.side.commander().aged(h.input, waited_us)
        };
        (input, h.answered)
    }

    /// When the oldest unanswered held input expires.
    fn next_expiry(&self) -> Option<tokio::time::Instant> {
        let h = self
            .held
            .iter()
            .find(|h| !h.answered && h.input.expires())?;
        Some((h.at + self.input_expiry).into())
    }

    /// Held inputs past `commander.input_expiry_s` with no frame to apply them at: their
    /// refusal goes out now (the ground station's answer, a warning for a typed one); the
    /// flight records it at the next frame.
    fn answer_expired(&mut self) {
        let why = expiry_reason(self.input_expiry.as_secs_f64());
        for h in self.held.iter_mut() {
            if h.answered || !h.input.expires() || h.at.elapsed() <= self.input_expiry {
                continue;
            }
            h.answered = true;
            match notice_of(&h.input, Some(why.clone())) {
                Some(n) => self.out.notices.send(n),
                None => tracing::warn!("{} refused: {why}", h.input.what()),
            }
        }
    }

    /// Once a second while disarmed (in flight the control path spends nothing on it): what
    /// an `arm` would be told now by the pre-arm checks, for a ground station's pre-arm bit
    /// (the facts as an `arm` gathers them; nothing is recorded).
    fn publish_prearm(&mut self, t_us: i64) {
        if t_us < self.next_prearm_us || self.side.mode() != Mode::Disarmed {
            return;
        }
        self.next_prearm_us = t_us + PREARM_EVERY_US;
        let facts = self.arm_facts(t_us);
        let pass =
            self.side.commander().may_arm() && self.side.prearm_verdict(&facts, t_us).is_ok();
        self.prearm.verdict.set(pass);
    }

    /// The pre-arm facts as an `arm` at `t_us` sees them.
    fn arm_facts(&self, t_us: i64) -> ArmFacts {
        let silent = self.esc_status.silent_addresses(&self.prearm.addresses);
        let fix = self.gps_live.as_ref().and_then(|rx| *rx.borrow());
        self.prearm.facts(silent, fix.as_ref(), t_us)
    }

    /// The operator's inputs that arrived since the previous frame, never waited for; `fly
    /// --arm` arms once the flight side is ready.
    fn operate(&mut self, t_us: i64) {
        // Once the IMU has settled and its frames vouch for it (a gap at the start would
        // refuse an arm made at once).
        if self.auto_arm && self.side.ready_to_arm(t_us) {
            self.auto_arm = false;
            self.apply(
                OperatorInput::Command(Command::Arm, LinkSource::Terminal),
                t_us,
            );
        }
        while self.held.len() < HELD_MAX
            && let Ok(input) = self.operator.try_recv()
        {
            self.hold(input);
        }
        let now = Instant::now();
        while let Some(h) = self.held.pop_front() {
            let (input, answered) = self.aged(h, now);
            if answered {
                // Its refusal went out already: recorded, not answered twice.
                let facts = ArmFacts::default();
                self.side
                    .operator(input, t_us, ArmCheck::Facts(&facts), &mut self.out);
            } else {
                self.apply(input, t_us);
            }
        }
    }

    fn apply(&mut self, input: OperatorInput, t_us: i64) {
        let facts = if input.checked_against_facts() {
            self.arm_facts(t_us)
        } else {
            ArmFacts::default()
        };
        // A ground station's command or mission is acknowledged with its outcome.
        let asked = notice_of(&input, None).is_some().then(|| input.clone());
        let action = self
            .side
            .operator(input, t_us, ArmCheck::Facts(&facts), &mut self.out);
        if let Some(asked) = asked {
            let refused = self.side.last_refusal().map(str::to_string);
            if let Some(n) = notice_of(&asked, refused) {
                self.out.notices.send(n);
            }
        }
        let mut escs = MailboxEscs {
            esc: &self.esc,
            cancel: &self.cancel,
        };
        act(action, &mut escs);
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

/// The answer a ground station waits for about `input` (a command of its, a mission), with
/// the refusal's reason if refused; `None` for inputs no one waits on.
pub(crate) fn notice_of(input: &OperatorInput, refused: Option<String>) -> Option<Notice> {
    match input {
        OperatorInput::Command(command, source @ LinkSource::Gcs) => Some(Notice::Outcome {
            command: *command,
            source: *source,
            refused,
        }),
        OperatorInput::Mission(plan) => Some(Notice::Mission {
            name: plan.name.clone(),
            refused,
        }),
        OperatorInput::Expired { input, .. } => notice_of(input, refused),
        _ => None,
    }
}
