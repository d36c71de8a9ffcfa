//! A loaded profile, `Profile`: the validated configuration with its data files, and the core
//! objects (motor map, controller, estimator and controller cores, fake GPS) it describes.

use super::schema::{Config, GpsMode};
use crate::core::imu::calib::Calibration;
use std::path::PathBuf;

/// A validated configuration with the data files it names, loaded.
#[derive(Debug, Clone)]
pub struct Profile {
    /// The file it came from.
    pub path: PathBuf,
    /// The configuration with every path made absolute.
    pub config: Config,
    pub calib: Calibration,
    /// 4 × `control.states`, row-major (rows = motors).
    pub k_prop: Vec<f64>,
    /// 4 × the integrator count, row-major.
    pub k_int: Vec<f64>,
    /// LQR weights: 16 × 16 and 4 × 4, row-major.
    pub lqr_q: Vec<f64>,
    pub lqr_r: Vec<f64>,
    /// `gcs.signing_key_file`'s key (`None`: MAVLink 2 signing off).
    pub signing_key: Option<super::SigningKey>,
    /// The mission `start` flies (`--mission FILE`), with its gains.
    pub mission: Option<std::sync::Arc<super::LoadedMission>>,
}

impl Profile {
    /// The ESC wiring and trims.
    pub fn motor_map(&self) -> crate::core::motor::MotorMap {
        crate::core::motor::MotorMap {
            addresses: self.config.esc.addresses,
            trims: self.config.esc.trims,
        }
    }

    /// The controller this profile describes, with its integrators seeded.
    pub fn controller(&self) -> crate::core::control::Controller {
        let c = &self.config.control;
        let set = c
            .integrator_set()
            .unwrap_or(crate::core::control::Integrators::PsiPhiZTheta);
        // Shapes were checked at load, so this cannot fail for a loaded profile.
        crate::core::control::Controller::new(
            &self.k_prop,
            &self.k_int,
            c.states == 8,
            set,
            &c.integral_rules(),
            c.error_limits,
        )
        .unwrap_or_else(|e| unreachable!("gain shapes are validated at load: {e}"))
    }

    /// The estimator half of the flight loop.
    pub fn estimator_core(&self, skip_settle: bool) -> crate::core::flight::EstimatorCore {
        let c = &self.config;
        crate::core::flight::EstimatorCore::new(
            c.imu.startup_params(),
            self.calib.clone(),
            c.ekf.params(&c.imu),
            skip_settle,
        )
    }

    /// The controller half of the flight loop.
    pub fn controller_core(&self) -> crate::core::flight::ControllerCore {
        let c = &self.config;
        let core = crate::core::flight::ControllerCore::new(
            self.controller(),
            crate::core::flight::PlannerSpec {
                hover_z_m: c.control.hover_z_m,
                mass_kg: c.vehicle.mass_kg,
                w_max_rad_s: c.motor.w_max_rad_s,
                bounds: c.control.manual,
            },
            c.control.original_timing,
            (c.control.gps_hold_timeout_s * 1e6).round() as i64,
        );
        if c.control.torque_observer_s > 0.0 {
            core.with_torque_observer(c.control.torque_observer_s, c.motor.tau_s)
        } else {
            core
        }
    }

    /// The commander this profile describes, with its mission.
    pub fn commander(&self) -> crate::core::commander::Commander {
        let c = crate::core::commander::Commander::new(self.config.commander_params());
        match &self.mission {
            Some(m) => c.with_mission(m.plan.clone()),
            None => c,
        }
    }

    /// Positions of fake GPS samples for this profile's mode.
    pub fn fake_positions(&self) -> crate::core::gps::FakePositions {
        let g = &self.config.gps;
        match g.mode {
            GpsMode::FakeRandom => crate::core::gps::FakePositions::Random {
                rng: crate::core::gps::SplitMix64::new(g.seed),
                span_m: g.fake_span_m,
            },
            _ => crate::core::gps::FakePositions::Zero,
        }
    }
}
