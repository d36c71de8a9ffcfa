//! The 15-state extended Kalman filter of the original, with the three gyro-bias states and
//! the two receiver-bias states the default profile adds (`core::ekf_gyro_bias`,
//! `core::ekf_gps_bias`; the 2012 profile has them off).
//!
//! Spec section 3 with ERRATA 2–4: states (3.1), process model (3.3), Jacobian (3.4, without
//! the `F[3][12] = T` term the flown program did not have), observation models (3.5), noise
//! (3.6), step (3.7), θ unwrapping (3.8). Units: m, rad, m/s, rad/s, m/s²; dt in µs.
//!
//! Fixed-size nalgebra matrices: a step allocates nothing. The observation matrices are pure
//! selections (each row reads one state), so H·P·Hᵀ and P·Hᵀ are index gathers, not products;
//! the arithmetic on the fixed structure of F and of the update is in `ekf_kernels`.

use crate::core::ekf_kernels as kernels;
use crate::core::gps::GpsSample;
use crate::core::imu::calib::{ImuSample, unwrap_theta};
use crate::core::math;
use crate::core::model::{
    ARM_LENGTH_M, GRAVITY_M_S2, IXX_KG_M2, IYY_KG_M2, IZZ_KG_M2, IZZM_KG_M2, drag_nm, thrust_n,
};
use nalgebra::{ArrayStorage, SMatrix, SVector};

pub use crate::core::ekf_kernels::{N_STATES, StateMatrix};
/// The model's states (spec 3.1): what the process model, the controller and the logs know.
pub const N_MODEL: usize = 15;
pub type State = SVector<f64, N_MODEL>;
pub type ModelMatrix = SMatrix<f64, N_MODEL, N_MODEL>;
/// The filter's states: the model's, then the gyros' bias (`core::ekf_gyro_bias`), then the
/// receiver's horizontal bias (`core::ekf_gps_bias`).
pub type FilterState = SVector<f64, N_STATES>;
/// Motor speeds m0..m3, rad/s.
pub type Input = [f64; 4];

/// State indices (spec 3.1).
pub mod idx {
    pub const X: usize = 0;
    pub const Y: usize = 1;
    pub const Z: usize = 2;
    pub const PSI: usize = 3;
    pub const PHI: usize = 4;
    pub const THETA: usize = 5;
    pub const VQX: usize = 6;
    pub const VQY: usize = 7;
    pub const VQZ: usize = 8;
    pub const WQX: usize = 9;
    pub const WQY: usize = 10;
    pub const WQZ: usize = 11;
    pub const BAX: usize = 12;
    pub const BAY: usize = 13;
    pub const BAZ: usize = 14;
    /// The gyros' bias, body x y z, rad/s (the filter's only: `core::ekf_gyro_bias`).
    pub const BGX: usize = 15;
    pub const BGY: usize = 16;
    pub const BGZ: usize = 17;
    /// The GPS receiver's horizontal bias, north and west, m (the filter's only:
    /// `core::ekf_gps_bias`).
    pub const BPX: usize = 18;
    pub const BPY: usize = 19;
}

/// Rows of the IMU-only update: ψ, φ, θ, ax, ay, az, ωx, ωy, ωz, baro altitude.
pub const IMU_ROWS: usize = 10;
/// Rows of the IMU + GPS update: the nine IMU rows, then GPS x, y, z.
pub const GPS_ROWS: usize = 12;
/// The state each IMU row observes (the az row observes baz plus the thrust term).
const IMU_OBS: [usize; IMU_ROWS] = [3, 4, 5, 12, 13, 14, 9, 10, 11, 2];
const GPS_OBS: [usize; GPS_ROWS] = [3, 4, 5, 12, 13, 14, 9, 10, 11, 0, 1, 2];

/// The measurement groups the innovation test judges, one per sensor that can be wrong on its
/// own (a disturbed magnetometer, a pressure jump, a GPS multipath fix). The accelerometer and
/// gyro rows are not tested: the filter cannot run without them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Group {
    /// The IMU's Euler angles ψ, φ, θ.
    Attitude,
    /// The barometer's altitude (IMU update) or the GPS z (IMU + GPS update).
    Altitude,
    /// The GPS x, y.
    Gps,
    /// Accelerometer and gyro rows: always fused.
    Untested,
}

/// The group of each IMU row.
const IMU_GROUPS: [Group; IMU_ROWS] = {
    let mut g = [Group::Untested; IMU_ROWS];
    (g[0], g[1], g[2]) = (Group::Attitude, Group::Attitude, Group::Attitude);
    g[9] = Group::Altitude;
    g
};
/// The group of each IMU + GPS row.
const GPS_GROUPS: [Group; GPS_ROWS] = {
    let mut g = [Group::Untested; GPS_ROWS];
    (g[0], g[1], g[2]) = (Group::Attitude, Group::Attitude, Group::Attitude);
    (g[9], g[10]) = (Group::Gps, Group::Gps);
    g[11] = Group::Altitude;
    g
};

/// Filter parameters (from the `ekf.*` configuration keys).
#[derive(Debug, Clone, PartialEq)]
pub struct EkfParams {
    /// Keep the original's model quirks its logs depend on: `cψ·cψ` in the z row and `cφ·sθ`
    /// in the x row of the process model (and their Jacobian terms). `false` uses the
    /// rotation's `cφ·cψ` and `cψ·sθ`.
    pub original_model: bool,
    /// Process noise, diagonal (added unscaled each step).
    pub q_diag: [f64; N_MODEL],
    /// IMU measurement noise, diagonal, rows as `IMU_ROWS`.
    pub r_imu_diag: [f64; IMU_ROWS],
    /// IMU + GPS measurement noise, diagonal, rows as `GPS_ROWS`.
    pub r_gps_diag: [f64; GPS_ROWS],
    /// Initial covariance, diagonal.
    pub p0_diag: [f64; N_MODEL],
    /// Accepted step interval; outside it dt is clamped (spec 3.9), µs.
    pub dt_min_us: i64,
    pub dt_max_us: i64,
    /// Width of the innovation gate, standard deviations of the innovation: a row's test
    /// ratio is y²/(gate_sigma²·S_ii), above 1 outside the gate (PX4 EKF2's convention).
    pub gate_sigma: f64,
    /// Leave a measurement group whose test ratio is above 1 out of the step's update (a
    /// fix's velocity not wildly off is fused at the gate's edge instead, `core::ekf_fix`). `false` fuses every row (the ratios are still computed and reported).
    pub gate_fusion: bool,
    /// How a GPS fix is fused.
    pub gps_fusion: GpsFusion,
    /// Noise of a fix's velocity rows ([`GpsFusion::PositionVelocity`]; the vertical one only
    /// while the barometer is lost), (m/s)².
    pub r_gps_vel: f64,
    /// The drag's specific force per m/s of airspeed across the thrust axis, 1/s (PX4's
    /// EKF2_MCOEF): without fixes it holds the horizontal velocity (`core::ekf_drag`); 0: off.
    pub drag_per_s: f64,
    /// While the vehicle rests on the ground, fuse its height and a still body (the model has
    /// no ground: without it the estimate falls through the ground at a touchdown).
    pub ground_fusion: bool,
    /// The noise of those rows: the height, m², and each body velocity, (m/s)², on the
    /// profile's own scale of noise.
    pub r_ground: [f64; 2],
    /// Fuse the IMU's angles once every this many seconds, each fusion one reading of their
    /// error's correlation time (`core::ekf_angles`); 0: every step.
    pub angle_period_s: f64,
    /// The gyros' bias states (`core::ekf_gyro_bias`): their process noise per step and
    /// initial variance, (rad/s)² each; both 0: no bias (the states stay 0).
    pub gyro_bias_q: f64,
    pub gyro_bias_p0: f64,
    /// The receiver's horizontal bias states (`core::ekf_gps_bias`, with
    /// [`GpsFusion::PositionVelocity`]): the bias's standard deviation per axis, m, and its
    /// correlation time, s (first-order Gauss-Markov); a deviation of 0: no bias states.
    pub gps_bias_m: f64,
    pub gps_bias_tau_s: f64,
    /// The IMU's roll and pitch noise while the vehicle rests on the ground, rad²
    /// (`core::ekf_angles`); 0: the flight's, as the 2012 flights.
    pub r_angles_rest: f64,
    /// The noise of each axis of the magnetometer's direction (a unit vector) where it holds
    /// the tilt (`core::ekf_field`); 0: never used, as the 2012 flights.
    pub r_field: f64,
}

/// How a GPS fix is fused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GpsFusion {
    /// With the IMU rows in one update of every state (spec 3.7; the 2012 flights).
    Joint,
    /// After the IMU rows, into position and velocity only, the first fix placing the
    /// position (`core::ekf_fix`).
    PositionVelocity,
}

/// The gate width of the default profile, standard deviations: PX4 EKF2's default for its GPS
/// position and barometer gates.
pub const DEFAULT_GATE_SIGMA: f64 = 5.0;

impl EkfParams {
    /// The values the 2012 flights printed to err.log (spec 3.6).
    pub fn flight_2012() -> Self {
        EkfParams {
            original_model: true,
            q_diag: [
                100.0, 100.0, 100.0, 0.01, 0.01, 1e-5, 100.0, 100.0, 100.0, 0.1, 0.1, 0.1, 1.0,
                1.0, 1.0,
            ],
            r_imu_diag: [100.0, 100.0, 1e5, 1e4, 1e4, 1e4, 1e-3, 1e-3, 1e-3, 1e5],
            r_gps_diag: [
                100.0, 100.0, 1e5, 1e4, 1e4, 1e4, 1e-3, 1e-3, 1e-3, 100.0, 100.0, 1e5,
            ],
            p0_diag: [1.0; N_MODEL],
            dt_min_us: 8_000,
            dt_max_us: 12_000,
            gate_sigma: DEFAULT_GATE_SIGMA,
            // The 2012 flights fused every measurement; their replays must stay bit-exact.
            gate_fusion: false,
            gps_fusion: GpsFusion::Joint,
            r_gps_vel: 0.01,
            drag_per_s: 0.0,
            // The 2012 flights' filter knew no ground; their replays must stay bit-exact.
            ground_fusion: false,
            r_ground: [1e3, 1e-2],
            // The 2012 flights fused the angles every step, and knew no gyro bias.
            angle_period_s: 0.0,
            gyro_bias_q: 0.0,
            gyro_bias_p0: 0.0,
            gps_bias_m: 0.0,
            gps_bias_tau_s: 60.0,
            r_angles_rest: 0.0,
            r_field: 0.0,
        }
    }
}

/// When the IMU's angles are next fused, and what that fusion compares with
/// (`core::ekf_angles`).
#[derive(Debug, Clone, Copy)]
pub struct AngleClock {
    /// Time since the last fusion, s.
    pub(crate) since_s: f64,
    /// The predictions' change of the horizontal velocity (north, west), m/s, over the
    /// window before the next fusion, and the window's length so far, s.
    pub(crate) window_dv_m_s: [f64; 2],
    pub(crate) window_s: f64,
    /// This step fuses the angles.
    pub(crate) due: bool,
    /// The attitude's test ratio at the last fusion.
    pub(crate) ratio: f64,
}

impl Default for AngleClock {
    fn default() -> Self {
        AngleClock {
            // The first step fuses: the initial covariance knows nothing of the attitude, and
            // the fixes' velocity must not tilt it meanwhile.
            since_s: f64::INFINITY,
            window_dv_m_s: [0.0; 2],
            window_s: 0.0,
            due: true,
            ratio: 0.0,
        }
    }
}

/// Why a step did not apply its measurement update.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EkfError {
    #[error("measurement is not finite; prediction only")]
    NonFiniteMeasurement,
    #[error("innovation covariance is not positive definite; prediction only")]
    SingularInnovation,
}

/// Per-step inputs besides the IMU sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepInput {
    /// Motor speeds used as the model input u, rad/s.
    pub u_rad_s: Input,
    /// Vehicle mass, kg.
    pub mass_kg: f64,
    /// Filter dt before clamping, µs.
    pub dt_us: i64,
    /// A GPS position (local frame, m) to fuse in this step.
    pub gps: Option<GpsSample>,
    /// The ground's height (m, the estimate's frame) while the vehicle rests on it: with
    /// `ground_fusion`, the height and a still body are fused as measurements.
    pub ground_m: Option<f64>,
    /// The vehicle rests on the ground, armed or not: with `ground_fusion` and the gyros'
    /// bias states, a body that does not turn is fused as a measurement.
    pub at_rest: bool,
}

#[cfg(test)]
impl StepInput {
    /// A 10 ms step of the 1.55 kg airframe at hover thrust, without a fix or the ground.
    pub(crate) fn hover_10ms() -> StepInput {
        StepInput {
            u_rad_s: [crate::core::model::w_hover_rad_s(1.55); 4],
            mass_kg: 1.55,
            dt_us: 10_000,
            gps: None,
            ground_m: None,
            at_rest: false,
        }
    }
}

/// What a step did, for counters and logs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// The dt actually used, µs.
    pub dt_used_us: i64,
    /// dt was outside the accepted interval and was clamped.
    pub dt_clamped: bool,
    /// The measured θ after unwrapping against the previous estimate (what kalman_in logs).
    pub theta_unwrapped_rad: f64,
    /// The innovation test ratios of the step's measurement groups.
    pub ratios: TestRatios,
    /// The groups left out of the update (only with `gate_fusion`); `gps` is the fix's
    /// position (its velocity is gated apart: `fix_velocity_fused`).
    pub gated: GatedGroups,
    /// The normalised innovation squared of each group fused or judged in the step.
    pub nis: StepNis,
    /// A fix's horizontal velocity was fused this step inside its gate, whether or not its
    /// position was (one fused at the gate's edge does not count: it is not a measurement the
    /// estimate agrees with).
    pub fix_velocity_fused: bool,
    /// The test ratio of a fix's horizontal velocity rows alone, when it had them: a
    /// position jump with a consistent velocity is the receiver's glitch, a velocity outside
    /// its gate the estimate's own error.
    pub fix_velocity_ratio: Option<f64>,
}

/// A group's normalised innovation squared, yᵀ·S⁻¹·y over its rows with S = H·P·Hᵀ + R taken
/// before the update (and before any group is left out): for a consistent filter it follows
/// a chi-square law with `dof` degrees of freedom.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nis {
    pub value: f64,
    pub dof: u8,
}

/// The NIS of each measurement group of one step; `None` for a group the step did not measure
/// (no fix, a lost barometer, the first fix that places the position, the attitude between
/// the IMU's angle fusions).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepNis {
    pub attitude: Option<Nis>,
    pub altitude: Option<Nis>,
    pub gps: Option<Nis>,
}

/// The NIS over `rows` of an innovation `y` with covariance `s` (at most four rows, the
/// largest group: a fix's horizontal position and velocity); `None` if a row is not finite or
/// the block is not positive definite.
pub(crate) fn group_nis<const M: usize>(
    y: &SVector<f64, M>,
    s: &SMatrix<f64, M, M>,
    rows: impl Iterator<Item = usize>,
) -> Option<Nis> {
    let mut idx = [0usize; 4];
    let mut n = 0;
    for r in rows {
        *idx.get_mut(n)? = r;
        n += 1;
    }
    if n == 0 {
        return None;
    }
    // Padded with identity rows (zero innovation): they add nothing to yᵀ·S⁻¹·y.
    let block = nalgebra::Matrix4::<f64>::from_fn(|r, c| match (r < n, c < n) {
        (true, true) => s[(idx[r], idx[c])],
        _ if r == c => 1.0,
        _ => 0.0,
    });
    let v = nalgebra::Vector4::<f64>::from_fn(|r, _| if r < n { y[idx[r]] } else { 0.0 });
    if !v.iter().all(|e| e.is_finite()) {
        return None;
    }
    let value = v.dot(&block.cholesky()?.solve(&v));
    Some(Nis {
        value,
        dof: n as u8,
    })
}

/// The NIS of each tested group of an update over rows grouped as `groups`.
fn step_nis<const M: usize>(
    y: &SVector<f64, M>,
    s: &SMatrix<f64, M, M>,
    groups: &[Group; M],
) -> StepNis {
    let of = |g: Group| group_nis(y, s, (0..M).filter(|&i| groups[i] == g));
    StepNis {
        attitude: of(Group::Attitude),
        altitude: of(Group::Altitude),
        gps: of(Group::Gps),
    }
}

/// Normalised innovation test ratios of one step, one per measurement group: the largest over
/// the group's rows of y_i²/(gate_sigma²·S_ii), with y the innovation and S = H·P·Hᵀ + R.
/// Dimensionless; above 1 the innovation is outside the gate. NaN when a row's measurement is
/// not a number (the step then fuses nothing). The attitude's is its last fusion's between the
/// IMU's angle fusions (`core::ekf_angles`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TestRatios {
    pub attitude: f64,
    pub altitude: f64,
    /// `None` in a step without a GPS sample.
    pub gps: Option<f64>,
}

impl TestRatios {
    /// The groups outside the gate (ratio above 1; NaN is not).
    pub fn outside_gate(&self) -> GatedGroups {
        GatedGroups {
            attitude: self.attitude > 1.0,
            altitude: self.altitude > 1.0,
            gps: self.gps.is_some_and(|r| r > 1.0),
        }
    }

    /// The ratio slot of `group`; `None` for the untested rows.
    fn slot(&mut self, group: Group) -> Option<&mut f64> {
        match group {
            Group::Attitude => Some(&mut self.attitude),
            Group::Altitude => Some(&mut self.altitude),
            Group::Gps => Some(self.gps.get_or_insert(0.0)),
            Group::Untested => None,
        }
    }
}

/// Which measurement groups a step left out of its update.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GatedGroups {
    pub attitude: bool,
    pub altitude: bool,
    pub gps: bool,
}

impl GatedGroups {
    pub fn any(self) -> bool {
        self.attitude || self.altitude || self.gps
    }

    pub fn contains(self, group: Group) -> bool {
        match group {
            Group::Attitude => self.attitude,
            Group::Altitude => self.altitude,
            Group::Gps => self.gps,
            Group::Untested => false,
        }
    }
}

/// What a measurement update did.
pub(crate) struct UpdateOutcome {
    pub(crate) ratios: TestRatios,
    pub(crate) gated: GatedGroups,
    pub(crate) nis: StepNis,
    /// A fix's horizontal velocity was fused (its position may have been left out).
    pub(crate) fix_velocity_fused: bool,
    /// The test ratio of a fix's horizontal velocity rows, when it had them.
    pub(crate) fix_velocity_ratio: Option<f64>,
    pub(crate) result: Result<(), EkfError>,
}

/// The filter: estimate and covariance.
#[derive(Debug, Clone)]
pub struct Ekf {
    pub params: EkfParams,
    pub x: FilterState,
    pub p: StateMatrix,
    /// A fix has been fused (with [`GpsFusion::PositionVelocity`] the first one places the
    /// position).
    pub fix_seen: bool,
    /// The last IMU update had no barometer altitude (a failed barometer): with
    /// [`GpsFusion::PositionVelocity`] the altitude is then left out, not refused, and the
    /// fixes' vertical velocity holds the vertical until it returns.
    pub baro_lost: bool,
    /// The last update had no gyro rates (a stuck gyro, `core::imu::health`): its rows are
    /// left out and the rates follow the model's torques, the attitude the IMU's angles.
    pub gyro_lost: bool,
    /// Steps since the last fix (saturating); the drag holds the velocity past a threshold.
    pub steps_without_fix: u32,
    /// The last step's thrust carried most of the weight (`core::ekf_drag`).
    pub flying: bool,
    /// This step the vehicle rests on the ground, by the commander (`StepInput::at_rest`).
    pub(crate) at_rest: bool,
    /// The IMU's angles the estimate began from, until the first step (`Ekf::new`).
    start_angles_rad: Option<[f64; 3]>,
    /// The gyros' roll and pitch bias as the last fused fix left them, rad/s
    /// (`core::ekf_gyro_bias`).
    pub(crate) bias_at_fix_rad_s: [f64; 2],
    /// The accelerometer's x and y summed over the drag's window, m/s², and the samples in
    /// it (`core::ekf_drag`).
    pub(crate) drag_sum_m_s2: [f64; 2],
    pub(crate) drag_samples: u32,
    /// Windows in a row that have read a push (`core::ekf_drag`).
    pub(crate) push_windows: u32,
    /// When the IMU's angles are next fused (`core::ekf_angles`).
    pub(crate) angles: AngleClock,
    /// The Earth's field as the filter's start read it, and the steps since its last fusion
    /// (`core::ekf_field`).
    pub(crate) field: Option<crate::core::ekf_field::Field>,
    pub(crate) field_steps: u32,
}

struct Trig {
    s_psi: f64,
    c_psi: f64,
    s_phi: f64,
    c_phi: f64,
    t_phi: f64,
    s_th: f64,
    c_th: f64,
}

impl Trig {
    fn of(x: &State) -> Self {
        let (s_psi, c_psi) = math::sin_cos(x[idx::PSI]);
        let (s_phi, c_phi) = math::sin_cos(x[idx::PHI]);
        let (s_th, c_th) = math::sin_cos(x[idx::THETA]);
        Trig {
            s_psi,
            c_psi,
            s_phi,
            c_phi,
            t_phi: math::tan(x[idx::PHI]),
            s_th,
            c_th,
        }
    }
}

/// Sum of the four thrusts, N.
fn total_thrust_n(u: &Input) -> f64 {
    thrust_n(u[0]) + thrust_n(u[1]) + thrust_n(u[2]) + thrust_n(u[3])
}

/// The process model x⁻ = f(x, u, T) (spec 3.3, explicit Euler).
pub fn process(x: &State, u: &Input, t_s: f64, mass_kg: f64, original_model: bool) -> State {
    process_at(x, &Trig::of(x), u, t_s, mass_kg, original_model)
}

/// [`process`] with the state's sines and cosines already taken.
fn process_at(
    x: &State,
    trig: &Trig,
    u: &Input,
    t_s: f64,
    mass_kg: f64,
    original_model: bool,
) -> State {
    let &Trig {
        s_psi,
        c_psi,
        s_phi,
        c_phi,
        t_phi,
        s_th,
        c_th,
    } = trig;
    let [vqx, vqy, vqz] = [x[idx::VQX], x[idx::VQY], x[idx::VQZ]];
    let [wqx, wqy, wqz] = [x[idx::WQX], x[idx::WQY], x[idx::WQZ]];
    let [bias_x, bias_y, bias_z] = [x[idx::BAX], x[idx::BAY], x[idx::BAZ]];
    let g = GRAVITY_M_S2;
    let tm: [f64; 4] = std::array::from_fn(|i| thrust_n(u[i]));
    let d: [f64; 4] = std::array::from_fn(|i| drag_nm(u[i]));
    let w_sum = u[0] - u[1] + u[2] - u[3];
    let sum_tm = total_thrust_n(u);
    // The original multiplied vqz by cψ·cψ where the kinematics have cφ·cψ (spec 3.3).
    let z_vqz = if original_model {
        c_psi * c_psi
    } else {
        c_phi * c_psi
    };
    let mut n = *x;
    // The original wrote cφ·sθ in the x row where the rotation has cψ·sθ (spec 3.3).
    let x_vqy_s_th = if original_model { c_phi } else { c_psi };
    n[idx::X] = x[idx::X]
        + t_s
            * (vqx * c_phi * c_th
                + vqy * (c_th * s_phi * s_psi - x_vqy_s_th * s_th)
                + vqz * (s_psi * s_th + c_psi * c_th * s_phi));
    n[idx::Y] = x[idx::Y]
        + t_s
            * (vqx * c_phi * s_th
                + vqy * (s_th * s_phi * s_psi + c_psi * c_th)
                + vqz * (c_psi * s_th * s_phi - c_th * s_psi));
    n[idx::Z] = x[idx::Z] + t_s * (-vqx * s_phi + vqy * c_phi * s_psi + vqz * z_vqz);
    n[idx::PSI] = x[idx::PSI] + t_s * (wqx + wqz * t_phi * c_psi + wqy * t_phi * s_psi);
    n[idx::PHI] = x[idx::PHI] + t_s * (wqy * c_psi - wqz * s_psi);
    n[idx::THETA] = x[idx::THETA] + t_s * (wqz * c_psi / c_phi + wqy * s_psi / c_phi);
    n[idx::VQX] = vqx + t_s * (vqy * wqz - vqz * wqy + g * s_phi + bias_x);
    n[idx::VQY] = vqy + t_s * (vqz * wqx - vqx * wqz - g * c_phi * s_psi + bias_y);
    n[idx::VQZ] =
        vqz + t_s * (vqx * wqy - vqy * wqx - g * c_phi * c_psi + sum_tm / mass_kg + bias_z);
    n[idx::WQX] = wqx
        + t_s
            * (wqy * wqz * (IYY_KG_M2 - IZZ_KG_M2)
                + wqy * IZZM_KG_M2 * w_sum
                + ARM_LENGTH_M * (tm[1] - tm[3]))
            / IXX_KG_M2;
    n[idx::WQY] = wqy
        + t_s
            * (wqx * wqz * (IZZ_KG_M2 - IXX_KG_M2)
                + wqx * IZZM_KG_M2 * w_sum
                + ARM_LENGTH_M * (tm[2] - tm[0]))
            / IYY_KG_M2;
    n[idx::WQZ] = wqz - t_s * (d[0] - d[1] + d[2] - d[3]) / IZZ_KG_M2;
    n
}

/// The Jacobian F = ∂f/∂x at `x` (spec 3.4, ERRATA 2).
pub fn jacobian(x: &State, u: &Input, t_s: f64, original_model: bool) -> ModelMatrix {
    jacobian_at(x, &Trig::of(x), u, t_s, original_model)
}

/// [`jacobian`] with the state's sines and cosines already taken.
fn jacobian_at(x: &State, trig: &Trig, u: &Input, t_s: f64, original_model: bool) -> ModelMatrix {
    let &Trig {
        s_psi,
        c_psi,
        s_phi,
        c_phi,
        t_phi,
        s_th,
        c_th,
    } = trig;
    let [vqx, vqy, vqz] = [x[idx::VQX], x[idx::VQY], x[idx::VQZ]];
    let [wqx, wqy, wqz] = [x[idx::WQX], x[idx::WQY], x[idx::WQZ]];
    let g = GRAVITY_M_S2;
    let t = t_s;
    let w_sum = u[0] - u[1] + u[2] - u[3];
    let mut f = ModelMatrix::identity();
    if original_model {
        f[(0, 3)] = t * (vqz * (c_psi * s_th - c_th * s_phi * s_psi) + vqy * c_psi * c_th * s_phi);
        f[(0, 4)] = t
            * (vqy * (s_phi * s_th + c_phi * c_th * s_psi) - vqx * c_th * s_phi
                + vqz * c_phi * c_psi * c_th);
        f[(0, 5)] = -t
            * (vqy * (c_phi * c_th + s_phi * s_psi * s_th)
                - vqz * (c_th * s_psi - c_psi * s_phi * s_th)
                + vqx * c_phi * s_th);
        f[(0, 7)] = -t * (c_phi * s_th - c_th * s_phi * s_psi);
    } else {
        f[(0, 3)] = t
            * (vqz * (c_psi * s_th - c_th * s_phi * s_psi)
                + vqy * (c_psi * c_th * s_phi + s_psi * s_th));
        f[(0, 4)] =
            t * (vqy * c_phi * c_th * s_psi - vqx * c_th * s_phi + vqz * c_phi * c_psi * c_th);
        f[(0, 5)] = -t
            * (vqy * (c_psi * c_th + s_phi * s_psi * s_th)
                - vqz * (c_th * s_psi - c_psi * s_phi * s_th)
                + vqx * c_phi * s_th);
        f[(0, 7)] = -t * (c_psi * s_th - c_th * s_phi * s_psi);
    }
    f[(0, 6)] = t * c_phi * c_th;
    f[(0, 8)] = t * (s_psi * s_th + c_psi * c_th * s_phi);

    f[(1, 3)] = -t
        * (vqy * (c_th * s_psi - c_psi * s_phi * s_th)
            + vqz * (c_psi * c_th + s_phi * s_psi * s_th));
    f[(1, 4)] = t * (vqz * c_phi * c_psi * s_th - vqx * s_phi * s_th + vqy * c_phi * s_psi * s_th);
    f[(1, 5)] = t
        * (vqz * (s_psi * s_th + c_psi * c_th * s_phi)
            - vqy * (c_psi * s_th - c_th * s_phi * s_psi)
            + vqx * c_phi * c_th);
    f[(1, 6)] = t * c_phi * s_th;
    f[(1, 7)] = t * (c_psi * c_th + s_phi * s_psi * s_th);
    f[(1, 8)] = -t * (c_th * s_psi - c_psi * s_phi * s_th);

    if original_model {
        f[(2, 3)] = t * (vqy * c_phi * c_psi - 2.0 * vqz * c_psi * s_psi);
        f[(2, 4)] = -t * (vqx * c_phi + vqy * s_phi * s_psi);
        f[(2, 8)] = t * c_psi * c_psi;
    } else {
        f[(2, 3)] = t * (vqy * c_phi * c_psi - vqz * c_phi * s_psi);
        f[(2, 4)] = -t * (vqx * c_phi + vqy * s_phi * s_psi + vqz * s_phi * c_psi);
        f[(2, 8)] = t * c_phi * c_psi;
    }
    f[(2, 6)] = -t * s_phi;
    f[(2, 7)] = t * c_phi * s_psi;

    f[(3, 3)] = 1.0 + t * (wqy * c_psi * t_phi - wqz * s_psi * t_phi);
    f[(3, 4)] = t * (wqz * c_psi + wqy * s_psi) * (1.0 + t_phi * t_phi);
    f[(3, 9)] = t;
    f[(3, 10)] = t * s_psi * t_phi;
    f[(3, 11)] = t * c_psi * t_phi;

    f[(4, 3)] = -t * (wqz * c_psi + wqy * s_psi);
    f[(4, 10)] = t * c_psi;
    f[(4, 11)] = -t * s_psi;

    f[(5, 3)] = t * (wqy * c_psi - wqz * s_psi) / c_phi;
    f[(5, 4)] = t * (wqz * c_psi * s_phi + wqy * s_phi * s_psi) / (c_phi * c_phi);
    f[(5, 10)] = t * s_psi / c_phi;
    f[(5, 11)] = t * c_psi / c_phi;

    f[(6, 4)] = t * g * c_phi;
    f[(6, 7)] = t * wqz;
    f[(6, 8)] = -t * wqy;
    f[(6, 10)] = -t * vqz;
    f[(6, 11)] = t * vqy;
    f[(6, 12)] = t;

    f[(7, 3)] = -t * g * c_phi * c_psi;
    f[(7, 4)] = t * g * s_phi * s_psi;
    f[(7, 6)] = -t * wqz;
    f[(7, 8)] = t * wqx;
    f[(7, 9)] = t * vqz;
    f[(7, 11)] = -t * vqx;
    f[(7, 13)] = t;

    f[(8, 3)] = t * g * c_phi * s_psi;
    f[(8, 4)] = t * g * c_psi * s_phi;
    f[(8, 6)] = t * wqy;
    f[(8, 7)] = -t * wqx;
    f[(8, 9)] = -t * vqy;
    f[(8, 10)] = t * vqx;
    f[(8, 14)] = t;

    f[(9, 10)] = t * (wqz * (IYY_KG_M2 - IZZ_KG_M2) + IZZM_KG_M2 * w_sum) / IXX_KG_M2;
    f[(9, 11)] = t * wqy * (IYY_KG_M2 - IZZ_KG_M2) / IXX_KG_M2;

    f[(10, 9)] = -t * (wqz * (IXX_KG_M2 - IZZ_KG_M2) - IZZM_KG_M2 * w_sum) / IYY_KG_M2;
    f[(10, 11)] = -t * wqx * (IXX_KG_M2 - IZZ_KG_M2) / IYY_KG_M2;
    f
}

impl Ekf {
    /// The initial state from the calibration null sample (spec 3.7): attitude from its Euler
    /// angles, accelerometer bias = its acceleration minus gravity, everything else 0; P = P₀.
    pub fn new(params: EkfParams, null_sample: &ImuSample) -> Self {
        let mut x = FilterState::zeros();
        x[idx::PSI] = null_sample.euler_rad[0];
        x[idx::PHI] = null_sample.euler_rad[1];
        x[idx::THETA] = null_sample.euler_rad[2];
        x[idx::BAX] = null_sample.acc_m_s2[0];
        x[idx::BAY] = null_sample.acc_m_s2[1];
        x[idx::BAZ] = null_sample.acc_m_s2[2] - GRAVITY_M_S2;
        let p0 = params.p0_diag;
        // The receiver's bias has no variance until the first fix places it (`ekf_gps_bias`).
        let p = StateMatrix::from_diagonal(&FilterState::from_fn(|i, _| match i {
            idx::BGX..=idx::BGZ => params.gyro_bias_p0,
            _ => p0.get(i).copied().unwrap_or(0.0),
        }));
        let mut ekf = Ekf {
            params,
            x,
            p,
            fix_seen: false,
            baro_lost: false,
            gyro_lost: false,
            steps_without_fix: 0,
            flying: false,
            at_rest: false,
            start_angles_rad: Some(null_sample.euler_rad),
            bias_at_fix_rad_s: [0.0; 2],
            drag_sum_m_s2: [0.0; 2],
            drag_samples: 0,
            push_windows: 0,
            angles: AngleClock::default(),
            field: None,
            field_steps: 0,
        };
        ekf.anchor_field(null_sample.magn);
        ekf
    }

    /// The horizontal position's standard deviation, the larger axis's, m: with the receiver's
    /// bias states (`core::ekf_gps_bias`) it holds the bias's doubt, which the fixes take away only
    /// over several of its correlation times, and grows, without fixes, as the position's own
    /// does (the fence's margin).
    pub fn horizontal_sigma_m(&self) -> f64 {
        self.p[(idx::X, idx::X)]
            .max(self.p[(idx::Y, idx::Y)])
            .max(0.0)
            .sqrt()
    }

    /// The same in the frame the fixes are in (the bias states' doubt left out): how well the
    /// fixes have placed the position, what a pre-arm check asks.
    pub fn fix_frame_sigma_m(&self) -> f64 {
        self.fix_frame_variance_m2(0)
            .max(self.fix_frame_variance_m2(1))
            .max(0.0)
            .sqrt()
    }

    /// Clamps a step interval to the accepted range (spec 3.9).
    pub fn clamp_dt_us(&self, dt_us: i64) -> (i64, bool) {
        let c = dt_us.clamp(self.params.dt_min_us, self.params.dt_max_us);
        (c, c != dt_us)
    }

    /// One filter step (spec 3.7): unwrap θ, predict, update with the IMU rows (and the GPS rows
    /// when `input.gps_m` is given), leaving out the groups outside the innovation gate when
    /// `gate_fusion` is on. On a bad measurement the prediction stands and the error says why;
    /// the estimate never becomes non-finite from the measurement.
    pub fn step(
        &mut self,
        sample: &ImuSample,
        input: &StepInput,
    ) -> (StepReport, Result<(), EkfError>) {
        let theta_m = unwrap_theta(sample.euler_rad[2], self.x[idx::THETA]);
        let (dt_used_us, dt_clamped) = self.clamp_dt_us(input.dt_us);
        // A fix counts once fused (the gate may leave it out): until then this step is one
        // more without, so a fix left out never turns the drag's hold off, even for a step.
        self.steps_without_fix = self.steps_without_fix.saturating_add(1);
        let weight_n = input.mass_kg * crate::core::model::GRAVITY_M_S2;
        self.flying = total_thrust_n(&input.u_rad_s) > FLYING_THRUST_SHARE * weight_n;
        self.at_rest = input.at_rest;
        let u = &input.u_rad_s;
        let dt_s = dt_used_us as f64 / 1e6;
        // The velocities the IMU's angles' noise is judged by, only in the window that needs
        // them (the 2012 profile's every-step fusion never does).
        let watch = self.angle_window_open(dt_s);
        let v_before_m_s = watch.then(|| self.earth_velocity_xy_m_s());
        self.predict(u, dt_s, input.mass_kg);
        let v_predicted_m_s = watch.then(|| self.earth_velocity_xy_m_s());
        let az_pred = total_thrust_n(u) / input.mass_kg + self.x[idx::BAZ];
        let out = self.correct(sample, theta_m, az_pred, input.gps);
        if let Some(ground_m) = input.ground_m.filter(|_| self.params.ground_fusion)
            && out.result.is_ok()
        {
            self.fuse_ground(ground_m);
        }
        if input.at_rest && self.params.ground_fusion && out.result.is_ok() {
            self.fuse_still_rates();
        }
        // A fix's velocity alone (its position left out) observes the velocity as well: the
        // drag's hold is not needed.
        if input.gps.is_some() && (!out.gated.gps || out.fix_velocity_fused) {
            self.fix_fused_now();
        }
        // The velocity the step flew, for the IMU's angles' noise: its prediction and the
        // IMU's own corrections (a push the accelerometer reads, the drag), not a fix's pull.
        let v_flown_m_s = if input.gps.is_some() {
            v_predicted_m_s
        } else {
            watch.then(|| self.earth_velocity_xy_m_s())
        };
        self.tick_angles(dt_s, v_before_m_s.zip(v_flown_m_s));
        let nis = self.without_start_nis(out.nis, sample);
        let report = StepReport {
            dt_used_us,
            dt_clamped,
            theta_unwrapped_rad: theta_m,
            ratios: out.ratios,
            gated: out.gated,
            nis,
            fix_velocity_fused: out.fix_velocity_fused,
            fix_velocity_ratio: out.fix_velocity_ratio,
        };
        (report, out.result)
    }

    /// A fix was fused this step: the drag's hold and the bias learnt without fixes count
    /// from here (the bias as the whole step left it).
    fn fix_fused_now(&mut self) {
        self.steps_without_fix = 0;
        self.bias_at_fix_rad_s = [self.x[idx::BGX], self.x[idx::BGY]];
    }

    /// The step's NIS, less the attitude's on the first step if it measures the sample the
    /// estimate began from: that innovation is zero by construction, no measure of the
    /// filter's consistency.
    fn without_start_nis(&mut self, mut nis: StepNis, sample: &ImuSample) -> StepNis {
        if self.start_angles_rad.take() == Some(sample.euler_rad) {
            nis.attitude = None;
        }
        nis
    }

    /// The prediction: x⁻ = f(x, u, T), P⁻ = F·P·Fᵀ + Q with F at the previous estimate.
    fn predict(&mut self, u: &Input, t_s: f64, mass_kg: f64) {
        let orig = self.params.original_model;
        // The model runs on the body's rates: the rate states' gyro frame less the bias.
        let xm = self.model_state();
        // F and f(x) share the previous estimate's sines and cosines: take them once.
        let trig = Trig::of(&xm);
        let f = self.filter_jacobian(&jacobian_at(&xm, &trig, u, t_s, orig));
        let x_pred = process_at(&xm, &trig, u, t_s, mass_kg, orig);
        kernels::propagate_covariance(&f, &mut self.p);
        for i in 0..N_MODEL {
            self.p[(i, i)] += self.params.q_diag[i];
        }
        self.bias_process_noise();
        self.receiver_bias_decay(t_s);
        if self.drag_modelled() {
            // bax, bay are then the drag, tied to the velocity: not a bias free to wander
            // (also on a step the thrust dips: a wide P would let the next window's drag jump
            // the velocity).
            for i in [idx::BAX, idx::BAY] {
                self.p[(i, i)] += Q_BAXY_DRAG - self.params.q_diag[i];
            }
        }
        if self.pushed_now() {
            // The gyros alone carry roll and pitch through a push: the profile's attitude
            // noise is sized against the IMU's angle rows (fused every step or once a
            // period, `core::ekf_angles`), which a push
            // leaves out (below); without them it would spread a tilt's doubt into the
            // velocity within a second.
            for i in [idx::PSI, idx::PHI] {
                self.p[(i, i)] += Q_ANGLES_PUSHED_RAD2 - self.params.q_diag[i];
            }
        }
        if self.gyro_lost {
            // The profile's rate noise lets the gyro's rows pull the rates within a few
            // steps; without them the torques the model knows carry the rates.
            for i in [idx::WQX, idx::WQY, idx::WQZ] {
                self.p[(i, i)] += Q_W_NO_GYRO - self.params.q_diag[i];
            }
        }
        if self.baro_lost {
            // The profile's vertical process noise is sized against the barometer's row, which
            // is fused every step; without it the height is the integral of the vertical
            // velocity, and that velocity wanders only as the accelerometer's noise does.
            self.p[(idx::Z, idx::Z)] += Q_Z_NO_BARO_M2 - self.params.q_diag[idx::Z];
            self.p[(idx::VQZ, idx::VQZ)] += Q_VZ_NO_BARO - self.params.q_diag[idx::VQZ];
        }
        self.set_model_state(&x_pred);
    }

    /// The measurement update: the IMU rows, plus the GPS rows when a sample is given. `theta_m`
    /// is the unwrapped θ, `az_pred` the predicted az (thrust/mass + baz), m/s².
    fn correct(
        &mut self,
        sample: &ImuSample,
        theta_m: f64,
        az_pred: f64,
        gps: Option<GpsSample>,
    ) -> UpdateOutcome {
        let (a, w, e) = (sample.acc_m_s2, sample.gyro_rad_s, sample.euler_rad);
        self.note_gyro(&w);
        // Without the gyro its rows read the predicted rates (no innovation) at a noise that
        // gives them no weight: the update keeps its shape and the other rows fuse.
        let w = if self.gyro_lost {
            [idx::WQX, idx::WQY, idx::WQZ].map(|i| self.x[i])
        } else {
            w
        };
        let imu9 = [e[0], e[1], theta_m, a[0], a[1], a[2], w[0], w[1], w[2]];
        match gps {
            Some(g) if self.params.gps_fusion == GpsFusion::PositionVelocity => {
                let imu = self.correct(sample, theta_m, az_pred, None);
                let fix = self.fuse_fix(&g);
                UpdateOutcome {
                    ratios: TestRatios {
                        gps: fix.ratios.gps,
                        ..imu.ratios
                    },
                    gated: GatedGroups {
                        gps: fix.gated.gps,
                        ..imu.gated
                    },
                    nis: StepNis {
                        gps: fix.nis.gps,
                        ..imu.nis
                    },
                    fix_velocity_fused: fix.fix_velocity_fused,
                    fix_velocity_ratio: fix.fix_velocity_ratio,
                    result: imu.result.and(fix.result),
                }
            }
            None => self.correct_imu(sample, imu9, az_pred),
            Some(g) => {
                let z: [f64; GPS_ROWS] = std::array::from_fn(|i| {
                    if i < 9 {
                        imu9[i]
                    } else {
                        gps_row(&g, i - 9, sample.alt_m)
                    }
                });
                let mut r = self.params.r_gps_diag;
                self.without_gyro(&mut r);
                self.angle_rows(&mut r);
                if g.z_m.is_none() {
                    // A fix without altitude: the barometer's row, with its noise, stands in.
                    r[GPS_ROWS - 1] = self.params.r_imu_diag[IMU_ROWS - 1];
                }
                self.update::<GPS_ROWS>(&z, &GPS_OBS, &GPS_GROUPS, az_pred, &r)
            }
        }
    }

    /// The IMU rows alone (between fixes, and before a fix in position-velocity fusion);
    /// without the barometer the altitude left out, without fixes the drag fused.
    fn correct_imu(&mut self, sample: &ImuSample, imu9: [f64; 9], az_pred: f64) -> UpdateOutcome {
        // The joint fusion (the 2012 flights) refuses the update as it always did.
        let lost =
            !sample.alt_m.is_finite() && self.params.gps_fusion == GpsFusion::PositionVelocity;
        if lost && !self.baro_lost {
            self.vertical_from_barometer();
        }
        self.baro_lost = lost;
        let z: [f64; IMU_ROWS] =
            std::array::from_fn(|i| if i < 9 { imu9[i] } else { sample.alt_m });
        let mut r = self.params.r_imu_diag;
        self.without_gyro(&mut r);
        if lost {
            // The accelerometer's vertical row then carries the height between fixes: read at
            // its own noise (or the profile's, if tighter), it teaches the thrust model's error
            // (baz), so the estimate stands still when the vehicle does (on the ground, too).
            r[5] = r[5].min(R_AZ_NO_BARO);
        }
        if self.pushed_now() {
            // The IMU's angles take the accelerometer for the gravity's direction: during a
            // push they read it as a tilt. The gyros carry the attitude until it ends.
            r[0] = R_ANGLES_PUSHED_RAD2;
            r[1] = R_ANGLES_PUSHED_RAD2;
        }
        self.angle_rows(&mut r);
        if self.field_holds_tilt() && !self.gyro_lost {
            // In the air without fixes the IMU's roll and pitch read the thrust axis: the
            // field's rows hold the tilt. Its yaw stays: the field cannot see a turn about
            // itself, and that yaw pins it (left out too, the hover without a receiver rolled
            // off along it: 45-138 m from the start on seeds 1-3, 24-42 m with it).
            r[..2].fill(R_ANGLES_PUSHED_RAD2);
        }
        let mut out = self.update::<IMU_ROWS>(&z, &IMU_OBS, &IMU_GROUPS, az_pred, &r);
        if out.result.is_ok() && !self.fuse_field(sample.magn) {
            out.gated.attitude = true;
        }
        if self.drag_active() && out.result.is_ok() {
            self.fuse_drag(sample.acc_m_s2);
        } else {
            self.drag_samples = 0;
            if !self.drag_modelled() {
                self.push_windows = 0;
            }
        }
        out
    }

    /// Whether the gyro's rates came this step (a stuck gyro sends none,
    /// `core::imu::health`); the step it is lost puts the rates in doubt.
    fn note_gyro(&mut self, w_rad_s: &[f64; 3]) {
        let was_lost = self.gyro_lost;
        self.gyro_lost = !w_rad_s.iter().all(|v| v.is_finite());
        if self.gyro_lost && !was_lost && self.field_holds_tilt() {
            self.rates_in_doubt();
        }
    }

    /// The gyro has just been found stuck: the rates it read over the frames that took
    /// (`core::imu::health`) were its stuck value, while the controller flew against them.
    /// Their doubt becomes [`VAR_W_AT_GYRO_LOSS`], apart from every other state's, and the
    /// field's rows (`core::ekf_field`) correct them from there.
    fn rates_in_doubt(&mut self) {
        for i in [idx::WQX, idx::WQY, idx::WQZ] {
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
            self.p[(i, i)] = VAR_W_AT_GYRO_LOSS;
        }
    }

    /// A lost gyro's rows (6 to 8 in both updates) at a noise that leaves them out.
    fn without_gyro<const M: usize>(&self, r: &mut [f64; M]) {
        if self.gyro_lost {
            r[6..9].fill(R_GYRO_LOST);
        }
    }

    /// The barometer has just gone: the height and vertical speed it held were good to
    /// centimetres (a profile with the 2012 noise values has a P that says metres), so the
    /// fixes that take over correct them gently instead of replacing them.
    fn vertical_from_barometer(&mut self) {
        for (i, var) in [(idx::Z, VAR_Z_AT_LOSS_M2), (idx::VQZ, VAR_VZ_AT_LOSS)] {
            // A profile on its sensors' scale may already know them better.
            let var = var.min(self.p[(i, i)]);
            self.p.row_mut(i).fill(0.0);
            self.p.column_mut(i).fill(0.0);
            self.p[(i, i)] = var;
        }
    }

    /// Measurement update for a selection observation: row i reads state `obs[i]`, except the
    /// az row (index 5), whose prediction is `az_pred` (thrust/mass + baz) with the same H row.
    /// Every row's test ratio is computed first; with `gate_fusion`, the rows of the groups
    /// outside the gate are then left out.
    fn update<const M: usize>(
        &mut self,
        z: &[f64; M],
        obs: &[usize; M],
        groups: &[Group; M],
        az_pred: f64,
        r_diag: &[f64; M],
    ) -> UpdateOutcome {
        let x = &self.x;
        let p = &self.p;
        let mut innovation = SVector::<f64, M>::from_fn(|i, _| {
            let h = if i == 5 { az_pred } else { x[obs[i]] };
            z[i] - h
        });
        // P·Hᵀ: the observed columns of P. S = H·P·Hᵀ + R: the observed rows of those.
        let mut pht =
            SMatrix::<f64, N_STATES, M>::from_data(ArrayStorage(std::array::from_fn(|c| {
                p.data.0[obs[c]]
            })));
        let mut s = SMatrix::<f64, M, M>::from_fn(|r, c| pht[(obs[r], c)]);
        for i in 0..M {
            s[(i, i)] += r_diag[i];
        }
        let mut ratios = test_ratios(&innovation, &s, groups, self.params.gate_sigma);
        let mut nis = step_nis(&innovation, &s, groups);
        if !self.angles.due {
            // Not this step's: the angle rows are left out exactly, the ratio is the last
            // fusion's (a NaN angle is still judged: it refuses the update below).
            if !ratios.attitude.is_nan() {
                ratios.attitude = self.angles.ratio;
            }
            nis.attitude = None;
            let angles = GatedGroups {
                attitude: true,
                ..GatedGroups::default()
            };
            leave_out(angles, groups, &mut innovation, &mut pht, &mut s);
        }
        let lost = non_finite_groups(z, groups);
        // Without the barometer the other rows still hold the attitude (position-velocity
        // fusion: the fixes then hold the vertical); any other row not a number refuses the
        // update. Its NaN ratio is the `estimator` failsafe's.
        let any_lost = z.iter().any(|v| !v.is_finite());
        let only_altitude = lost.altitude && !lost.attitude && !lost.gps;
        let untested_lost = z
            .iter()
            .zip(groups)
            .any(|(v, g)| !v.is_finite() && *g == Group::Untested);
        let degrade = self.params.gps_fusion == GpsFusion::PositionVelocity
            && only_altitude
            && !untested_lost;
        if any_lost && !degrade {
            return UpdateOutcome {
                ratios,
                gated: GatedGroups::default(),
                nis,
                fix_velocity_fused: false,
                fix_velocity_ratio: None,
                result: Err(EkfError::NonFiniteMeasurement),
            };
        }
        let mut gated = if self.params.gate_fusion {
            ratios.outside_gate()
        } else {
            GatedGroups::default()
        };
        gated.altitude |= lost.altitude;
        // A held ratio outside the gate is not a step's measurement left out.
        gated.attitude &= self.angles.due;
        if gated.any() {
            leave_out(gated, groups, &mut innovation, &mut pht, &mut s);
        }
        let result = self.fuse(&innovation, &mut pht, &mut s);
        self.angles_fused(result.is_ok(), ratios.attitude);
        UpdateOutcome {
            ratios,
            gated,
            nis,
            fix_velocity_fused: false,
            fix_velocity_ratio: None,
            result,
        }
    }

    /// x += K·y and P −= K·H·P, with K = P·Hᵀ·S⁻¹.
    fn fuse<const M: usize>(
        &mut self,
        innovation: &SVector<f64, M>,
        pht: &mut SMatrix<f64, N_STATES, M>,
        s: &mut SMatrix<f64, M, M>,
    ) -> Result<(), EkfError> {
        // With S = L·Lᵀ and U = P·Hᵀ·L⁻ᵀ: K·y = U·(L⁻¹·y) and K·H·P = U·Uᵀ. Two triangular
        // solves replace the explicit inverse, and P stays symmetric by construction. S becomes
        // L and P·Hᵀ becomes U in place: no copies of either.
        let inv_diag = kernels::cholesky_in_place(s).ok_or(EkfError::SingularInnovation)?;
        let (l, u) = (s, pht);
        kernels::solve_right_lower_t(u, l, &inv_diag);
        let a = kernels::solve_lower(l, &inv_diag, innovation);
        kernels::add_product(&mut self.x, u, &a);
        kernels::subtract_gram(&mut self.p, u);
        Ok(())
    }
}

/// The test ratio of each group: the largest over its rows of y_i²/(gate_sigma²·S_ii). A NaN
/// row makes its group's ratio NaN (a bad measurement must not read as a good one).
fn test_ratios<const M: usize>(
    innovation: &SVector<f64, M>,
    s: &SMatrix<f64, M, M>,
    groups: &[Group; M],
    gate_sigma: f64,
) -> TestRatios {
    let gate_sq = gate_sigma * gate_sigma;
    let mut out = TestRatios {
        attitude: 0.0,
        altitude: 0.0,
        gps: None,
    };
    for (i, group) in groups.iter().enumerate() {
        if let Some(slot) = out.slot(*group) {
            let y = innovation[i];
            let ratio = y * y / (gate_sq * s[(i, i)]);
            if ratio > *slot || ratio.is_nan() {
                *slot = ratio;
            }
        }
    }
    out
}

/// The ground is fused only into an estimate this close to resting on it: height, m, and
/// speed, m/s (a slow landing's estimate sinks 0.1–0.2 m below the ground and moves at
/// 0.25 m/s; a lost one is off by metres).
const GROUND_GATE_M: f64 = 0.3;
const GROUND_GATE_M_S: f64 = 0.5;
/// The rates a body resting on the ground turns at, and its gyros' bias states.
const STILL_RATES: [usize; 3] = [idx::WQX, idx::WQY, idx::WQZ];
const STILL_BIAS: [usize; 3] = [idx::BGX, idx::BGY, idx::BGZ];
/// A resting body's rate, (rad/s)²: 0.01 rad/s covers the ground levelling a landed vehicle
/// and the idling motors' shake (the gyro's own noise is in the rate states' doubt).
const R_STILL_RATE: f64 = 1e-4;
/// A body rate above this, rad/s, is a turn, not a resting body's (a MEMS gyro's bias
/// step is a few hundredths: the campaign's is 0.05).
const STILL_GATE_RAD_S: f64 = 0.2;
/// The ground's rows: z, then the body velocities.
const GROUND_OBS: [usize; 4] = [idx::Z, idx::VQX, idx::VQY, idx::VQZ];

impl Ekf {
    /// The ground as a measurement: the height `ground_m` and a still body, into the height
    /// and the body velocities only (a still body says nothing of the attitude; through the
    /// correlations a stuck gyro's wrong attitude would be pulled further).
    fn fuse_ground(&mut self, ground_m: f64) {
        // An estimate far from resting on the ground is not corrected onto it in one step:
        // the controller would fly the jump (a stuck gyro's estimate a metre up, pulled down,
        // launched the vehicle at full thrust).
        let v = [idx::VQX, idx::VQY, idx::VQZ].map(|i| self.x[i]);
        let speed_m_s = v.iter().map(|c| c * c).sum::<f64>().sqrt();
        if (self.x[idx::Z] - ground_m).abs() > GROUND_GATE_M || speed_m_s > GROUND_GATE_M_S {
            return;
        }
        let [rz, rv] = self.params.r_ground;
        let r = [rz, rv, rv, rv];
        let h = SMatrix::<f64, 4, N_STATES>::from_fn(|i, j| f64::from(GROUND_OBS[i] == j));
        let y = SVector::<f64, 4>::from_fn(|i, _| {
            let z = if i == 0 { ground_m } else { 0.0 };
            z - self.x[GROUND_OBS[i]]
        });
        // A singular S leaves the estimate as it was: the next step tries again.
        self.fuse_masked(&h, &y, &r, &GROUND_OBS);
    }

    /// A body resting on the ground does not turn: the rate states (what the gyro reads)
    /// less the bias are zero. Into the bias states only, so a bias that stepped while the
    /// vehicle waited on the ground is learnt there in a fraction of a second: nothing else
    /// teaches it without fixes (the IMU's angles read the thrust axis once it flies).
    fn fuse_still_rates(&mut self) {
        if !self.gyro_bias_on() || self.gyro_lost {
            return;
        }
        // A body turning faster than any bias is not resting (a halt's fall, a vehicle carried
        // about): its turn is not taught to the bias.
        let turning = (0..3)
            .any(|i| (self.x[STILL_RATES[i]] - self.x[STILL_BIAS[i]]).abs() > STILL_GATE_RAD_S);
        if turning {
            return;
        }
        let h = SMatrix::<f64, 3, N_STATES>::from_fn(|i, j| {
            if j == STILL_RATES[i] {
                1.0
            } else if j == STILL_BIAS[i] {
                -1.0
            } else {
                0.0
            }
        });
        let y = SVector::<f64, 3>::from_fn(|i, _| self.x[STILL_BIAS[i]] - self.x[STILL_RATES[i]]);
        self.fuse_masked(&h, &y, &[R_STILL_RATE; 3], &STILL_BIAS);
    }

    /// x += K·y and P = (I − K·H)·P·(I − K·H)ᵀ + K·R·Kᵀ (Joseph form: right for a gain cut
    /// to some states) with K = P·Hᵀ·S⁻¹ kept to the states in `keep`. `false`, nothing
    /// changed, when S cannot be inverted.
    pub(crate) fn fuse_masked<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, N_STATES>,
        y: &SVector<f64, M>,
        r: &[f64; M],
        keep: &[usize],
    ) -> bool {
        let pht = self.p * h.transpose();
        let mut s = h * pht;
        for (i, ri) in r.iter().enumerate() {
            s[(i, i)] += ri;
        }
        let Some(s_inv) = s.try_inverse() else {
            return false;
        };
        let mut gain = pht * s_inv;
        for st in (0..N_STATES).filter(|st| !keep.contains(st)) {
            gain.row_mut(st).fill(0.0);
        }
        self.x += gain * y;
        let i_kh = StateMatrix::identity() - gain * h;
        let mut krk = StateMatrix::zeros();
        for (c, rc) in r.iter().enumerate() {
            let col = gain.column(c);
            krk += col * col.transpose() * *rc;
        }
        self.p = i_kh * self.p * i_kh.transpose() + krk;
        true
    }
}

/// The vertical process noise per step without a barometer: the height follows its velocity
/// (a small floor keeps P positive), m²; the velocity wanders by 0.01 m/s a step (the
/// accelerometer's noise of about 0.5 m/s² over 10 ms, with room for the thrust model's
/// error), (m/s)².
const Q_Z_NO_BARO_M2: f64 = 1e-6;
const Q_VZ_NO_BARO: f64 = 1e-4;
/// The drag is read only while the motors carry most of the weight (`core::ekf_drag`): on
/// the ground friction and a slope would read as airspeed. Share of the weight.
const FLYING_THRUST_SHARE: f64 = 0.8;

/// The drag's process noise per step while it holds the velocity, (m/s²)².
const Q_BAXY_DRAG: f64 = 1e-6;

/// The IMU's roll and pitch rows while a push is read (`core::ekf_drag`), rad²: left to
/// the gyros.
const R_ANGLES_PUSHED_RAD2: f64 = 1e6;
/// Roll's and pitch's process noise per step meanwhile, rad²: a gyro's drift, 0.01 rad in a
/// second.
const Q_ANGLES_PUSHED_RAD2: f64 = 1e-6;

/// The rates' variance when the gyro is found stuck, (rad/s)²: 0.1 rad/s, their correlations
/// with every other state dropped. The ten stuck frames the detection takes leave rate errors
/// of 0.1-0.5 rad/s in the simulator's stuck-gyro holds, made by the controller flying against
/// a stuck reading, not the attitude's errors the correlations tie them to. The variance the
/// rates already had is about the same: what counts is the correlations dropped. Over 60
/// holds and 60 square missions (the field then fused every step), 0.003 and 0.03 (rad/s)²
/// landed worse and 0.1 (rad/s)² tumbled six of the square missions.
const VAR_W_AT_GYRO_LOSS: f64 = 0.01;
/// The rates' process noise per step without the gyro, (rad/s)².
const Q_W_NO_GYRO: f64 = 1e-5;
/// A lost gyro's rows, (rad/s)²: a rate known to a thousand rad/s is no measurement.
const R_GYRO_LOST: f64 = 1e6;

/// The accelerometer's vertical row without a barometer, (m/s²)²: a frame's noise on the
/// airframe, vibration included (about 1 m/s²).
const R_AZ_NO_BARO: f64 = 1.0;
/// The height's and vertical speed's variances when the barometer goes, m² and (m/s)²: a
/// 0.3 m and 0.1 m/s standard deviation.
const VAR_Z_AT_LOSS_M2: f64 = 0.09;
const VAR_VZ_AT_LOSS: f64 = 0.01;

/// The groups with a row that is not a number.
fn non_finite_groups<const M: usize>(z: &[f64; M], groups: &[Group; M]) -> GatedGroups {
    let mut out = GatedGroups::default();
    for (v, g) in z.iter().zip(groups) {
        if !v.is_finite() {
            match g {
                Group::Attitude => out.attitude = true,
                Group::Altitude => out.altitude = true,
                Group::Gps => out.gps = true,
                Group::Untested => {}
            }
        }
    }
    out
}

/// Takes the rows of the `gated` groups out of an update: zero innovation, a zero column of
/// P·Hᵀ, and a unit row and column of S. The Cholesky factor of that S has a unit row and
/// column there and, elsewhere, the factor of S without those rows (the zeros add exact
/// zeros), so W = P·Hᵀ·L⁻ᵀ has a zero row there and the gain and covariance correction are
/// those of the update without the rows: left out exactly, not drowned in a huge R. The
/// arrays keep their fixed size, so nothing is allocated.
fn leave_out<const M: usize>(
    gated: GatedGroups,
    groups: &[Group; M],
    innovation: &mut SVector<f64, M>,
    pht: &mut SMatrix<f64, N_STATES, M>,
    s: &mut SMatrix<f64, M, M>,
) {
    for (k, group) in groups.iter().enumerate() {
        if gated.contains(*group) {
            innovation[k] = 0.0;
            pht.column_mut(k).fill(0.0);
            s.row_mut(k).fill(0.0);
            s.column_mut(k).fill(0.0);
            s[(k, k)] = 1.0;
        }
    }
}

/// Row `k` (x, y, z) of a GPS measurement; a fix without altitude reads the barometer's
/// altitude `alt_m` for z.
fn gps_row(g: &GpsSample, k: usize, alt_m: f64) -> f64 {
    match k {
        0 | 1 => g.xy_m[k],
        _ => g.z_m.unwrap_or(alt_m),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::model::w_hover_rad_s;

    fn some_state() -> State {
        State::from([
            0.3, -0.2, 1.1, 0.05, -0.08, 1.9, 0.4, -0.3, 0.2, 0.1, -0.15, 0.07, 0.02, -0.01, 0.03,
        ])
    }

    #[test]
    fn hover_is_an_equilibrium_of_the_model() {
        let m = 1.55;
        let w = w_hover_rad_s(m);
        let x = State::zeros();
        for orig in [true, false] {
            let n = process(&x, &[w; 4], 0.01, m, orig);
            assert!(n.norm() < 1e-12, "{n}");
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let u = [300.0, 310.0, 295.0, 305.0];
        let t = 0.01;
        for orig in [true, false] {
            let x = some_state();
            let f = jacobian(&x, &u, t, orig);
            let h = 1e-6;
            for j in 0..N_MODEL {
                let mut xp = x;
                let mut xm = x;
                xp[j] += h;
                xm[j] -= h;
                let col =
                    (process(&xp, &u, t, 1.55, orig) - process(&xm, &u, t, 1.55, orig)) / (2.0 * h);
                for i in 0..N_MODEL {
                    assert!(
                        (f[(i, j)] - col[i]).abs() < 1e-8,
                        "orig {orig}: F[{i}][{j}] = {} but finite difference {}",
                        f[(i, j)],
                        col[i]
                    );
                }
            }
        }
    }

    #[test]
    fn sparse_propagation_equals_the_dense_product() {
        let a = StateMatrix::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
        let p = a * a.transpose() + StateMatrix::identity();
        let mut params = EkfParams::flight_2012();
        params.gyro_bias_q = 1e-9;
        let ekf = Ekf::new(params, &ImuSample::default());
        for orig in [true, false] {
            let f = jacobian(&some_state(), &[300.0, 310.0, 295.0, 305.0], 0.01, orig);
            let f = ekf.filter_jacobian(&f);
            let dense = f * p * f.transpose();
            let mut sparse = p;
            kernels::propagate_covariance(&f, &mut sparse);
            assert!((dense - sparse).abs().max() < 1e-12 * dense.abs().max());
            assert_eq!(sparse, sparse.transpose());
        }
    }

    #[test]
    fn the_jacobian_writes_only_inside_the_fixed_structure() {
        let u = [300.0, 310.0, 295.0, 305.0];
        for orig in [true, false] {
            for scale in [0.0, 0.5, 1.0, -2.0] {
                let f = jacobian(&(some_state() * scale), &u, 0.01, orig);
                for i in 0..N_MODEL {
                    for j in 0..N_MODEL {
                        let d = f[(i, j)] - if i == j { 1.0 } else { 0.0 };
                        let listed = kernels::D_COLS[i].contains(&j);
                        assert!(
                            d == 0.0 || listed,
                            "orig {orig}: D[{i}][{j}] = {d} unlisted"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn original_and_corrected_models_differ_only_in_the_x_and_z_rows() {
        let x = some_state();
        let u = [300.0; 4];
        let a = process(&x, &u, 0.01, 1.55, true);
        let b = process(&x, &u, 0.01, 1.55, false);
        let (c_psi, c_phi, s_th) = (x[idx::PSI].cos(), x[idx::PHI].cos(), x[idx::THETA].sin());
        for i in 0..N_MODEL {
            if i == idx::Z {
                let expected = 0.01 * x[idx::VQZ] * (c_psi * c_psi - c_phi * c_psi);
                assert!((a[i] - b[i] - expected).abs() < 1e-15);
                assert!((a[i] - b[i]).abs() > 1e-6);
            } else if i == idx::X {
                let expected = -0.01 * x[idx::VQY] * (c_phi - c_psi) * s_th;
                assert!((a[i] - b[i] - expected).abs() < 1e-15);
                assert!((a[i] - b[i]).abs() > 1e-6);
            } else {
                assert_eq!(a[i], b[i], "row {i}");
            }
        }
    }

    #[test]
    fn update_pulls_towards_measurement_and_shrinks_covariance() {
        let mut params = EkfParams::flight_2012();
        params.original_model = false;
        let null = ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        let mut ekf = Ekf::new(params, &null);
        let m = 1.55;
        let w = w_hover_rad_s(m);
        let mut s = null;
        s.euler_rad = [0.1, 0.0, 0.0];
        s.alt_m = 2.0;
        let p_before = ekf.p;
        let (rep, res) = ekf.step(
            &s,
            &StepInput {
                u_rad_s: [w; 4],
                mass_kg: m,
                dt_us: 20_000,
                gps: Some(GpsSample::at([1.0, -1.0, 0.0])),
                ground_m: None,
                at_rest: false,
            },
        );
        res.unwrap();
        assert!(rep.dt_clamped && rep.dt_used_us == 12_000);
        assert!(ekf.x[idx::PSI] > 0.0 && ekf.x[idx::PSI] < 0.1);
        assert!(ekf.x[idx::X] > 0.5 && ekf.x[idx::Y] < -0.5, "{}", ekf.x);
        // Rates are trusted (R = 1e-3): the estimate follows the gyro closely.
        assert!(ekf.p[(idx::WQX, idx::WQX)] < 1e-2);
        assert!(ekf.p[(idx::X, idx::X)] < p_before[(idx::X, idx::X)] + 100.0);
        // A NaN measurement leaves a finite prediction and says why.
        s.acc_m_s2[0] = f64::NAN;
        let (_, res) = ekf.step(
            &s,
            &StepInput {
                u_rad_s: [w; 4],
                mass_kg: m,
                dt_us: 10_000,
                gps: None,
                ground_m: None,
                at_rest: false,
            },
        );
        assert_eq!(res, Err(EkfError::NonFiniteMeasurement));
        assert!(ekf.x.iter().all(|v| v.is_finite()));
    }

    /// The predicted az of the update tests, m/s².
    const AZ_PRED: f64 = 0.5;

    /// A filter at `some_state` with covariance `p` and the 2012 noise, gate 5 σ.
    fn filter(p: StateMatrix, gate_fusion: bool) -> Ekf {
        let params = EkfParams {
            gate_fusion,
            ..EkfParams::flight_2012()
        };
        let mut ekf = Ekf::new(params, &ImuSample::default());
        ekf.x = FilterState::from_fn(|i, _| some_state().get(i).copied().unwrap_or(0.0));
        ekf.p = p;
        ekf
    }

    /// A covariance with correlations between every pair of states.
    fn correlated() -> StateMatrix {
        let a = StateMatrix::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 / 10.0 - 0.5);
        a * a.transpose() + StateMatrix::identity()
    }

    /// An IMU + GPS measurement whose row i lies `sigmas[i]` standard deviations of its
    /// innovation (√S_ii) from the prediction.
    fn measurement(ekf: &Ekf, sigmas: [f64; GPS_ROWS]) -> [f64; GPS_ROWS] {
        let r = ekf.params.r_gps_diag;
        std::array::from_fn(|i| {
            let s_ii = ekf.p[(GPS_OBS[i], GPS_OBS[i])] + r[i];
            let h = if i == 5 { AZ_PRED } else { ekf.x[GPS_OBS[i]] };
            h + sigmas[i] * s_ii.sqrt()
        })
    }

    fn gps_update(ekf: &mut Ekf, z: &[f64; GPS_ROWS]) -> UpdateOutcome {
        let r = ekf.params.r_gps_diag;
        ekf.update::<GPS_ROWS>(z, &GPS_OBS, &GPS_GROUPS, AZ_PRED, &r)
    }

    /// The textbook update K = P·Hᵀ·S⁻¹ on the rows `keep` accepts, in dense matrices.
    fn reference_update(ekf: &Ekf, z: &[f64; GPS_ROWS], keep: impl Fn(usize) -> bool) -> Ekf {
        use nalgebra::{DMatrix, DVector};
        let rows: Vec<usize> = (0..GPS_ROWS).filter(|&i| keep(i)).collect();
        let m = rows.len();
        let h = DMatrix::from_fn(m, N_STATES, |i, j| f64::from(GPS_OBS[rows[i]] == j));
        let y = DVector::from_fn(m, |i, _| {
            let k = rows[i];
            z[k] - if k == 5 { AZ_PRED } else { ekf.x[GPS_OBS[k]] }
        });
        let r = DVector::from_fn(m, |i, _| ekf.params.r_gps_diag[rows[i]]);
        let p = DMatrix::from_fn(N_STATES, N_STATES, |i, j| ekf.p[(i, j)]);
        let s = &h * &p * h.transpose() + DMatrix::from_diagonal(&r);
        let k = &p * h.transpose() * s.try_inverse().unwrap();
        let mut out = ekf.clone();
        out.x += FilterState::from_fn(|i, _| (&k * &y)[i]);
        let kp = &k * &h * &p;
        out.p -= StateMatrix::from_fn(|i, j| kp[(i, j)]);
        out
    }

    fn assert_close(a: &Ekf, b: &Ekf) {
        let dx = (a.x - b.x).abs().max();
        let dp = (a.p - b.p).abs().max();
        assert!(dx < 1e-12 && dp < 1e-12, "x differs by {dx}, P by {dp}");
    }

    #[test]
    fn a_consistent_measurement_is_inside_the_gate() {
        let mut ekf = filter(correlated(), true);
        let z = measurement(&ekf, [1.0; GPS_ROWS]);
        let out = gps_update(&mut ekf, &z);
        out.result.unwrap();
        // 1 σ in a 5 σ gate: 1/25 for every group.
        for ratio in [
            out.ratios.attitude,
            out.ratios.altitude,
            out.ratios.gps.unwrap(),
        ] {
            assert!((ratio - 0.04).abs() < 1e-12, "{ratio}");
        }
        assert_eq!(out.gated, GatedGroups::default());
    }

    #[test]
    fn a_measurement_ten_sigma_off_is_gated_and_leaves_its_states_alone() {
        // P = I: each row moves only the state it observes.
        let mut ekf = filter(StateMatrix::identity(), true);
        let before = ekf.clone();
        let mut sigmas = [1.0; GPS_ROWS];
        sigmas[1] = 10.0; // φ
        let z = measurement(&ekf, sigmas);
        let out = gps_update(&mut ekf, &z);
        out.result.unwrap();
        assert!(
            (out.ratios.attitude - 4.0).abs() < 1e-12,
            "{:?}",
            out.ratios
        );
        assert!(out.ratios.altitude < 1.0 && out.ratios.gps.unwrap() < 1.0);
        let attitude_only = GatedGroups {
            attitude: true,
            ..GatedGroups::default()
        };
        assert_eq!(out.gated, attitude_only);
        for i in [idx::PSI, idx::PHI, idx::THETA] {
            assert_eq!(ekf.x[i], before.x[i], "state {i}");
            assert_eq!(ekf.p[(i, i)], before.p[(i, i)], "variance {i}");
        }
        // The other groups still update.
        for i in [idx::X, idx::Y, idx::Z, idx::WQX, idx::BAX] {
            assert_ne!(ekf.x[i], before.x[i], "state {i}");
            assert!(ekf.p[(i, i)] < before.p[(i, i)], "variance {i}");
        }
    }

    #[test]
    fn a_gated_group_is_left_out_exactly() {
        // With correlations, the gated rows must be left out as if they were not there: the
        // value of the rejected measurement changes nothing, and the result is the update on
        // the other rows.
        let start = filter(correlated(), true);
        let fused = |off_sigma: f64| {
            let mut sigmas = [0.5; GPS_ROWS];
            sigmas[9] = off_sigma; // GPS x
            let z = measurement(&start, sigmas);
            let mut ekf = start.clone();
            let out = gps_update(&mut ekf, &z);
            out.result.unwrap();
            assert!(out.gated.gps && !out.gated.attitude && !out.gated.altitude);
            (ekf, z)
        };
        let (ten, z) = fused(10.0);
        let (thirty, _) = fused(-30.0);
        assert_eq!((ten.x, ten.p), (thirty.x, thirty.p));
        assert_close(
            &ten,
            &reference_update(&start, &z, |i| !(9..=10).contains(&i)),
        );
        assert_ne!(ten.x[idx::Z], start.x[idx::Z]);
    }

    #[test]
    fn with_gating_off_every_row_is_fused_as_the_ungated_update() {
        let mut sigmas = [1.0; GPS_ROWS];
        sigmas[11] = 10.0; // GPS z
        let start = filter(correlated(), false);
        let z = measurement(&start, sigmas);
        let mut off = start.clone();
        let out = gps_update(&mut off, &z);
        out.result.unwrap();
        assert!(out.ratios.altitude > 1.0, "{:?}", out.ratios);
        assert_eq!(out.gated, GatedGroups::default());
        // Bit for bit the update of a gate nothing leaves, and the textbook update.
        let mut wide = start.clone();
        wide.params.gate_fusion = true;
        wide.params.gate_sigma = 1e6;
        let wide_out = gps_update(&mut wide, &z);
        assert_eq!(wide_out.gated, GatedGroups::default());
        assert_eq!((off.x, off.p), (wide.x, wide.p));
        assert_close(&off, &reference_update(&start, &z, |_| true));
    }

    #[test]
    fn a_step_reports_its_ratios() {
        let null = ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        let mut ekf = Ekf::new(EkfParams::flight_2012(), &null);
        let mut input = StepInput::hover_10ms();
        let (rep, res) = ekf.step(&null, &input);
        res.unwrap();
        assert!(rep.ratios.attitude < 1e-3 && rep.ratios.altitude < 1e-3);
        assert_eq!(rep.ratios.gps, None);
        input.gps = Some(GpsSample::at([0.0, 0.0, 0.0]));
        let (rep, _) = ekf.step(&null, &input);
        assert!(rep.ratios.gps.is_some_and(|r| r < 1e-3));
        // A measurement that is not a number: its group's ratio says so, nothing is gated.
        let mut bad = null;
        bad.alt_m = f64::NAN;
        input.gps = None;
        let (rep, res) = ekf.step(&bad, &input);
        assert_eq!(res, Err(EkfError::NonFiniteMeasurement));
        assert!(rep.ratios.altitude.is_nan() && rep.ratios.attitude < 1e-3);
        assert_eq!(rep.gated, GatedGroups::default());
    }

    #[test]
    fn a_lost_gyro_is_left_out_and_the_rates_follow_the_model() {
        let null = ImuSample {
            acc_m_s2: [0.0, 0.0, GRAVITY_M_S2],
            ..ImuSample::default()
        };
        let input = StepInput::hover_10ms();
        for fusion in [GpsFusion::Joint, GpsFusion::PositionVelocity] {
            let params = EkfParams {
                gps_fusion: fusion,
                ..EkfParams::flight_2012()
            };
            let (mut live, mut lost) = (Ekf::new(params.clone(), &null), Ekf::new(params, &null));
            let mut spinning = null;
            spinning.gyro_rad_s = [0.5, 0.0, 0.0];
            let mut stuck = null;
            stuck.gyro_rad_s = [f64::NAN; 3];
            for _ in 0..20 {
                live.step(&spinning, &input).1.unwrap();
                lost.step(&stuck, &input).1.unwrap();
            }
            assert!(live.x[idx::WQX] > 0.4 && !live.gyro_lost, "{fusion:?}");
            // Level and balanced motors: the model's rates stay at rest.
            assert!(
                lost.x[idx::WQX].abs() < 1e-9 && lost.gyro_lost,
                "{fusion:?}"
            );
            assert!(lost.x.iter().all(|v| v.is_finite()), "{fusion:?}");
        }
    }

    #[test]
    fn a_fix_without_altitude_leaves_the_altitude_to_the_barometer() {
        // The barometer reads 2 m. A 2D fix (no z) leaves the altitude where the barometer
        // alone puts it; a 3D fix at z = 0 pulls it down.
        let null = crate::core::imu::calib::ImuSample {
            acc_m_s2: [0.0, 0.0, 9.81],
            ..Default::default()
        };
        let z_after = |gps: Option<GpsSample>| {
            let mut ekf = Ekf::new(EkfParams::flight_2012(), &null);
            let mut s = null;
            s.alt_m = 2.0;
            for _ in 0..300 {
                let input = StepInput {
                    u_rad_s: [w_hover_rad_s(1.55); 4],
                    mass_kg: 1.55,
                    dt_us: 10_000,
                    gps,
                    ground_m: None,
                    at_rest: false,
                };
                ekf.step(&s, &input).1.unwrap();
            }
            ekf.x[idx::Z]
        };
        let baro_only = z_after(None);
        let two_d = z_after(Some(GpsSample {
            xy_m: [0.0, 0.0],
            z_m: None,
            vel_m_s: None,
        }));
        let three_d = z_after(Some(GpsSample::at([0.0, 0.0, 0.0])));
        assert!((two_d - baro_only).abs() < 1e-6, "{two_d} vs {baro_only}");
        assert!(three_d < baro_only - 0.5, "{three_d} vs {baro_only}");
    }

    #[test]
    fn the_nis_of_a_group_is_its_innovation_weighed_by_its_covariance() {
        // Rows 0 and 2 of a correlated S: yᵀ·S⁻¹·y by hand.
        let s = SMatrix::<f64, 3, 3>::new(4.0, 0.0, 1.0, 0.0, 9.0, 0.0, 1.0, 0.0, 2.0);
        let y = SVector::<f64, 3>::new(1.0, 5.0, -1.0);
        let nis = group_nis(&y, &s, [0, 2].into_iter()).unwrap();
        // S₀₂ = [[4, 1], [1, 2]], det 7, inverse [[2, -1], [-1, 4]] / 7; y = (1, -1).
        assert!(
            (nis.value - (2.0 + 2.0 + 4.0) / 7.0).abs() < 1e-12,
            "{nis:?}"
        );
        assert_eq!(nis.dof, 2);
        assert!(group_nis(&y, &s, std::iter::empty()).is_none());
        let bad = SVector::<f64, 3>::new(f64::NAN, 0.0, 0.0);
        assert!(group_nis(&bad, &s, [0].into_iter()).is_none());
        assert!(group_nis(&y, &s, [0, 1, 2, 0, 1].into_iter()).is_none());
    }

    #[test]
    fn the_ground_holds_a_resting_estimate_and_leaves_a_lost_one() {
        // Rows far surer than the estimate (P₀ = 1).
        let params = EkfParams {
            ground_fusion: true,
            r_ground: [1e-4, 1e-4],
            ..EkfParams::flight_2012()
        };
        let mut ekf = Ekf::new(params, &ImuSample::default());
        let mut near = ekf.clone();
        near.x[idx::Z] = -0.15;
        near.x[idx::VQZ] = -0.2;
        near.fuse_ground(0.0);
        assert!(
            near.x[idx::Z].abs() < 0.05 && near.x[idx::VQZ].abs() < 0.05,
            "{:?}",
            near.x
        );
        // Only the height and the body velocity move.
        assert_eq!(near.x[idx::PSI], 0.0);
        // A metre off (a lost estimate): left as it is.
        ekf.x[idx::Z] = 1.0;
        ekf.fuse_ground(0.0);
        assert_eq!(ekf.x[idx::Z], 1.0);
        // Off without ground_fusion: the step ignores the ground.
        let mut off = Ekf::new(
            EkfParams {
                r_ground: [1e-4, 1e-4],
                ..EkfParams::flight_2012()
            },
            &ImuSample::default(),
        );
        off.x[idx::Z] = -0.15;
        let input = StepInput {
            u_rad_s: [0.0; 4],
            mass_kg: 1.55,
            dt_us: 10_000,
            gps: None,
            ground_m: Some(0.0),
            at_rest: true,
        };
        let mut sample = ImuSample::default();
        sample.acc_m_s2[2] = GRAVITY_M_S2;
        sample.alt_m = -0.15;
        let mut on = off.clone();
        on.params.ground_fusion = true;
        off.step(&sample, &input).1.unwrap();
        on.step(&sample, &input).1.unwrap();
        assert!(
            on.x[idx::Z] > off.x[idx::Z] + 0.05,
            "{} {}",
            on.x[idx::Z],
            off.x[idx::Z]
        );
    }
}
