//! Configuration profiles: `config/*.toml`, parsed with serde, overridden with `--set`,
//! validated at load, with the data files they name (calibration, gains) loaded and checked.
//!
//! Every problem found is reported, one line each, naming the file and the key (or the
//! position of a malformed number in a data file). Relative paths resolve against the folder
//! of the configuration file.

use crate::core::control::{IntegralRule, Integrators, ManualBounds};
use crate::core::imu::calib::{CALIB_NUMBERS, Calibration};
use crate::core::imu::startup::StartupParams;
use crate::core::numfile;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

/// Default configuration used when a command gets no `--config`.
pub const DEFAULT_CONFIG: &str = "config/uquad.toml";

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
    /// IMU temperature, °C.
    pub temp_c: f64,
    /// Heading at start, rad.
    pub initial_yaw_rad: f64,
    /// Seed of every random draw of the simulation.
    pub seed: u64,
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
            temp_c: 30.0,
            initial_yaw_rad: 0.3,
            seed: 1,
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
        }
    }
}

/// One problem in a configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// The file the problem is in (the configuration or a data file it names).
    pub file: PathBuf,
    /// The configuration key concerned, when there is one.
    pub key: Option<String>,
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: ", self.file.display())?;
        if let Some(k) = &self.key {
            write!(f, "{k}: ")?;
        }
        f.write_str(&self.message)
    }
}

/// Every problem found while loading a configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    pub problems: Vec<Problem>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, p) in self.problems.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{p}")?;
        }
        Ok(())
    }
}

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

/// Parses a `--set KEY=VALUE` argument: a dotted key and a TOML value. A value that is not
/// valid TOML is taken as a string, so `--set gps.mode=fake-zero` works without quotes.
pub fn parse_set(arg: &str) -> Result<(String, toml::Value), String> {
    let (key, value) = arg
        .split_once('=')
        .ok_or_else(|| format!("--set {arg:?}: expected KEY=VALUE"))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(|p| p.trim().is_empty()) {
        return Err(format!(
            "--set {arg:?}: the key must be dotted names like vehicle.mass_kg"
        ));
    }
    let value = value.trim();
    let parsed = toml::from_str::<toml::Table>(&format!("v = {value}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(value.to_string()));
    Ok((key.to_string(), parsed))
}

fn set_dotted(table: &mut toml::Table, key: &str, value: toml::Value) -> Result<(), String> {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            cur.insert((*part).to_string(), value);
            return Ok(());
        }
        let entry = cur
            .entry((*part).to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = entry
            .as_table_mut()
            .ok_or_else(|| format!("{} is not a table", parts[..=i].join(".")))?;
    }
    Ok(())
}

fn remove_dotted(table: &mut toml::Table, key: &str) -> bool {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            return cur.remove(*part).is_some();
        }
        match cur.get_mut(*part).and_then(|v| v.as_table_mut()) {
            Some(t) => cur = t,
            None => return false,
        }
    }
    false
}

/// Picks the configuration file: the given one, else `config/uquad.toml` under the working
/// directory when it exists.
pub fn resolve_path(given: Option<&Path>) -> Result<PathBuf, String> {
    match given {
        Some(p) => Ok(p.to_path_buf()),
        None if Path::new(DEFAULT_CONFIG).is_file() => Ok(PathBuf::from(DEFAULT_CONFIG)),
        None => Err(format!(
            "no --config given and {DEFAULT_CONFIG} does not exist under the working directory"
        )),
    }
}

/// Loads, overrides, validates and resolves a configuration file and its data files.
pub fn load(path: &Path, sets: &[(String, toml::Value)]) -> Result<Profile, ConfigError> {
    let problem = |key: Option<&str>, message: String| Problem {
        file: path.to_path_buf(),
        key: key.map(str::to_string),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
        problems: vec![problem(None, format!("cannot read the configuration: {e}"))],
    })?;
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| ConfigError {
        problems: vec![problem(
            None,
            format!("not valid TOML: {}", e.to_string().trim()),
        )],
    })?;
    let mut problems = Vec::new();
    for (key, value) in sets {
        if let Err(e) = set_dotted(&mut table, key, value.clone()) {
            problems.push(problem(Some(key), format!("--set cannot apply: {e}")));
        }
    }
    let from_set = |key: &str| sets.iter().any(|(k, _)| k == key);
    let origin = |key: &str| {
        if from_set(key) { " (from --set)" } else { "" }
    };

    // Deserialise; on a type error note it, drop the key (its default applies) and go on, so
    // every bad value is reported rather than only the first.
    let mut unknown: Vec<String> = Vec::new();
    let config = loop {
        unknown.clear();
        let mut track = serde_path_to_error::Track::new();
        let de =
            serde_path_to_error::Deserializer::new(toml::Value::Table(table.clone()), &mut track);
        let result: Result<Config, _> =
            serde_ignored::deserialize(de, |p| unknown.push(p.to_string()));
        match result {
            Ok(c) => break c,
            Err(e) => {
                let key = track.path().to_string();
                // The first line is the problem; the rest repeats the key we already name.
                let full = e.to_string();
                let msg = full
                    .lines()
                    .next()
                    .unwrap_or("invalid value")
                    .trim()
                    .to_string();
                problems.push(problem(Some(&key), format!("{msg}{}", origin(&key))));
                if key.is_empty() || key == "." || !remove_dotted(&mut table, &key) {
                    return Err(ConfigError { problems });
                }
            }
        }
    };
    for key in &unknown {
        problems.push(problem(Some(key), format!("unknown key{}", origin(key))));
    }

    let mut c = config;
    let mut range = |key: &str, ok: bool, value: String, allowed: &str| {
        if !ok {
            problems.push(problem(
                Some(key),
                format!("{value} is out of range{}: allowed {allowed}", origin(key)),
            ));
        }
    };
    let m = c.vehicle.mass_kg;
    range(
        "vehicle.mass_kg",
        m.is_finite() && (0.1..=2.3).contains(&m),
        m.to_string(),
        "0.1 to 2.3 kg (at 368 rad/s the motors lift at most 2.38 kg)",
    );
    let z = c.control.hover_z_m;
    range(
        "control.hover_z_m",
        z.is_finite() && (0.0..=10.0).contains(&z),
        z.to_string(),
        "0 to 10 m",
    );
    let to = c.control.gps_hold_timeout_s;
    range(
        "control.gps_hold_timeout_s",
        to.is_finite() && to > 0.0 && to <= 3600.0,
        to.to_string(),
        "more than 0, at most 3600 s",
    );
    let mt = c.motor.tau_s;
    range(
        "motor.tau_s",
        mt.is_finite() && mt > 0.0 && mt <= 1.0,
        mt.to_string(),
        "more than 0, at most 1 s",
    );
    let tau = c.control.torque_observer_s;
    range(
        "control.torque_observer_s",
        tau == 0.0 || (tau.is_finite() && (0.01..=10.0).contains(&tau)),
        tau.to_string(),
        "0 (off) or 0.01 to 10 s",
    );
    // Bounds relative to another key are checked only when that key is itself valid, so one
    // bad value is reported once.
    let m_ok = m.is_finite() && (0.1..=2.3).contains(&m);
    let z_ok = z.is_finite() && (0.0..=10.0).contains(&z);
    let imu = &c.imu;
    range(
        "imu.settle_frames",
        imu.settle_frames <= 10_000,
        imu.settle_frames.to_string(),
        "0 to 10000 frames",
    );
    range(
        "imu.settle_max_frames",
        imu.settle_max_frames >= imu.settle_frames && imu.settle_max_frames <= 100_000,
        imu.settle_max_frames.to_string(),
        "imu.settle_frames to 100000 frames",
    );
    range(
        "imu.settle_timeout_s",
        imu.settle_timeout_s.is_finite()
            && imu.settle_timeout_s > 0.0
            && imu.settle_timeout_s <= 600.0,
        imu.settle_timeout_s.to_string(),
        "more than 0, at most 600 s",
    );
    range(
        "imu.period_min_us",
        (1_000..=100_000).contains(&imu.period_min_us),
        imu.period_min_us.to_string(),
        "1000 to 100000 µs",
    );
    range(
        "imu.period_max_us",
        imu.period_max_us > imu.period_min_us && imu.period_max_us <= 100_000,
        imu.period_max_us.to_string(),
        "above imu.period_min_us, at most 100000 µs",
    );
    range(
        "imu.calib_frames",
        (6..=100_000).contains(&imu.calib_frames),
        imu.calib_frames.to_string(),
        "6 to 100000 frames (at least the FIR length)",
    );
    range(
        "imu.baud",
        [9_600, 19_200, 38_400, 57_600, 115_200, 230_400].contains(&c.imu.baud),
        c.imu.baud.to_string(),
        "one of 9600, 19200, 38400, 57600, 115200, 230400",
    );
    let esc = &c.esc;
    for (i, a) in esc.addresses.iter().enumerate() {
        range(
            &format!("esc.addresses[{i}]"),
            (0x08..=0x77).contains(a),
            format!("0x{a:02x}"),
            "a 7-bit I2C address, 0x08 to 0x77",
        );
    }
    let mut sorted = esc.addresses;
    sorted.sort_unstable();
    range(
        "esc.addresses",
        sorted.windows(2).all(|w| w[0] != w[1]),
        format!("{:?}", esc.addresses),
        "four different addresses",
    );
    for (i, t) in esc.trims.iter().enumerate() {
        range(
            &format!("esc.trims[{i}]"),
            (-50..=50).contains(t),
            t.to_string(),
            "-50 to 50",
        );
    }
    range(
        "esc.resend_ms",
        (1..=20).contains(&esc.resend_ms),
        esc.resend_ms.to_string(),
        "1 to 20 ms",
    );
    let wd = &c.watchdog;
    range(
        "watchdog.deadline_ms",
        (1..=1000).contains(&wd.deadline_ms),
        wd.deadline_ms.to_string(),
        "1 to 1000 ms",
    );
    range(
        "watchdog.imu_timeout_ms",
        wd.imu_timeout_ms > esc.resend_ms && wd.imu_timeout_ms <= 1000,
        wd.imu_timeout_ms.to_string(),
        "above esc.resend_ms, at most 1000 ms",
    );
    range(
        "esc.command_timeout_ms",
        esc.command_timeout_ms > wd.imu_timeout_ms
            && esc.command_timeout_ms > wd.deadline_ms + 10
            && esc.command_timeout_ms <= 2000,
        esc.command_timeout_ms.to_string(),
        "above watchdog.imu_timeout_ms and watchdog.deadline_ms + 10, at most 2000 ms",
    );
    range(
        "watchdog.max_missed_acks",
        (1..=1000).contains(&wd.max_missed_acks),
        wd.max_missed_acks.to_string(),
        "1 to 1000",
    );
    range(
        "watchdog.sanity_temp_max_c",
        wd.sanity_temp_max_c.is_finite() && (0.0..=125.0).contains(&wd.sanity_temp_max_c),
        wd.sanity_temp_max_c.to_string(),
        "0 to 125 °C",
    );
    range(
        "watchdog.sanity_tilt_max_rad",
        wd.sanity_tilt_max_rad.is_finite()
            && wd.sanity_tilt_max_rad > 0.0
            && wd.sanity_tilt_max_rad <= 1.57,
        wd.sanity_tilt_max_rad.to_string(),
        "more than 0, at most 1.57 rad",
    );
    range(
        "watchdog.sanity_max",
        wd.sanity_max <= 10_000,
        wd.sanity_max.to_string(),
        "0 to 10000",
    );
    range(
        "log.queue_records",
        (1..=1_000_000).contains(&c.log.queue_records),
        c.log.queue_records.to_string(),
        "1 to 1000000",
    );
    let w_max = c.motor.w_max_rad_s;
    range(
        "motor.w_max_rad_s",
        w_max.is_finite() && (100.0..=1000.0).contains(&w_max),
        w_max.to_string(),
        "100 to 1000 rad/s",
    );
    let w_hover = crate::core::model::w_hover_rad_s(m);
    range(
        "vehicle.mass_kg",
        !m_ok || !w_max.is_finite() || w_hover < w_max,
        format!("{m} (hover needs {w_hover:.1} rad/s)"),
        "a mass that hovers below motor.w_max_rad_s",
    );
    range(
        "gps.server",
        c.gps
            .server
            .rsplit_once(':')
            .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok()),
        format!("{:?}", c.gps.server),
        "HOST:PORT, e.g. 127.0.0.1:2947",
    );
    let sim = &c.sim;
    let nonneg = |v: f64, hi: f64| v.is_finite() && (0.0..=hi).contains(&v);
    range(
        "sim.duration_s",
        sim.duration_s.is_finite() && sim.duration_s > 0.0 && sim.duration_s <= 86_400.0,
        sim.duration_s.to_string(),
        "more than 0, at most 86400 s",
    );
    range(
        "sim.settle_s",
        nonneg(sim.settle_s, 3600.0),
        sim.settle_s.to_string(),
        "0 to 3600 s",
    );
    range(
        "sim.physics_hz",
        (1000..=100_000).contains(&sim.physics_hz)
            && 1_000_000 % sim.physics_hz == 0
            && (sim.physics_hz / 100) % 2 == 0,
        sim.physics_hz.to_string(),
        "1000 to 100000, dividing 1 s into whole µs and each 5 ms into whole steps",
    );
    range(
        "sim.motor_tau_s",
        sim.motor_tau_s.is_finite() && sim.motor_tau_s > 0.0 && sim.motor_tau_s <= 1.0,
        sim.motor_tau_s.to_string(),
        "more than 0, at most 1 s",
    );
    range(
        "sim.drag_n_per_m_s",
        nonneg(sim.drag_n_per_m_s, 10.0),
        sim.drag_n_per_m_s.to_string(),
        "0 to 10 N per m/s",
    );
    range(
        "sim.wind_m_s",
        sim.wind_m_s
            .iter()
            .all(|w| w.is_finite() && w.abs() <= 30.0),
        format!("{:?}", sim.wind_m_s),
        "each within ±30 m/s",
    );
    range(
        "sim.acc_noise_m_s2",
        nonneg(sim.acc_noise_m_s2, 10.0),
        sim.acc_noise_m_s2.to_string(),
        "0 to 10 m/s²",
    );
    range(
        "sim.gyro_noise_rad_s",
        nonneg(sim.gyro_noise_rad_s, 1.0),
        sim.gyro_noise_rad_s.to_string(),
        "0 to 1 rad/s",
    );
    range(
        "sim.gyro_bias_rad_s",
        sim.gyro_bias_rad_s
            .iter()
            .all(|b| b.is_finite() && b.abs() <= 1.0),
        format!("{:?}", sim.gyro_bias_rad_s),
        "each within ±1 rad/s",
    );
    range(
        "sim.baro_noise_pa",
        nonneg(sim.baro_noise_pa, 1000.0),
        sim.baro_noise_pa.to_string(),
        "0 to 1000 Pa",
    );
    range(
        "sim.mag_noise",
        nonneg(sim.mag_noise, 1.0),
        sim.mag_noise.to_string(),
        "0 to 1",
    );
    range(
        "sim.temp_c",
        sim.temp_c.is_finite() && (-20.0..=50.0).contains(&sim.temp_c),
        sim.temp_c.to_string(),
        "-20 to 50 °C",
    );
    range(
        "sim.initial_yaw_rad",
        sim.initial_yaw_rad.is_finite() && sim.initial_yaw_rad.abs() <= 3.2,
        sim.initial_yaw_rad.to_string(),
        "within ±3.2 rad",
    );
    let span = c.gps.fake_span_m;
    range(
        "gps.fake_span_m",
        span.is_finite() && (0.0..=100.0).contains(&span),
        span.to_string(),
        "0 to 100 m",
    );
    let diag_lists: [(&str, &[f64]); 4] = [
        ("ekf.q", &c.ekf.q),
        ("ekf.r_imu", &c.ekf.r_imu),
        ("ekf.r_gps", &c.ekf.r_gps),
        ("ekf.p0", &c.ekf.p0),
    ];
    for (key, values) in diag_lists {
        for (i, v) in values.iter().enumerate() {
            range(
                &format!("{key}[{i}]"),
                v.is_finite() && *v > 0.0 && *v <= 1e12,
                v.to_string(),
                "more than 0, at most 1e12 (a variance)",
            );
        }
    }
    let set = c.control.integrator_set();
    let states_ok = matches!(
        (c.control.states, set),
        (12, Some(Integrators::PsiPhiZTheta | Integrators::XYZTheta))
            | (8, Some(Integrators::ZTheta))
    );
    if !matches!(c.control.states, 8 | 12) {
        range(
            "control.states",
            false,
            c.control.states.to_string(),
            "12 (full) or 8 (reduced)",
        );
    } else if !states_ok {
        range(
            "control.integrators",
            false,
            format!("{:?}", c.control.integrators),
            if c.control.states == 12 {
                "\"psi,phi,z,theta\" or \"x,y,z,theta\" with control.states = 12"
            } else {
                "\"z,theta\" with control.states = 8"
            },
        );
    }
    let man = &c.control.manual;
    range(
        "control.manual.max_tilt_rad",
        man.max_tilt_rad.is_finite() && (0.0..=1.0).contains(&man.max_tilt_rad),
        man.max_tilt_rad.to_string(),
        "0 to 1 rad (the sanity check trips at 1 rad)",
    );
    range(
        "control.manual.max_yaw_offset_rad",
        man.max_yaw_offset_rad.is_finite() && (0.0..=6.3).contains(&man.max_yaw_offset_rad),
        man.max_yaw_offset_rad.to_string(),
        "0 to 6.3 rad",
    );
    range(
        "control.manual.z_min_m",
        man.z_min_m.is_finite() && man.z_min_m >= 0.0 && (!z_ok || man.z_min_m <= z),
        man.z_min_m.to_string(),
        "0 up to control.hover_z_m",
    );
    range(
        "control.manual.z_max_m",
        man.z_max_m.is_finite() && (!z_ok || man.z_max_m >= z) && man.z_max_m <= 20.0,
        man.z_max_m.to_string(),
        "control.hover_z_m up to 20 m",
    );
    range(
        "control.manual.mass_min_kg",
        man.mass_min_kg.is_finite() && man.mass_min_kg >= 0.1 && (!m_ok || man.mass_min_kg <= m),
        man.mass_min_kg.to_string(),
        "0.1 kg up to vehicle.mass_kg",
    );
    range(
        "control.manual.mass_max_kg",
        man.mass_max_kg.is_finite() && (!m_ok || man.mass_max_kg >= m) && man.mass_max_kg <= 2.3,
        man.mass_max_kg.to_string(),
        "vehicle.mass_kg up to 2.3 kg",
    );
    let rules = [
        ("psi", c.control.integral.psi),
        ("phi", c.control.integral.phi),
        ("z", c.control.integral.z),
        ("theta", c.control.integral.theta),
        ("x", c.control.integral.x),
        ("y", c.control.integral.y),
    ];
    for (name, r) in rules {
        let k = |leaf: &str| format!("control.integral.{name}.{leaf}");
        range(
            &k("step_max"),
            r.step_max.is_finite() && r.step_max > 0.0 && r.step_max <= 10.0,
            r.step_max.to_string(),
            "more than 0, at most 10",
        );
        range(
            &k("cap"),
            r.cap.is_finite() && r.cap > 0.0 && r.cap <= 100.0,
            r.cap.to_string(),
            "more than 0, at most 100",
        );
        if let Some(t) = r.threshold {
            range(
                &k("threshold"),
                t.is_finite() && t > 0.0,
                t.to_string(),
                "more than 0 (leave the key out for no threshold)",
            );
        }
        range(
            &k("seed"),
            r.seed.is_finite() && r.seed.abs() <= r.cap,
            r.seed.to_string(),
            "within ± the cap",
        );
    }

    // Resolve and load the data files.
    let base = path
        .parent()
        .map(|p| {
            if p.as_os_str().is_empty() {
                Path::new(".")
            } else {
                p
            }
        })
        .unwrap_or(Path::new("."));
    let base = std::fs::canonicalize(base).unwrap_or_else(|_| base.to_path_buf());
    let resolve = |p: &Path| {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            base.join(p)
        }
    };
    c.imu.calib_file = resolve(&c.imu.calib_file);
    c.log.dir = resolve(&c.log.dir);
    if !c.console.socket.as_os_str().is_empty() {
        c.console.socket = resolve(&c.console.socket);
    }
    c.control.k_prop_file = resolve(&c.control.k_prop_file);
    c.control.k_int_file = resolve(&c.control.k_int_file);
    c.control.lqr_q_file = resolve(&c.control.lqr_q_file);
    c.control.lqr_r_file = resolve(&c.control.lqr_r_file);

    let mut load_numbers = |key: &str, file: &Path, count: usize| -> Option<Vec<f64>> {
        let text = match std::fs::read_to_string(file) {
            Ok(t) => t,
            Err(e) => {
                problems.push(problem(
                    Some(key),
                    format!("cannot read {}: {e}", file.display()),
                ));
                return None;
            }
        };
        match numfile::parse_exact(&text, count) {
            Ok(n) => Some(n),
            Err(e) => {
                problems.push(Problem {
                    file: file.to_path_buf(),
                    key: Some(key.to_string()),
                    message: e.to_string(),
                });
                None
            }
        }
    };
    let calib = load_numbers("imu.calib_file", &c.imu.calib_file.clone(), CALIB_NUMBERS)
        .map(|n| Calibration::from_numbers(&n));
    // The original read exactly rows × cols numbers and ignored the rest (spec 4.3).
    let n_states = if c.control.states == 8 { 8 } else { 12 };
    let n_int = set.map_or(4, |s| s.states().len());
    let k_prop = load_numbers(
        "control.k_prop_file",
        &c.control.k_prop_file.clone(),
        4 * n_states,
    );
    let k_int = load_numbers(
        "control.k_int_file",
        &c.control.k_int_file.clone(),
        4 * n_int,
    );
    let lqr_q = load_numbers("control.lqr_q_file", &c.control.lqr_q_file.clone(), 256);
    let lqr_r = load_numbers("control.lqr_r_file", &c.control.lqr_r_file.clone(), 16);

    match (calib, k_prop, k_int, lqr_q, lqr_r) {
        (Some(calib), Some(k_prop), Some(k_int), Some(lqr_q), Some(lqr_r))
            if problems.is_empty() =>
        {
            Ok(Profile {
                path: path.to_path_buf(),
                config: c,
                calib,
                k_prop,
                k_int,
                lqr_q,
                lqr_r,
            })
        }
        _ => Err(ConfigError { problems }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_values_parse_as_toml_or_string() {
        assert_eq!(
            parse_set("vehicle.mass_kg=-3").unwrap(),
            ("vehicle.mass_kg".into(), toml::Value::Integer(-3))
        );
        assert_eq!(
            parse_set("gps.mode=fake-zero").unwrap().1,
            toml::Value::String("fake-zero".into())
        );
        assert_eq!(
            parse_set("gps.mode=\"off\"").unwrap().1,
            toml::Value::String("off".into())
        );
        assert!(parse_set("novalue").is_err());
        assert!(parse_set("a..b=1").is_err());
    }
}
