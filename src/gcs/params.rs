//! Parameters: the profile's numeric and true/false keys under MAVLink ids of at most 16
//! characters (the table below is the mapping; `uquad params` prints it with the values).
//! Text keys (paths, modes, actions) and lists are not parameters.
//!
//! Ids are the section's short name, an underscore and the key shortened: VEH vehicle, IMU,
//! EKF, CTL control, MAN control.manual, INT control.integral, MOT motor, ESC, WD watchdog,
//! LOG, GPS, SIM, CMD commander, FS failsafe, FEN fence, GCS.

use crate::config::Config;
use mavlink::dialects::common::MavParamType;

/// (id, dotted key), in the order a ground station lists them.
pub const TABLE: &[(&str, &str)] = &[
    ("VEH_MASS_KG", "vehicle.mass_kg"),
    ("IMU_BAUD", "imu.baud"),
    ("IMU_SETTLE_N", "imu.settle_frames"),
    ("IMU_SETTLE_MAX_N", "imu.settle_max_frames"),
    ("IMU_SETTLE_TO_S", "imu.settle_timeout_s"),
    ("IMU_PER_MIN_US", "imu.period_min_us"),
    ("IMU_PER_MAX_US", "imu.period_max_us"),
    ("IMU_CALIB_N", "imu.calib_frames"),
    ("EKF_ORIG_MODEL", "ekf.original_model"),
    ("EKF_GATE_SIGMA", "ekf.gate_sigma"),
    ("EKF_GATE_FUSE", "ekf.gate_fusion"),
    ("CTL_STATES", "control.states"),
    ("CTL_ORIG_TIMING", "control.original_timing"),
    ("CTL_ERR_LIMITS", "control.error_limits"),
    ("CTL_HOVER_Z_M", "control.hover_z_m"),
    ("CTL_GPS_HOLD_S", "control.gps_hold_timeout_s"),
    ("CTL_TQ_OBS_S", "control.torque_observer_s"),
    ("MAN_TILT_MAX", "control.manual.max_tilt_rad"),
    ("MAN_YAW_OFF_MAX", "control.manual.max_yaw_offset_rad"),
    ("MAN_Z_MIN_M", "control.manual.z_min_m"),
    ("MAN_Z_MAX_M", "control.manual.z_max_m"),
    ("MAN_MASS_MIN_KG", "control.manual.mass_min_kg"),
    ("MAN_MASS_MAX_KG", "control.manual.mass_max_kg"),
    ("INT_PSI_STEP", "control.integral.psi.step_max"),
    ("INT_PSI_CAP", "control.integral.psi.cap"),
    ("INT_PSI_THRESH", "control.integral.psi.threshold"),
    ("INT_PSI_SEED", "control.integral.psi.seed"),
    ("INT_PHI_STEP", "control.integral.phi.step_max"),
    ("INT_PHI_CAP", "control.integral.phi.cap"),
    ("INT_PHI_THRESH", "control.integral.phi.threshold"),
    ("INT_PHI_SEED", "control.integral.phi.seed"),
    ("INT_Z_STEP", "control.integral.z.step_max"),
    ("INT_Z_CAP", "control.integral.z.cap"),
    ("INT_Z_THRESH", "control.integral.z.threshold"),
    ("INT_Z_SEED", "control.integral.z.seed"),
    ("INT_THETA_STEP", "control.integral.theta.step_max"),
    ("INT_THETA_CAP", "control.integral.theta.cap"),
    ("INT_THETA_THRESH", "control.integral.theta.threshold"),
    ("INT_THETA_SEED", "control.integral.theta.seed"),
    ("INT_X_STEP", "control.integral.x.step_max"),
    ("INT_X_CAP", "control.integral.x.cap"),
    ("INT_X_THRESH", "control.integral.x.threshold"),
    ("INT_X_SEED", "control.integral.x.seed"),
    ("INT_Y_STEP", "control.integral.y.step_max"),
    ("INT_Y_CAP", "control.integral.y.cap"),
    ("INT_Y_THRESH", "control.integral.y.threshold"),
    ("INT_Y_SEED", "control.integral.y.seed"),
    ("MOT_W_MAX", "motor.w_max_rad_s"),
    ("MOT_TAU_S", "motor.tau_s"),
    ("ESC_RESEND_MS", "esc.resend_ms"),
    ("ESC_CMD_TO_MS", "esc.command_timeout_ms"),
    ("WD_DEADLINE_MS", "watchdog.deadline_ms"),
    ("WD_IMU_TO_MS", "watchdog.imu_timeout_ms"),
    ("WD_MISSED_ACKS", "watchdog.max_missed_acks"),
    ("WD_TEMP_MAX_C", "watchdog.sanity_temp_max_c"),
    ("WD_TILT_MAX", "watchdog.sanity_tilt_max_rad"),
    ("WD_SANITY_MAX", "watchdog.sanity_max"),
    ("WD_EKF_REFUSED", "watchdog.estimator_max_refused"),
    ("WD_HALT_RETRY_MS", "watchdog.halt_retry_ms"),
    ("LOG_QUEUE", "log.queue_records"),
    ("GPS_SEED", "gps.seed"),
    ("GPS_FAKE_SPAN_M", "gps.fake_span_m"),
    ("SIM_DURATION_S", "sim.duration_s"),
    ("SIM_SETTLE_S", "sim.settle_s"),
    ("SIM_PHYS_HZ", "sim.physics_hz"),
    ("SIM_MOT_TAU_S", "sim.motor_tau_s"),
    ("SIM_DRAG", "sim.drag_n_per_m_s"),
    ("SIM_ACC_NOISE", "sim.acc_noise_m_s2"),
    ("SIM_GYRO_NOISE", "sim.gyro_noise_rad_s"),
    ("SIM_BARO_NOISE", "sim.baro_noise_pa"),
    ("SIM_MAG_NOISE", "sim.mag_noise"),
    ("SIM_TEMP_C", "sim.temp_c"),
    ("SIM_YAW0", "sim.initial_yaw_rad"),
    ("SIM_SEED", "sim.seed"),
    ("SIM_GUST_N", "sim.gust_n"),
    ("SIM_GUST_S", "sim.gust_s"),
    ("SIM_GPS_HZ", "sim.gps_rate_hz"),
    ("SIM_GPS_DELAY_S", "sim.gps_delay_s"),
    ("SIM_GPS_NOISE_H", "sim.gps_noise_h_m"),
    ("SIM_GPS_NOISE_V", "sim.gps_noise_v_m"),
    ("SIM_GPS_BIAS_H", "sim.gps_bias_h_m"),
    ("SIM_GPS_BIAS_V", "sim.gps_bias_v_m"),
    ("SIM_GPS_TAU_S", "sim.gps_bias_tau_s"),
    ("SIM_GPS_VEL_NOI", "sim.gps_noise_vel_m_s"),
    ("EKF_R_GPS_VEL", "ekf.r_gps_vel"),
    ("EKF_DRAG_PER_S", "ekf.drag_per_s"),
    ("CMD_CLIMB_M_S", "commander.climb_m_s"),
    ("CMD_CLIMB_ACC", "commander.climb_acc_m_s2"),
    ("CMD_TKO_TOL_M", "commander.takeoff_tolerance_m"),
    ("CMD_LAND_M_S", "commander.land_m_s"),
    ("CMD_LAND_SLOW", "commander.land_slow_m_s"),
    ("CMD_TD_V_M_S", "commander.touchdown_v_m_s"),
    ("CMD_TD_THRUST", "commander.touchdown_thrust"),
    ("CMD_TD_S", "commander.touchdown_s"),
    ("CMD_GPS_EPH_M", "commander.gps_max_eph_m"),
    ("CMD_DISARM_GND", "commander.disarm_ground_s"),
    ("CMD_CRASH_TILT", "commander.crash_tilt_rad"),
    ("CMD_CRASH_S", "commander.crash_s"),
    ("CMD_TKO_TIMEOUT", "commander.takeoff_timeout_s"),
    ("FS_LINK_TO_S", "failsafe.link_timeout_s"),
    ("FS_GPS_LAND_S", "failsafe.gps_loss_land_s"),
    ("FS_EKF_BAD_S", "failsafe.ekf_bad_s"),
    ("FEN_RADIUS_M", "fence.radius_m"),
    ("FEN_ALT_MAX_M", "fence.alt_max_m"),
    ("GCS_BAUD", "gcs.baud"),
    ("GCS_SYSID", "gcs.system_id"),
    ("GCS_TELEM_HZ", "gcs.telemetry_hz"),
    ("GCS_MAX_RX_S", "gcs.max_rx_per_s"),
    ("MIS_ACC_M_S2", "mission.acc_m_s2"),
    ("MIS_YAW_RATE", "mission.yaw_rate_rad_s"),
    ("MIS_YAW_ACC", "mission.yaw_acc_rad_s2"),
    ("MIS_RETURN_M_S", "mission.return_m_s"),
    ("MIS_SPEED_M_S", "mission.speed_m_s"),
    ("MIS_PATH_GAINS", "mission.path_gains"),
];

/// How a parameter's value is written in the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Int,
    Float,
    Bool,
}

impl Kind {
    /// The type announced in PARAM_VALUE; the value itself always travels as the float it is
    /// (MAVLink's "C cast" encoding).
    pub fn wire(self) -> MavParamType {
        match self {
            Kind::Int => MavParamType::MAV_PARAM_TYPE_INT32,
            Kind::Float => MavParamType::MAV_PARAM_TYPE_REAL32,
            Kind::Bool => MavParamType::MAV_PARAM_TYPE_UINT8,
        }
    }
}

/// One parameter and its current value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Param {
    pub id: &'static str,
    pub key: &'static str,
    pub kind: Kind,
    pub value: f64,
}

impl Param {
    /// Keys whose change is refused while armed: all but the simulator's, the logs', the
    /// console's and the link's own.
    pub fn flight_critical(&self) -> bool {
        !["sim.", "log.", "console.", "gcs."]
            .iter()
            .any(|s| self.key.starts_with(s))
    }

    /// A value sent by a ground station as the TOML value of this key: whole for an integer
    /// key, 0 or 1 for a true/false key; a float by its shortest decimal (0.4 arrives as the
    /// f32 nearest 0.4 and is kept as 0.4, not 0.4000000059604645).
    pub fn toml_value(&self, v: f32) -> Result<toml::Value, String> {
        if !v.is_finite() {
            return Err(format!("{v} is not a number"));
        }
        match self.kind {
            Kind::Float => Ok(toml::Value::Float(
                v.to_string().parse().unwrap_or(f64::from(v)),
            )),
            Kind::Int if v.fract() == 0.0 => Ok(toml::Value::Integer(v as i64)),
            Kind::Int => Err(format!("{v}: a whole number is needed")),
            Kind::Bool if v == 0.0 || v == 1.0 => Ok(toml::Value::Boolean(v == 1.0)),
            Kind::Bool => Err(format!("{v}: 0 (false) or 1 (true) is needed")),
        }
    }
}

/// Every parameter with its value in a configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    list: Vec<Param>,
}

impl Params {
    /// The parameters of `c`. A key of the table that `c` does not have as a number or a
    /// true/false value is a programming error caught by the tests; it is skipped here.
    pub fn of(c: &Config) -> Params {
        let table = toml::Table::try_from(c).unwrap_or_default();
        let list = TABLE
            .iter()
            .filter_map(|&(id, key)| {
                let (kind, value) = number_at(&table, key)?;
                Some(Param {
                    id,
                    key,
                    kind,
                    value,
                })
            })
            .collect();
        Params { list }
    }

    pub fn len(&self) -> usize {
        self.list.len()
    }

    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    pub fn get(&self, index: usize) -> Option<&Param> {
        self.list.get(index)
    }

    /// The index of the parameter called `id`.
    pub fn find(&self, id: &str) -> Option<usize> {
        self.list.iter().position(|p| p.id == id)
    }

    pub fn set(&mut self, index: usize, value: f64) {
        if let Some(p) = self.list.get_mut(index) {
            p.value = value;
        }
    }
}

/// The number (or true/false, as 0 or 1) at dotted `key` of a configuration table.
fn number_at(table: &toml::Table, key: &str) -> Option<(Kind, f64)> {
    let mut parts = key.split('.').peekable();
    let mut cur = table;
    while let Some(part) = parts.next() {
        let v = cur.get(part)?;
        if parts.peek().is_some() {
            cur = v.as_table()?;
            continue;
        }
        return match v {
            toml::Value::Integer(i) => Some((Kind::Int, *i as f64)),
            toml::Value::Float(f) => Some((Kind::Float, *f)),
            toml::Value::Boolean(b) => Some((Kind::Bool, f64::from(u8::from(*b)))),
            _ => None,
        };
    }
    None
}

/// The value of a parameter as a number of its kind (for the TOML value a set keeps).
pub fn value_of(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Integer(i) => Some(*i as f64),
        toml::Value::Float(f) => Some(*f),
        toml::Value::Boolean(b) => Some(f64::from(u8::from(*b))),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every number and true/false key of a configuration, dotted.
    fn numeric_keys(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (k, v) in t {
            let key = format!("{prefix}{k}");
            match v {
                toml::Value::Table(sub) => numeric_keys(sub, &format!("{key}."), out),
                toml::Value::Integer(_) | toml::Value::Float(_) | toml::Value::Boolean(_) => {
                    out.push(key)
                }
                _ => {}
            }
        }
    }

    #[test]
    fn the_table_maps_every_numeric_key_once_to_a_short_unique_id() {
        let c = Config::default();
        let mut keys = Vec::new();
        numeric_keys(&toml::Table::try_from(&c).unwrap(), "", &mut keys);
        let mut mapped: Vec<String> = TABLE.iter().map(|(_, k)| k.to_string()).collect();
        keys.sort();
        mapped.sort();
        assert_eq!(keys, mapped, "every number and true/false key has an id");
        let mut ids: Vec<&str> = TABLE.iter().map(|(id, _)| *id).collect();
        assert!(ids.iter().all(|id| id.len() <= 16 && id.is_ascii()));
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), TABLE.len(), "ids are unique");
        assert_eq!(Params::of(&c).len(), TABLE.len());
    }

    #[test]
    fn ground_station_values_become_the_keys_own_kind() {
        let p = Params::of(&Config::default());
        let get = |id| *p.get(p.find(id).unwrap()).unwrap();
        let climb = get("CMD_CLIMB_M_S");
        assert_eq!(climb.value, 0.5);
        assert_eq!(climb.toml_value(0.4).unwrap(), toml::Value::Float(0.4));
        assert!(climb.flight_critical());
        let acks = get("WD_MISSED_ACKS");
        assert_eq!(acks.kind, Kind::Int);
        assert_eq!(acks.toml_value(4.0).unwrap(), toml::Value::Integer(4));
        assert!(acks.toml_value(4.5).is_err());
        let fuse = get("EKF_GATE_FUSE");
        assert_eq!(fuse.toml_value(0.0).unwrap(), toml::Value::Boolean(false));
        assert!(fuse.toml_value(2.0).is_err());
        assert!(climb.toml_value(f32::NAN).is_err());
        assert!(!get("SIM_GUST_N").flight_critical());
    }
}
