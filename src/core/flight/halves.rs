//! The flight loop's two halves as pure state machines: the estimator (measurement front end +
//! EKF) and the controller (hover planner + P + I controller + flight ramp and saturation).
//! The flight sequence (`sequence.rs` beside this file) drives them in the order every mode
//! follows.
//!
//! Spec section 8.3 steps 6–11 with ERRATA 3–8 and 10: one Kalman step per filtered frame; the
//! EKF input u is w_hover on step 1, the previous raw controller output while the flight ramp
//! runs (steps 2–100), then the previous command actually sent; the control period is the
//! control step's time minus the previous command's time. Replay is byte-identical because
//! every mode makes these same calls in the same order with the same inputs.

use crate::core::commander::{Guidance, Mode};
use crate::core::control::Gains;
use crate::core::control::{
    Controller, Horizontal, HoverPlanner, ManualCommand, ManualOutcome, SetPoint,
};
use crate::core::ekf::{
    Ekf, EkfError, EkfParams, GatedGroups, Input, State, StepInput, StepNis, TestRatios,
};
use crate::core::gps::GpsSample;
use crate::core::imu::calib::{Calibration, ImuSample};
use crate::core::imu::frame::RawFrame;
use crate::core::imu::health::GyroWatch;
use crate::core::imu::startup::{FrontEndEvent, ImuFrontEnd, StartupParams};
use crate::core::mission::{GainKey, GainTable};
use crate::core::model::MotorLimits;
use crate::core::motor::{FLIGHT_RAMP_STEPS, command_for_step};
use crate::core::torque::TorqueObserver;

/// The first Kalman and control steps have no predecessor: they use the nominal period.
pub const NOMINAL_PERIOD_US: i64 = 10_000;

/// One Kalman step's result.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// 1-based Kalman step.
    pub step: u32,
    /// Time of the step, µs since start.
    pub t_us: i64,
    /// The times its control step and motor command run at (the step's own time except in
    /// replay, which takes them from the run's logs).
    pub t_ctrl_us: i64,
    pub t_cmd_us: i64,
    /// The measurement the filter used (θ unwrapped), for kalman_in.log.
    pub sample: ImuSample,
    /// The state after the step.
    pub x: State,
    /// Yaw measured at calibration (the hover set point's θ).
    pub theta_cal_rad: f64,
    /// A fix was fused in this step: offered, and its position not left out by the innovation
    /// gate (a receiver whose positions stay gated is, past `failsafe.gps_loss_land_s`, a
    /// lost one to the commander).
    pub gps_used: bool,
    /// A fix's horizontal velocity was fused in this step inside its gate, its position
    /// perhaps left out (a position glitch): the velocity, and the position dead-reckoned on
    /// it, stay observed.
    pub gps_velocity_used: bool,
    /// The test ratio of a fix's velocity rows alone, when one came with a velocity.
    pub gps_velocity_ratio: Option<f64>,
    /// The filter observes the horizontal velocity: fixes lately fused (a fix's velocity
    /// alone counts), or without them the drag.
    pub velocity_observed: bool,
    /// The filter observes the vertical (a barometer, or fixes' vertical velocity).
    pub vertical_observed: bool,
    /// The gyro is lost (stuck): the filter's rates are the model's.
    pub gyro_lost: bool,
    /// The horizontal position's standard deviation (the larger axis's), m; with the
    /// receiver's bias states it holds the bias's doubt too (`Ekf::horizontal_sigma_m`).
    pub pos_sigma_m: f64,
    /// How far the gyros' roll and pitch bias was learnt to move since the last fused fix,
    /// rad/s (`Ekf::bias_learnt_unaided_rad_s`).
    pub bias_unaided_rad_s: f64,
    /// The accelerometer's size at rest, by the calibration, m/s².
    pub acc_rest_m_s2: f64,
    pub dt_clamped: bool,
    pub ekf_error: Option<EkfError>,
    /// The commander's guidance for this step's control, and the gains designed along its
    /// mission's paths (a new mission's reach the controller with its first step).
    pub guidance: Guidance,
    pub gains: Option<std::sync::Arc<GainTable>>,
    /// A manual key for the planner, applied before this step's control.
    pub manual: Option<ManualCommand>,
    /// Zero and disable the ESCs instead of commanding them (disarmed on the ground).
    pub stop_escs: bool,
    /// The step's innovation test ratios, for innov.log.
    pub ratios: TestRatios,
    /// The measurement groups the step left out of its update.
    pub gated: GatedGroups,
    /// The step's normalised innovations squared (the simulator's consistency figures).
    pub nis: StepNis,
}

/// What the commander knows of the ground for a Kalman step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ground {
    /// The ground's height while the vehicle rests on it disarmed or landed, m (the
    /// estimate's frame): its height and a still body are fused.
    pub height_m: Option<f64>,
    /// The vehicle rests on the ground, armed or not: a body that does not turn is fused.
    pub at_rest: bool,
}

/// The estimator half: front end (settle, calibrate, FIR, conversion) and EKF.
#[derive(Debug, Clone)]
pub struct EstimatorCore {
    front: ImuFrontEnd,
    params: EkfParams,
    ekf: Option<Ekf>,
    theta_cal_rad: f64,
    /// The accelerometer's size in the calibration's null sample, m/s².
    acc_rest_m_s2: f64,
    steps: u32,
    prev_step_us: Option<i64>,
    /// The raw gyro's health: once stuck, the samples carry no rates (not a number) and the
    /// filter leaves the gyro's rows out.
    gyro: GyroWatch,
}

impl EstimatorCore {
    pub fn new(
        startup: StartupParams,
        calib: Calibration,
        params: EkfParams,
        skip_settle: bool,
    ) -> Self {
        EstimatorCore {
            front: ImuFrontEnd::new(startup, calib, skip_settle),
            params,
            ekf: None,
            theta_cal_rad: 0.0,
            acc_rest_m_s2: crate::core::model::GRAVITY_M_S2,
            steps: 0,
            prev_step_us: None,
            gyro: GyroWatch::default(),
        }
    }

    /// Stop after settling until [`EstimatorCore::begin_calibration`] (the ESC start-up ramp
    /// runs in between, so the null estimate sees the motors idling as in flight).
    pub fn hold_after_settle(mut self) -> Self {
        self.front = self.front.hold_after_settle();
        self
    }

    pub fn begin_calibration(&mut self) {
        self.front.begin_calibration();
    }

    /// Drops the estimate and takes the null sample again (a calibration at rest that was
    /// not plausible).
    pub fn recalibrate(&mut self) {
        self.front.restart_calibration();
        self.ekf = None;
    }

    /// Kalman steps done so far.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    pub fn ekf(&self) -> Option<&Ekf> {
        self.ekf.as_ref()
    }

    /// Feeds a frame stamped at `stamp_us`. `Calibrated` and `Sample` events carry the sample
    /// for the next Kalman step ([`EstimatorCore::step`]); on `Calibrated` the filter has just
    /// been initialised from the null sample.
    pub fn on_frame(&mut self, frame: &RawFrame, stamp_us: i64) -> FrontEndEvent {
        let mut event = self.front.on_frame(frame, stamp_us);
        // Watched from each calibration's first frame (where a replay's log starts too): a
        // sensor still starting up while the period settles is not held against it.
        let gyro_lost = match event {
            FrontEndEvent::Calibrating { frames: 1 } => {
                self.gyro = GyroWatch::default();
                self.gyro.on_frame(frame)
            }
            FrontEndEvent::Calibrating { .. }
            | FrontEndEvent::Calibrated(_)
            | FrontEndEvent::Sample(_) => self.gyro.on_frame(frame),
            _ => self.gyro.lost(),
        };
        if gyro_lost {
            // A stuck gyro reads a still vehicle: its rates are not a measurement (the
            // calibration's check refuses a null sample without them).
            match &mut event {
                FrontEndEvent::Sample(s) => s.gyro_rad_s = [f64::NAN; 3],
                FrontEndEvent::Calibrated(null) => {
                    null.sample.gyro_rad_s = [f64::NAN; 3];
                    null.reference.gyro_null_rad_s = [f64::NAN; 3];
                }
                _ => {}
            }
        }
        if let FrontEndEvent::Calibrated(null) = &event {
            self.ekf = Some(Ekf::new(self.params.clone(), &null.sample));
            self.theta_cal_rad = null.sample.euler_rad[2];
            let [ax, ay, az] = null.sample.acc_m_s2;
            self.acc_rest_m_s2 = (ax * ax + ay * ay + az * az).sqrt();
        }
        event
    }

    /// One Kalman step on `sample` at `t_us` with input `u_rad_s`, mass `mass_kg`, an
    /// optional GPS sample and what the commander knows of the ground. `None` before
    /// calibration finished.
    pub fn step(
        &mut self,
        mut sample: ImuSample,
        t_us: i64,
        u_rad_s: Input,
        mass_kg: f64,
        gps: Option<GpsSample>,
        ground: Ground,
    ) -> Option<Estimate> {
        let ekf = self.ekf.as_mut()?;
        let dt_us = self.prev_step_us.map_or(NOMINAL_PERIOD_US, |p| t_us - p);
        self.prev_step_us = Some(t_us);
        let (report, result) = ekf.step(
            &sample,
            &StepInput {
                u_rad_s,
                mass_kg,
                dt_us,
                gps,
                ground_m: ground.height_m,
                at_rest: ground.at_rest,
            },
        );
        sample.euler_rad[2] = report.theta_unwrapped_rad;
        self.steps += 1;
        Some(Estimate {
            step: self.steps,
            t_us,
            t_ctrl_us: t_us,
            t_cmd_us: t_us,
            sample,
            x: ekf.model_state(),
            theta_cal_rad: self.theta_cal_rad,
            gps_used: gps.is_some() && !report.gated.gps,
            gps_velocity_used: report.fix_velocity_fused,
            gps_velocity_ratio: report.fix_velocity_ratio,
            velocity_observed: ekf.horizontal_velocity_observed(),
            vertical_observed: ekf.vertical_observed(),
            gyro_lost: ekf.gyro_lost,
            pos_sigma_m: ekf.horizontal_sigma_m(),
            bias_unaided_rad_s: ekf.bias_learnt_unaided_rad_s(),
            acc_rest_m_s2: self.acc_rest_m_s2,
            dt_clamped: report.dt_clamped,
            ekf_error: result.err(),
            guidance: Guidance::OFF,
            gains: None,
            manual: None,
            stop_escs: false,
            ratios: report.ratios,
            gated: report.gated,
            nis: report.nis,
        })
    }
}

/// One control step's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlOut {
    pub step: u32,
    /// Control step time and command time, µs since start.
    pub t_ctrl_us: i64,
    pub t_cmd_us: i64,
    /// Raw controller output, rad/s.
    pub w_ctrl: [f64; 4],
    /// The command to send: flight ramp and saturation applied, rad/s.
    pub w_sent: [f64; 4],
    /// Integrators (the first `n_int` are meaningful).
    pub x_int: [f64; 4],
    pub n_int: usize,
    /// At least one speed was clamped to w_min or w_max.
    pub saturated: bool,
    /// The horizontal position was held (a GPS fix fused lately).
    pub position_hold: bool,
    /// The set point flown: x, y, z (m), ψ, φ, θ (rad); none while the control law rests.
    pub setpoint: Option<[f64; 6]>,
}

/// The controller half: planner, controller, flight ramp and saturation, and the EKF input.
#[derive(Debug, Clone)]
pub struct ControllerCore {
    controller: Controller,
    make_planner: PlannerSpec,
    planner: Option<HoverPlanner>,
    original_timing: bool,
    /// The previous step's raw output, command sent and command time.
    prev: Option<([f64; 4], [f64; 4], i64)>,
    /// Horizontal position is held while a GPS fix was fused within this long, µs.
    gps_hold_timeout_us: i64,
    /// Time of the last step that fused a GPS fix, µs.
    last_gps_us: Option<i64>,
    /// Roll, pitch and yaw torque-disturbance observer (not in the original), from the end of
    /// the flight ramp on.
    observer: Option<TorqueObserver>,
    /// The Kalman step the control law started at (the takeoff): the flight ramp counts
    /// from it.
    ramp_from: Option<u32>,
    /// Gains designed along a mission's paths, the profile's, and which are flown.
    gain_table: std::sync::Arc<GainTable>,
    first_table: Option<std::sync::Arc<GainTable>>,
    profile_gains: Gains,
    active_gains: GainKey,
    /// The last step's set point was a path's.
    following: bool,
    /// The observer as built, for each flight's start.
    observer_new: Option<TorqueObserver>,
    /// Disarmed after a flight: the next takeoff starts the control law afresh.
    flown: bool,
}

/// What the hover planner is built from once the calibration yaw is known.
#[derive(Debug, Clone, Copy)]
pub struct PlannerSpec {
    pub hover_z_m: f64,
    pub mass_kg: f64,
    pub w_max_rad_s: f64,
    pub bounds: crate::core::control::ManualBounds,
}

impl ControllerCore {
    /// `gps_hold_timeout_us`: the horizontal position is held only while a GPS fix was fused
    /// within this long (see [`Controller::step_with_hold`]).
    pub fn new(
        controller: Controller,
        spec: PlannerSpec,
        original_timing: bool,
        gps_hold_timeout_us: i64,
    ) -> Self {
        ControllerCore {
            profile_gains: controller.gains(),
            gain_table: std::sync::Arc::new(GainTable::default()),
            first_table: None,
            active_gains: GainKey::Profile,
            following: false,
            controller,
            make_planner: spec,
            planner: None,
            original_timing,
            prev: None,
            gps_hold_timeout_us,
            last_gps_us: None,
            observer: None,
            ramp_from: None,
            observer_new: None,
            flown: false,
        }
    }

    /// The flight ramp's step (1-based) for Kalman step `step`; none before the takeoff.
    fn ramp_step(&self, step: u32) -> Option<u32> {
        self.ramp_from.map(|from| step.saturating_sub(from) + 1)
    }

    /// Adds the torque-disturbance observer with low-pass time constant `tau_s`, for motors
    /// with time constant `motor_tau_s` (see [`TorqueObserver`]); it acts from the end of the
    /// flight ramp on.
    pub fn with_torque_observer(mut self, tau_s: f64, motor_tau_s: f64) -> Self {
        self.observer = Some(TorqueObserver::new(tau_s, motor_tau_s));
        self.observer_new = self.observer.clone();
        self
    }

    /// Swaps in the gains the guidance asks for (the profile's when none were designed), at
    /// a segment's start: a new table (a new mission's) is only taken then, the gains flown
    /// kept until it.
    fn swap_gains(&mut self, table: Option<&std::sync::Arc<GainTable>>, key: GainKey) {
        if key == self.active_gains {
            return;
        }
        if let Some(t) = table
            && !std::sync::Arc::ptr_eq(t, &self.gain_table)
        {
            // The commander keeps every table it handed over alive and the first one, the
            // controller's own, is kept here: a swap frees no memory on the control thread.
            let old = std::mem::replace(&mut self.gain_table, t.clone());
            self.first_table.get_or_insert(old);
        }
        self.active_gains = key;
        let gains = *self.gain_table.get(key).unwrap_or(&self.profile_gains);
        // Between two kinds flown on the same gains nothing is swapped (nor rescaled).
        if gains != self.controller.gains() {
            self.controller.set_gains(&gains);
        }
    }

    /// The err.log line for a change of position hold.
    pub fn position_hold_message(&self, hold: bool) -> String {
        if hold {
            "position hold on: GPS fixes fused".to_string()
        } else {
            format!(
                "position hold off: no GPS fix fused for {} s; holding attitude, altitude and yaw",
                self.gps_hold_timeout_us as f64 / 1e6
            )
        }
    }

    /// Motor limits for the current mass.
    pub fn limits(&self) -> MotorLimits {
        match &self.planner {
            Some(p) => p.limits(),
            None => MotorLimits::new(self.make_planner.mass_kg, self.make_planner.w_max_rad_s),
        }
    }

    pub fn mass_kg(&self) -> f64 {
        self.planner
            .as_ref()
            .map_or(self.make_planner.mass_kg, HoverPlanner::mass_kg)
    }

    pub fn planner(&self) -> Option<&HoverPlanner> {
        self.planner.as_ref()
    }

    /// The EKF input for Kalman step `step` (ERRATA 6).
    pub fn input_for_step(&self, step: u32) -> Input {
        let ramping = self.ramp_step(step).is_some_and(|r| r <= FLIGHT_RAMP_STEPS);
        match self.prev {
            None => [self.limits().w_hover_rad_s; 4],
            Some((w_ctrl, _, _)) if ramping => w_ctrl,
            Some((_, w_sent, _)) => w_sent,
        }
    }

    /// A step without the control law: idle speeds while armed on the ground, zero once
    /// disarmed (not sent: the ESCs are stopped). The filter's model has no ground: standing
    /// on it, the ground's push makes up the weight, so the EKF's input is the speed whose
    /// thrust is the weight, whatever the motors do (else the estimate sinks into the ground).
    fn rest(&mut self, est: &Estimate, t_ctrl_us: i64, t_cmd_us: i64) -> ControlOut {
        if est.guidance.mode == Mode::Disarmed && self.ramp_from.is_some() {
            self.flown = true;
        }
        let limits = self.limits();
        let w = if est.guidance.mode == Mode::Armed {
            [limits.w_min_rad_s; 4]
        } else {
            [0.0; 4]
        };
        let w_model = [limits.w_hover_rad_s; 4];
        self.prev = Some((w_model, w_model, t_cmd_us));
        let (x_int, n_int) = self.integrators();
        ControlOut {
            step: est.step,
            t_ctrl_us,
            t_cmd_us,
            w_ctrl: w,
            w_sent: w,
            x_int,
            n_int,
            saturated: false,
            position_hold: false,
            setpoint: None,
        }
    }

    /// A manual set-point command (spec 5.2); ignored before the planner exists.
    pub fn apply_manual(&mut self, cmd: ManualCommand) -> Option<ManualOutcome> {
        self.planner.as_mut().map(|p| p.apply(cmd))
    }

    /// One control step on `est` (spec 4.4, 8.3 steps 10–11), with the commander's guidance.
    pub fn control(&mut self, est: &Estimate, t_ctrl_us: i64, t_cmd_us: i64) -> ControlOut {
        if !est.guidance.fly {
            return self.rest(est, t_ctrl_us, t_cmd_us);
        }
        if std::mem::take(&mut self.flown) {
            self.new_flight();
        }
        let ramp_step = est
            .step
            .saturating_sub(*self.ramp_from.get_or_insert(est.step))
            + 1;
        let key = est.guidance.path.map_or(GainKey::Profile, |p| p.2);
        self.swap_gains(est.gains.as_ref(), key);
        let hold = self.horizontal_hold(est);
        let (sp, mass_kg) = self.guided_set_point(est, hold);
        let limits = MotorLimits::new(mass_kg, self.make_planner.w_max_rad_s);
        let t_s = self.period_us(t_ctrl_us) as f64 / 1e6;
        let position_hold = hold == Horizontal::Position;
        let mut w_ctrl = self.controller.step_with_hold(&est.x, &sp, t_s, hold);
        // The observer starts once the flight ramp is over: before, the vehicle stands on the
        // ground, which holds any torque, and the motors are far from the hover speeds the
        // correction is linearised around.
        if let Some(o) = &mut self.observer
            && ramp_step > FLIGHT_RAMP_STEPS
        {
            o.observe(&est.x, est.t_us, mass_kg);
            let c = o.correction_rad_s(&limits);
            for (w, dw) in w_ctrl.iter_mut().zip(c) {
                *w += dw;
            }
        }
        if let Some(share) = est.guidance.blind_thrust {
            crate::core::motor::set_thrust(&mut w_ctrl, share, mass_kg);
        }
        let w_sent = command_for_step(&w_ctrl, ramp_step, &limits);
        if let Some(o) = &mut self.observer {
            o.sent(&est.x, est.t_us, &w_sent);
        }
        self.prev = Some((w_ctrl, w_sent, t_cmd_us));
        let (x_int, n_int) = self.integrators();
        let saturated = w_sent
            .iter()
            .any(|&w| w == limits.w_min_rad_s || w == limits.w_max_rad_s);
        ControlOut {
            step: est.step,
            t_ctrl_us,
            t_cmd_us,
            w_ctrl,
            w_sent,
            x_int,
            n_int,
            saturated,
            position_hold,
            setpoint: Some(std::array::from_fn(|i| sp.x[i])),
        }
    }

    /// A takeoff after a landing in the same run: the flight ramp, the planner (its hover
    /// point and the manual keys' offsets), the integrators and the observer start as they
    /// did for the first flight.
    fn new_flight(&mut self) {
        self.ramp_from = None;
        self.planner = None;
        self.controller.reset_integrators();
        self.observer = self.observer_new.clone();
        self.following = false;
    }

    /// The planner's set point with the commander's position and climb speed (the planner
    /// keeps the attitude and the weight keys'), and the mass it flies with.
    fn guided_set_point(&mut self, est: &Estimate, hold: Horizontal) -> (SetPoint, f64) {
        let (g, spec) = (est.guidance, self.make_planner);
        let planner = self.planner.get_or_insert_with(|| {
            HoverPlanner::new(
                g.pos_m[2],
                est.theta_cal_rad,
                [g.pos_m[0], g.pos_m[1]],
                spec.mass_kg,
                spec.w_max_rad_s,
                spec.bounds,
            )
        });
        // A path is flown only on a position: without one its tilts and speeds would fly
        // the vehicle away from a place it cannot see.
        if let Some((point, _, _)) = g.path.filter(|_| hold == Horizontal::Position) {
            planner.follow(&point);
            self.following = true;
            return (planner.sp, planner.mass_kg());
        }
        // Off a path: its attitude, velocity and rates back to rest, its heading kept (the
        // manual keys move them again from there).
        if std::mem::take(&mut self.following) {
            planner.sp.x[3..].fill(0.0);
            planner.sp.x[crate::core::ekf::idx::THETA] = g.yaw_rad.unwrap_or(est.theta_cal_rad);
        }
        // The `altitude` mode's sticks: the tilt (none: level) and the heading they fly, at
        // every step (the set point goes back to rest when the mode is left, as off a path).
        if g.mode == crate::core::commander::Mode::Altitude {
            let [roll_rad, pitch_rad] = g.tilt_rad.unwrap_or([0.0, 0.0]);
            (planner.sp.x[3], planner.sp.x[4]) = (roll_rad, pitch_rad);
            planner.sp.x[crate::core::ekf::idx::THETA] = g.yaw_rad.unwrap_or(est.theta_cal_rad);
            self.following = true;
        }
        planner.sp.x[0] = g.pos_m[0];
        planner.sp.x[1] = g.pos_m[1];
        planner.sp.x[2] = g.pos_m[2];
        planner.sp.x[crate::core::ekf::idx::VQZ] = g.vz_m_s;
        planner.update_setpoint();
        planner.accelerate_up(g.az_m_s2);
        (planner.sp, planner.mass_kg())
    }

    /// T_s = this control step's time − the previous command's (ERRATA 8). The original's
    /// first step measured from the program's start and kept only the microseconds.
    fn period_us(&self, t_ctrl_us: i64) -> i64 {
        match self.prev {
            Some((_, _, t_prev_cmd)) => t_ctrl_us - t_prev_cmd,
            None if self.original_timing => t_ctrl_us.rem_euclid(1_000_000),
            None => NOMINAL_PERIOD_US,
        }
    }

    /// The horizontal position is held while a fix was fused lately (its velocity alone
    /// counts: the position is dead-reckoned on it) and the commander has not let it go (a
    /// lost GPS); else the velocity, while the filter observes it.
    fn horizontal_hold(&mut self, est: &Estimate) -> Horizontal {
        if est.gps_used || est.gps_velocity_used {
            self.last_gps_us = Some(est.t_us);
        }
        let fixes = self
            .last_gps_us
            .is_some_and(|t| est.t_us - t <= self.gps_hold_timeout_us);
        // The `altitude` mode's tilt is the pilot's: no position or velocity is held against it.
        if est.guidance.tilt_rad.is_some() {
            return Horizontal::Attitude;
        }
        // Without the gyro the attitude is the model's guess: a position or velocity held
        // on it asks for tilts that the guess does not see flown (a stop from a mission's
        // speed tumbled the vehicle). Level, the landing asks for no turn at all.
        if est.gyro_lost {
            return Horizontal::Attitude;
        }
        match (est.guidance.hold_xy && fixes, est.velocity_observed) {
            (true, _) => Horizontal::Position,
            (false, true) => Horizontal::Velocity,
            (false, false) => Horizontal::Attitude,
        }
    }

    /// The integrators and how many are meaningful.
    fn integrators(&self) -> ([f64; 4], usize) {
        let n_int = self.controller.x_int().len();
        let mut x_int = [0.0; 4];
        x_int[..n_int].copy_from_slice(self.controller.x_int());
        (x_int, n_int)
    }
}
