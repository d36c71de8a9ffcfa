//! Parameters served to a ground station: the profile's numeric and true/false keys under
//! MAVLink ids of at most 16 characters (the mapping is `config::PARAMETERS`; `uquad params`
//! prints it with the values). Text keys (paths, modes, actions) and lists are not
//! parameters.

use crate::config::Config;
use mavlink::dialects::common::MavParamType;

/// (id, dotted key), in the order a ground station lists them (the configuration's list:
/// `params.toml` holds these keys only).
pub const TABLE: &[(&str, &str)] = crate::config::PARAMETERS;

/// How a parameter's value is written in the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Int,
    Float,
    Bool,
}

impl Kind {
    /// The type announced in PARAM_VALUE: REAL32 for every kind. An integer or a true/false
    /// value announced as INT32 or UINT8 travels in the float field either as the number
    /// (the "C cast" encoding, ArduPilot's) or as its bytes (the "bytewise" one, PX4's), and
    /// a client that assumes the other shows 1077936128 for 3 or drops the parameter. A REAL32
    /// reads the same under both; every integer parameter here is within ±2^24, which a REAL32
    /// holds exactly.
    pub fn wire(self) -> MavParamType {
        MavParamType::MAV_PARAM_TYPE_REAL32
    }
}

/// The number a PARAM_SET carries, whatever type its sender declared: REAL32 as it is; an
/// integer type as the number (C cast), unless the float is what an integer's bytes look
/// like (bytewise): a subnormal (a small positive integer) or a NaN whose bytes are a small
/// negative one. A fraction stays a fraction (an integer key refuses it, named).
pub fn set_value(value: f32, declared: MavParamType) -> f32 {
    use MavParamType::*;
    const EXACT: i64 = 1 << 24;
    let bits = value.to_bits();
    let bytewise = match declared {
        MAV_PARAM_TYPE_REAL32 | MAV_PARAM_TYPE_REAL64 => None,
        MAV_PARAM_TYPE_UINT8 => Some(i64::from(bits as u8)),
        MAV_PARAM_TYPE_INT8 => Some(i64::from(bits as u8 as i8)),
        MAV_PARAM_TYPE_UINT16 => Some(i64::from(bits as u16)),
        MAV_PARAM_TYPE_INT16 => Some(i64::from(bits as u16 as i16)),
        MAV_PARAM_TYPE_UINT32 | MAV_PARAM_TYPE_UINT64 => Some(i64::from(bits)),
        MAV_PARAM_TYPE_INT32 | MAV_PARAM_TYPE_INT64 => Some(i64::from(bits as i32)),
    };
    let looks_bytewise = value.is_subnormal() || value.is_nan();
    match bytewise {
        Some(i) if looks_bytewise && i.abs() <= EXACT => i as f32,
        _ => value,
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
    /// console's and the link's own (taken for the next start), and those that take effect
    /// in flight.
    pub fn flight_critical(&self) -> bool {
        let own = ["sim.", "log.", "console.", "gcs."]
            .iter()
            .any(|s| self.key.starts_with(s));
        !own && !self.in_flight()
    }

    /// A change takes effect in the running flight, at its next step (the commander's
    /// speeds and heights, the failsafes' timeouts); every other key at the next start.
    pub fn in_flight(&self) -> bool {
        crate::core::commander::in_flight_key(self.key).is_some()
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

    /// Every integer parameter's value is exact as the REAL32 it is announced as.
    #[test]
    fn integers_travel_exactly_as_real32() {
        let p = Params::of(&Config::default());
        for i in 0..p.len() {
            let q = *p.get(i).unwrap();
            assert_eq!(q.kind.wire(), MavParamType::MAV_PARAM_TYPE_REAL32);
            if q.kind == Kind::Int {
                assert!(q.value.abs() <= 16_777_216.0, "{} = {}", q.id, q.value);
                assert_eq!(f64::from(q.value as f32), q.value, "{}", q.id);
            }
        }
    }

    /// A set reads the same whichever encoding its sender used for an integer type.
    #[test]
    fn a_set_value_is_read_in_either_encoding() {
        use MavParamType::*;
        assert_eq!(set_value(0.4, MAV_PARAM_TYPE_REAL32), 0.4);
        // C cast: the number itself.
        assert_eq!(set_value(50.0, MAV_PARAM_TYPE_INT32), 50.0);
        assert_eq!(set_value(1.0, MAV_PARAM_TYPE_UINT8), 1.0);
        // Bytewise: the integer's bytes in the float.
        assert_eq!(set_value(f32::from_bits(50), MAV_PARAM_TYPE_INT32), 50.0);
        assert_eq!(
            set_value(f32::from_bits(-3i32 as u32), MAV_PARAM_TYPE_INT32),
            -3.0
        );
        assert_eq!(set_value(f32::from_bits(1), MAV_PARAM_TYPE_UINT8), 1.0);
        assert_eq!(set_value(0.0, MAV_PARAM_TYPE_UINT8), 0.0);
        // A fraction stays a fraction whatever the declared type (an integer key refuses
        // it); so does a NaN that is not an integer's bytes, and an infinity.
        assert_eq!(set_value(4.5, MAV_PARAM_TYPE_REAL32), 4.5);
        assert_eq!(set_value(0.4, MAV_PARAM_TYPE_INT32), 0.4);
        assert_eq!(set_value(0.5, MAV_PARAM_TYPE_UINT8), 0.5);
        assert!(set_value(f32::NAN, MAV_PARAM_TYPE_INT32).is_nan());
        assert!(set_value(f32::INFINITY, MAV_PARAM_TYPE_INT32).is_infinite());
    }

    #[test]
    fn ground_station_values_become_the_keys_own_kind() {
        let p = Params::of(&Config::default());
        let get = |id| *p.get(p.find(id).unwrap()).unwrap();
        let climb = get("CMD_CLIMB_M_S");
        assert_eq!(climb.value, 0.5);
        assert_eq!(climb.toml_value(0.4).unwrap(), toml::Value::Float(0.4));
        assert!(
            !climb.flight_critical() && climb.in_flight(),
            "set in flight"
        );
        assert!(get("CMD_CRASH_TILT").flight_critical());
        assert!(!get("CMD_CRASH_TILT").in_flight());
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
