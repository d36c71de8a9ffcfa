//! The flight: its two halves (estimator, controller), the GPS feed between them, the
//! sequence that orders them into one flight step for every mode (spec 8.3; see
//! [`sequence`] for the order, written once), and the driving loop's pieces every driver
//! calls ([`drive`]).

pub mod drive;
pub mod gps_feed;
pub mod halves;
pub mod imu_watch;
pub mod sequence;

pub use gps_feed::GpsFeed;
pub use halves::{
    ControlOut, ControllerCore, Estimate, EstimatorCore, NOMINAL_PERIOD_US, PlannerSpec,
};
pub use sequence::{
    Abort, ArmCheck, Command, ControllerCounts, ControllerSide, EscState, EstimatorCounts,
    EstimatorSide, Feedback, FlightRecord, FrameAction, FrameTimes, GatedCounts, OperatorAction,
    Outputs, Phase, RecordedClock,
};
