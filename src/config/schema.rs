//! The configuration's schema: the serde structs and enums of every section, their defaults
//! and the accessors turning a section into the parameters of a core object.

use crate::core::control::{IntegralRule, ManualBounds};
use crate::core::imu::startup::StartupParams;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct Config {
    pub vehicle: Vehicle,
    pub imu: Imu,
    pub ekf: Ekf,
    pub control: Control,
    pub motor: Motor,
    pub esc: Esc,
    pub watchdog: WatchdogConfig,
    pub gps: Gps,
    pub sim: Sim,
    pub console: Console,
    pub log: Log,
    pub commander: super::CommanderConfig,
    pub failsafe: super::FailsafeConfig,
    pub fence: super::Fence,
    pub gcs: super::GcsConfig,
    pub mission: super::MissionConfig,
    pub rc: super::RcConfig,
}

/// The ESC writer (spec 6.3, 6.4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Esc {
    /// Linux I2C bus of the ESCs.
    pub bus: PathBuf,
    /// I2C addresses of motors m0..m3.
    pub addresses: [u8; 4],
    /// Trims added to the speed values of m0..m3 while running.
    pub trims: [i16; 4],
    /// Re-send period of the last speeds, ms (the ESCs stop when I2C traffic stops).
    pub resend_ms: u32,
    /// The writer's own refusal: a flight command whose frame is older than this is replaced
    /// by zero + disable, ms. A backup to the watchdog, which names the reason: it must leave
    /// the watchdog time to act (above its IMU timeout and its deadline + one IMU period).
    pub command_timeout_ms: u32,
}

/// The console socket served by `fly` and `sim`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct Console {
    /// Unix socket path (relative to the configuration's folder); empty = no console.
    pub socket: PathBuf,
}

/// The simulator (`uquad sim`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Sim {
    /// Simulated seconds flown by `uquad sim` without --duration (start-up included).
    pub duration_s: f64,
    /// The hover window of the report starts this long after the flight ramp ends, s.
    pub settle_s: f64,
    /// Physics steps per second (1000 or more).
    pub physics_hz: u32,
    /// Motor time constant, s.
    pub motor_tau_s: f64,
    /// Linear air drag, N per m/s.
    pub drag_n_per_m_s: f64,
    /// Steady wind (north, west, up), m/s.
    pub wind_m_s: [f64; 3],
    /// Sensor noise (standard deviations) and gyro bias.
    pub acc_noise_m_s2: f64,
    pub gyro_noise_rad_s: f64,
    pub gyro_bias_rad_s: [f64; 3],
    pub baro_noise_pa: f64,
    pub mag_noise: f64,
    /// The gyro's and accelerometer's bias random walk (rate random walk): the bias drifts by
    /// this much per √s, rad/s/√s and m/s²/√s; 0 holds the bias.
    pub gyro_bias_walk_rad_s_per_sqrt_s: f64,
    pub acc_bias_walk_m_s2_per_sqrt_s: f64,
    /// IMU temperature, °C.
    pub temp_c: f64,
    /// Heading at start, rad.
    pub initial_yaw_rad: f64,
    /// Seed of every random draw of the simulation.
    pub seed: u64,
    /// The `gust` fault: a push northward of this force, N, for this long, s.
    pub gust_n: f64,
    pub gust_s: f64,
    /// The `gps-glitch` fault: the receiver's position jumps this far north, m, for this
    /// long, s.
    pub gps_glitch_m: f64,
    pub gps_glitch_s: f64,
    /// The `gyro-bias` fault: the x gyro's bias steps by this much, rad/s.
    pub gyro_bias_step_rad_s: f64,
    /// The simulated receiver (`sim::gps`): fixes a second, delay, s; white noise and the
    /// wandering bias's spread (horizontal per axis, vertical), m; the bias's correlation
    /// time, s.
    pub gps_rate_hz: f64,
    pub gps_delay_s: f64,
    pub gps_noise_h_m: f64,
    pub gps_noise_v_m: f64,
    pub gps_bias_h_m: f64,
    pub gps_bias_v_m: f64,
    pub gps_bias_tau_s: f64,
    /// White noise of the receiver's velocity, per axis, m/s.
    pub gps_noise_vel_m_s: f64,
}

impl Default for Sim {
    fn default() -> Self {
        Sim {
            duration_s: 40.0,
            settle_s: 20.0,
            physics_hz: 1000,
            motor_tau_s: 0.03,
            drag_n_per_m_s: 0.1,
            wind_m_s: [0.0; 3],
            acc_noise_m_s2: 0.05,
            gyro_noise_rad_s: 0.003,
            gyro_bias_rad_s: [0.01, -0.005, 0.002],
            baro_noise_pa: 1.0,
            mag_noise: 0.005,
            gyro_bias_walk_rad_s_per_sqrt_s: 0.0,
            acc_bias_walk_m_s2_per_sqrt_s: 0.0,
            temp_c: 30.0,
            initial_yaw_rad: 0.3,
            seed: 1,
            gust_n: 3.0,
            gust_s: 3.0,
            gps_glitch_m: 20.0,
            gps_glitch_s: 10.0,
            gyro_bias_step_rad_s: 0.05,
            // A u-blox NEO-M8N (`sim::gps::GpsErrors::NEO_M8N`).
            gps_rate_hz: 1.0,
            gps_delay_s: 0.1,
            gps_noise_h_m: 0.7,
            gps_noise_v_m: 1.4,
            gps_bias_h_m: 2.0,
            gps_bias_v_m: 4.0,
            gps_bias_tau_s: 60.0,
            gps_noise_vel_m_s: 0.05,
        }
    }
}

/// The watchdog (its policy: `core::watchdog`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct WatchdogConfig {
    /// Longest time from a frame's arrival to its motor command, ms.
    pub deadline_ms: u32,
    /// Longest time without a frame while the motors run, ms.
    pub imu_timeout_ms: u32,
    /// Consecutive failed ESC write cycles that halt the motors.
    pub max_missed_acks: u32,
    /// Sanity (spec 2.5): IMU temperature limit, °C.
    pub sanity_temp_max_c: f64,
    /// Sanity: |ψ̂|, |φ̂| limit, rad.
    pub sanity_tilt_max_rad: f64,
    /// Sanity: insane steps (net) tolerated.
    pub sanity_max: u32,
    /// Consecutive refused EKF measurement updates that halt the motors.
    pub estimator_max_refused: u32,
    /// A stop (zero, then disable) is retried until every ESC acknowledged it, for at most
    /// this long, ms.
    pub halt_retry_ms: u32,
}

impl Default for WatchdogConfig {
    fn default() -> Self {
        let d = crate::core::watchdog::WatchdogParams::DEFAULT;
        WatchdogConfig {
            deadline_ms: (d.deadline_us / 1000) as u32,
            imu_timeout_ms: (d.imu_timeout_us / 1000) as u32,
            max_missed_acks: d.max_missed_acks,
            sanity_temp_max_c: d.temp_max_c,
            sanity_tilt_max_rad: d.tilt_max_rad,
            sanity_max: d.sanity_max,
            estimator_max_refused: d.estimator_max_refused,
            halt_retry_ms: 500,
        }
    }
}

impl WatchdogConfig {
    pub fn params(&self) -> crate::core::watchdog::WatchdogParams {
        crate::core::watchdog::WatchdogParams {
            deadline_us: i64::from(self.deadline_ms) * 1000,
            imu_timeout_us: i64::from(self.imu_timeout_ms) * 1000,
            max_missed_acks: self.max_missed_acks,
            temp_max_c: self.sanity_temp_max_c,
            tilt_max_rad: self.sanity_tilt_max_rad,
            sanity_max: self.sanity_max,
            estimator_max_refused: self.estimator_max_refused,
        }
    }
}

impl Config {
    /// The IMU calibrates at rest before arming (`imu.calibrate = "before-arm"`), unless the
    /// start is flying: that one arms at once, and calibrates after its ESC ramp whatever
    /// the key says.
    pub fn calibrates_before_arm(&self) -> bool {
        self.imu.calibrate == crate::core::imu::startup::CalibrateWhen::BeforeArm
            && self.commander.start != crate::core::commander::Start::Flying
    }

    /// The ESC driver's timing: its re-send period, its stale-command timeout and how long a
    /// stop is retried.
    pub fn esc_timing(&self) -> crate::core::esc::EscTiming {
        crate::core::esc::EscTiming {
            resend_us: i64::from(self.esc.resend_ms) * 1000,
            command_timeout_us: i64::from(self.esc.command_timeout_ms) * 1000,
            halt_retry_us: i64::from(self.watchdog.halt_retry_ms) * 1000,
        }
    }
}

impl Default for Esc {
    fn default() -> Self {
        let m = crate::core::motor::MotorMap::UQUAD;
        Esc {
            bus: PathBuf::from("/dev/i2c-2"),
            addresses: m.addresses,
            trims: m.trims,
            resend_ms: 2,
            command_timeout_ms: 25,
        }
    }
}

/// Log streams.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Log {
    /// Folder under which each run gets its own `<run-id>` folder.
    pub dir: PathBuf,
    /// Records each stream may queue before new ones are dropped (and counted).
    pub queue_records: u32,
}

impl Default for Log {
    fn default() -> Self {
        Log {
            dir: PathBuf::from("logs"),
            queue_records: 256,
        }
    }
}

/// The estimator (spec 3). Diagonals of the noise matrices, in state / measurement order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Ekf {
    /// Keep the original's model quirks its logs depend on (the cψ·cψ term of 3.3).
    pub original_model: bool,
    /// Process noise Q, 15 values.
    pub q: [f64; 15],
    /// IMU measurement noise R, 10 values: ψ φ θ ax ay az ωx ωy ωz alt.
    pub r_imu: [f64; 10],
    /// IMU + GPS measurement noise, 12 values: the first nine of r_imu, then GPS x y z.
    pub r_gps: [f64; 12],
    /// Initial covariance P₀, 15 values.
    pub p0: [f64; 15],
    /// Width of the innovation gate, standard deviations of the innovation.
    pub gate_sigma: f64,
    /// Leave a measurement group outside the gate out of the step's update.
    pub gate_fusion: bool,
    /// "joint": a fix with the IMU rows into every state (the 2012 flights); "position-velocity":
    /// after them, into position and velocity only.
    pub gps_fusion: crate::core::ekf::GpsFusion,
    /// With "position-velocity": noise of the receiver's velocity (the vertical only while the
    /// barometer is lost), (m/s)².
    pub r_gps_vel: f64,
    /// Drag per m/s of airspeed, 1/s (PX4's EKF2_MCOEF): without fixes it holds the
    /// horizontal velocity; 0: off.
    pub drag_per_s: f64,
    /// Fuse the ground's height and a still body while the vehicle rests on it disarmed or
    /// landed, and a body that does not turn (the gyros' bias) armed on it too.
    pub ground_fusion: bool,
    /// Their noise: height (m²), each body velocity ((m/s)²).
    pub r_ground: [f64; 2],
    /// Fuse the IMU's angles once every this many seconds; 0: every step (the 2012 flights).
    pub angle_period_s: f64,
    /// The gyros' bias states: process noise per step and initial variance, (rad/s)²; both
    /// 0: none (the 2012 flights).
    pub q_gyro_bias: f64,
    pub p0_gyro_bias: f64,
    /// The receiver's horizontal bias states, with "position-velocity": the bias's standard
    /// deviation σ per axis, m (0: none, the 2012 flights).
    pub gps_bias_m: f64,
    /// The bias's correlation time, s.
    pub gps_bias_tau_s: f64,
    /// The IMU's roll and pitch noise while the vehicle rests on the ground, rad²; 0: the
    /// flight's (`r_imu`), as the 2012 flights.
    pub r_angles_rest: f64,
    /// The noise of each axis of the magnetometer's direction where it holds the tilt (no
    /// fix in the air, or no gyro); 0: never used, as the 2012 flights.
    pub r_field: f64,
}

impl Default for Ekf {
    fn default() -> Self {
        let p = crate::core::ekf::EkfParams::flight_2012();
        Ekf {
            original_model: false,
            q: p.q_diag,
            r_imu: p.r_imu_diag,
            r_gps: p.r_gps_diag,
            p0: p.p0_diag,
            gate_sigma: p.gate_sigma,
            // As the default profile: the 2012 flights fused everything, uquad gates.
            gate_fusion: true,
            gps_fusion: p.gps_fusion,
            r_gps_vel: p.r_gps_vel,
            drag_per_s: p.drag_per_s,
            ground_fusion: p.ground_fusion,
            r_ground: p.r_ground,
            angle_period_s: p.angle_period_s,
            q_gyro_bias: p.gyro_bias_q,
            p0_gyro_bias: p.gyro_bias_p0,
            gps_bias_m: p.gps_bias_m,
            gps_bias_tau_s: p.gps_bias_tau_s,
            r_angles_rest: p.r_angles_rest,
            r_field: p.r_field,
        }
    }
}

impl Ekf {
    /// The filter parameters; the dt clamp is the accepted IMU period (spec 3.9).
    pub fn params(&self, imu: &Imu) -> crate::core::ekf::EkfParams {
        crate::core::ekf::EkfParams {
            original_model: self.original_model,
            q_diag: self.q,
            r_imu_diag: self.r_imu,
            r_gps_diag: self.r_gps,
            p0_diag: self.p0,
            dt_min_us: i64::from(imu.period_min_us),
            dt_max_us: i64::from(imu.period_max_us),
            gate_sigma: self.gate_sigma,
            gate_fusion: self.gate_fusion,
            gps_fusion: self.gps_fusion,
            r_gps_vel: self.r_gps_vel,
            drag_per_s: self.drag_per_s,
            ground_fusion: self.ground_fusion,
            r_ground: self.r_ground,
            angle_period_s: self.angle_period_s,
            gyro_bias_q: self.q_gyro_bias,
            gyro_bias_p0: self.p0_gyro_bias,
            gps_bias_m: self.gps_bias_m,
            gps_bias_tau_s: self.gps_bias_tau_s,
            r_angles_rest: self.r_angles_rest,
            r_field: self.r_field,
        }
    }
}

/// Motors (spec 4.2, 6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Motor {
    /// Highest motor speed, rad/s; also sets w_min = 2·w_hover − w_max.
    pub w_max_rad_s: f64,
    /// The motors' first-order time constant (command to speed), s, as the torque observer
    /// models it.
    pub tau_s: f64,
}

impl Default for Motor {
    fn default() -> Self {
        Motor {
            w_max_rad_s: crate::core::model::W_MAX_2012_RAD_S,
            tau_s: 0.03,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Vehicle {
    /// Take-off mass, kg.
    pub mass_kg: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Imu {
    /// Serial device of the IMU (115200 8N1 raw).
    pub device: PathBuf,
    /// Baud rate.
    pub baud: u32,
    /// `imu_calib.txt` (45 numbers, spec 2.1).
    pub calib_file: PathBuf,
    /// Consecutive in-range frame intervals required before calibrating.
    pub settle_frames: u32,
    /// Frames after which settling gives up.
    pub settle_max_frames: u32,
    /// Time after which settling gives up, s.
    pub settle_timeout_s: f64,
    /// Accepted frame interval, µs.
    pub period_min_us: u32,
    pub period_max_us: u32,
    /// Frames averaged into the start-up null sample.
    pub calib_frames: u32,
    /// How their pressures are averaged: "truncated" (the original's integer division) or
    /// "exact".
    pub null_pressure: crate::core::imu::calib::NullPressure,
    /// When the null sample is taken: "before-arm" (at rest, the estimator running from then
    /// on) or "after-arm" (motors idling, the original's order).
    pub calibrate: crate::core::imu::startup::CalibrateWhen,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Control {
    /// Controlled states: 12 (full) or 8 (z, ψ, φ, θ, vqz, wqx, wqy, wqz).
    pub states: u32,
    /// Integrated states, in gain-file column order: "psi,phi,z,theta" or "x,y,z,theta"
    /// (12 states), "z,theta" (8 states).
    pub integrators: String,
    /// The first control step's T_s is the microseconds part of its time since start (the
    /// original's quirk, ERRATA 8); false uses the nominal 10 ms.
    pub original_timing: bool,
    /// Clamp the errors as the later version did (|e_x|, |e_y| ≤ 18 m, |e_z| ≤ 4 m,
    /// |e_θ| ≤ 1.05 rad).
    pub error_limits: bool,
    /// Proportional gain matrix, 4 × states (rows = motors).
    pub k_prop_file: PathBuf,
    /// Integral gain matrix, 4 × integrators.
    pub k_int_file: PathBuf,
    /// LQR state weights, 16 × 16 (12 states, then the 4 integrators), for `uquad lqr`.
    pub lqr_q_file: PathBuf,
    /// LQR input weights, 4 × 4.
    pub lqr_r_file: PathBuf,
    /// Hover altitude set point above the start altitude, m.
    pub hover_z_m: f64,
    /// The horizontal position is held only while a GPS fix was fused within this long, s.
    pub gps_hold_timeout_s: f64,
    /// Time constant of the roll, pitch and yaw torque-disturbance observer, s; 0 = off (the
    /// original).
    pub torque_observer_s: f64,
    pub integral: Integrals,
    /// Bounds on how far manual commands may move the set point (spec 5.2).
    pub manual: ManualBounds,
}

impl Control {
    /// The integrator set named by `integrators` (validated at load).
    pub fn integrator_set(&self) -> Option<crate::core::control::Integrators> {
        crate::core::control::Integrators::parse(&self.integrators)
    }

    /// The rule of each integrated state, in gain-file column order.
    pub fn integral_rules(&self) -> Vec<IntegralRule> {
        let i = &self.integral;
        let by_state = |state: usize| match state {
            0 => i.x,
            1 => i.y,
            2 => i.z,
            3 => i.psi,
            4 => i.phi,
            _ => i.theta,
        };
        self.integrator_set()
            .map(|set| set.states())
            .unwrap_or(&[])
            .iter()
            .map(|&s| by_state(s))
            .collect()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Integrals {
    pub psi: IntegralRule,
    pub phi: IntegralRule,
    pub z: IntegralRule,
    pub theta: IntegralRule,
    pub x: IntegralRule,
    pub y: IntegralRule,
}

/// Where the estimator's GPS samples come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GpsMode {
    Off,
    FakeZero,
    FakeRandom,
    Gpsd,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Gps {
    pub mode: GpsMode,
    /// gpsd's address (gps.mode = "gpsd").
    pub server: String,
    /// Seed of the fake-random positions.
    pub seed: u64,
    /// Span of the fake-random positions (`GPS_RAND_PP`), m.
    pub fake_span_m: f64,
}

impl Default for Vehicle {
    fn default() -> Self {
        Vehicle { mass_kg: 1.55 }
    }
}

impl Default for Imu {
    fn default() -> Self {
        let p = StartupParams::ORIGINAL;
        Imu {
            device: PathBuf::from("/dev/ttyS1"),
            baud: 115_200,
            calib_file: PathBuf::from("imu_calib.txt"),
            settle_frames: p.settle_frames,
            settle_max_frames: p.settle_max_frames,
            settle_timeout_s: p.settle_timeout_us as f64 / 1e6,
            period_min_us: p.period_min_us as u32,
            period_max_us: p.period_max_us as u32,
            calib_frames: p.calib_frames,
            null_pressure: p.null_pressure,
            calibrate: crate::core::imu::startup::CalibrateWhen::AfterArm,
        }
    }
}

impl Default for Control {
    fn default() -> Self {
        Control {
            states: 12,
            integrators: "psi,phi,z,theta".to_string(),
            error_limits: true,
            original_timing: false,
            manual: ManualBounds::default(),
            k_prop_file: PathBuf::from("K_prop_full_ppzt.txt"),
            k_int_file: PathBuf::from("K_int_full_ppzt.txt"),
            lqr_q_file: PathBuf::from("lqr-Q.txt"),
            lqr_r_file: PathBuf::from("lqr-R.txt"),
            hover_z_m: 1.0,
            gps_hold_timeout_s: 3.0,
            torque_observer_s: 0.0,
            integral: Integrals::default(),
        }
    }
}

impl Default for Integrals {
    /// The later version's rules (spec 4.4 table), thresholds on.
    fn default() -> Self {
        Integrals {
            psi: IntegralRule::new(1e-3, 1.0, Some(0.26)),
            phi: IntegralRule::new(1e-3, 1.0, Some(0.26)),
            z: IntegralRule::new(2.5e-3, 2.0, Some(2.0)),
            theta: IntegralRule::new(7e-3, 2.0, Some(0.78)),
            x: IntegralRule::new(1.0, 5.0, Some(1.0)),
            y: IntegralRule::new(1.0, 5.0, Some(1.0)),
        }
    }
}

impl Default for Gps {
    fn default() -> Self {
        Gps {
            mode: GpsMode::FakeZero,
            server: "127.0.0.1:2947".to_string(),
            seed: 1,
            fake_span_m: 1.0,
        }
    }
}

impl Imu {
    pub fn startup_params(&self) -> StartupParams {
        StartupParams {
            settle_frames: self.settle_frames,
            settle_max_frames: self.settle_max_frames,
            settle_timeout_us: (self.settle_timeout_s * 1e6).round() as i64,
            period_min_us: i64::from(self.period_min_us),
            period_max_us: i64::from(self.period_max_us),
            calib_frames: self.calib_frames,
            null_pressure: self.null_pressure,
        }
    }
}
