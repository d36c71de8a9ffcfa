//! The driving loop's pieces, written once (spec 8.3): an operator's input and a frame taken
//! through the flight sequence, with what they ask of the ESCs. `sim --fast` and `replay` run
//! both sides in one thread through [`Flight`]; `fly` splits the same step at the estimate
//! between its estimator and controller tasks and calls the same pieces ([`act`],
//! [`frame_action`], [`hand_off`]). What differs between drivers — where the ESCs are, where a live fix
//! comes from, what a driver does after an estimate — is [`Edges`].

use super::halves::Estimate;
use super::sequence::{
    Abort, ArmCheck, Command, ControllerSide, EscState, EstimatorSide, Feedback, FrameAction,
    FrameTimes, OperatorAction, Outputs,
};
use crate::core::commander::OperatorInput;
use crate::core::ekf::Ekf;
use crate::core::esc::StopReason;
use crate::core::gps::LiveFix;
use crate::core::imu::calib::ImuSample;
use crate::core::imu::frame::RawFrame;

/// What the flight asks of the ESCs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EscAsk {
    /// Enable them and run their start-up ramp.
    Start,
    /// Zero, then disable them, for this reason.
    Stop(StopReason),
    /// Spin one motor alone, disarmed (a motor test).
    TestMotor(crate::core::esc::MotorTest),
}

/// What a driver does with the ESCs and with the end of its run.
pub trait EscEdges {
    fn escs(&mut self, ask: EscAsk);
    /// The operator's quit key: end the run, the motors stopped first.
    fn quit(&mut self);
}

/// The rest of what differs between drivers that run both sides in one thread.
pub trait Edges<O: Outputs>: EscEdges {
    /// The ESCs as the flight sees them before a frame.
    fn esc_state(&self) -> EscState;
    /// The newest live fix not yet offered to a Kalman step, taken.
    fn take_fix(&mut self) -> Option<LiveFix>;
    /// After an estimate, before the controller: the driver's own look at it (the
    /// simulator's truth, a replay's hook).
    fn estimated(&mut self, est: &Estimate, ekf: Option<&Ekf>, out: &mut O);
    /// The step's command, handed to the ESCs.
    fn command(&mut self, c: &Command);
}

/// What an operator's action asks of the edges; one mapping for every driver.
pub fn act(action: OperatorAction, edges: &mut impl EscEdges) {
    match action {
        OperatorAction::StopEscs => edges.escs(EscAsk::Stop(StopReason::Disarmed)),
        OperatorAction::StartEscs => edges.escs(EscAsk::Start),
        OperatorAction::TestMotor(test) => edges.escs(EscAsk::TestMotor(test)),
        OperatorAction::KillSwitch => edges.escs(EscAsk::Stop(StopReason::KillSwitch)),
        OperatorAction::Quit => edges.quit(),
        OperatorAction::Nothing => {}
    }
}

/// What became of a frame after [`frame_action`].
#[derive(Debug)]
pub enum Framed {
    /// A Kalman step is due on this sample.
    Step(ImuSample),
    /// Nothing more for this frame (the ESCs were told what the flight asked, if anything).
    Done,
    /// The run ends with this error; the driver stops the motors.
    Aborted(Abort),
    /// The run has ended: no more frames.
    Ended,
}

/// A frame's action as the edges carry it out; one mapping for every driver.
pub fn frame_action(action: FrameAction, edges: &mut impl EscEdges) -> Framed {
    match action {
        FrameAction::Step(sample) => Framed::Step(sample),
        FrameAction::Wait => Framed::Done,
        FrameAction::StartEscs => {
            edges.escs(EscAsk::Start);
            Framed::Done
        }
        FrameAction::StopEscs => {
            edges.escs(EscAsk::Stop(StopReason::Disarmed));
            Framed::Done
        }
        FrameAction::Abort(why) => Framed::Aborted(why),
        FrameAction::Ended => Framed::Ended,
    }
}

/// The step's command as the ESCs take it: a stop when the commander disarmed, else speeds.
pub fn hand_off(c: &Command, edges: &mut impl EscEdges) -> bool {
    if c.stop_escs {
        edges.escs(EscAsk::Stop(StopReason::Disarmed));
        false
    } else {
        true
    }
}

/// Both sides of the flight in one thread, and the feedback between them.
pub struct Flight {
    pub estimator: EstimatorSide,
    pub controller: ControllerSide,
    feedback: Feedback,
}

impl Flight {
    pub fn new(estimator: EstimatorSide, controller: ControllerSide) -> Self {
        let feedback = controller.first_feedback();
        Flight {
            estimator,
            controller,
            feedback,
        }
    }

    /// An operator's input at `t_us`, and what it asks of the edges.
    pub fn operate<O: Outputs>(
        &mut self,
        input: OperatorInput,
        t_us: i64,
        check: ArmCheck<'_>,
        edges: &mut impl EscEdges,
        out: &mut O,
    ) {
        let action = self.estimator.operator(input, t_us, check, out);
        act(action, edges);
    }

    /// One frame in the flight sequence's order: the estimator side's verdict on it, the
    /// Kalman step with the previous step's feedback and a live fix, the driver's look, the
    /// control step and its command to the ESCs. An abort is returned, the run's to end.
    pub fn frame<O: Outputs, E: Edges<O>>(
        &mut self,
        frame: &RawFrame,
        times: FrameTimes,
        edges: &mut E,
        out: &mut O,
    ) -> Result<(), Abort> {
        let esc = edges.esc_state();
        let action = self.estimator.on_frame(frame, times, esc, out);
        let sample = match frame_action(action, edges) {
            Framed::Step(sample) => sample,
            Framed::Done | Framed::Ended => return Ok(()),
            Framed::Aborted(why) => return Err(why),
        };
        let fix = edges.take_fix();
        let Some(est) = self
            .estimator
            .estimate(sample, times, &self.feedback, fix, out)
        else {
            return Ok(());
        };
        edges.estimated(&est, self.estimator.ekf(), out);
        let send = |c: &Command| {
            if hand_off(c, edges) {
                edges.command(c);
            }
        };
        self.feedback = self.controller.control(&est, send, out).feedback;
        Ok(())
    }
}
