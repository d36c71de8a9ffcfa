//! Configuration profiles: `config/*.toml`, parsed with serde, overridden with `--set`,
//! validated at load, with the data files they name (calibration, gains) loaded and checked.
//!
//! Every problem found is reported, one line each, naming the file and the key (or the
//! position of a malformed number in a data file). Relative paths resolve against the folder
//! of the configuration file.
//!
//! - `schema`: the sections, their defaults and accessors;
//! - `overrides`: `--set KEY=VALUE`;
//! - `load`: reading, deserialising, resolving paths, loading the data files;
//! - `validate`: the rules a configuration must meet;
//! - `profile`: the loaded profile and the core objects it describes;
//! - `bounded`: every file read whole, with bounds.

pub mod bounded;
mod commander;
mod gcs;
mod load;
mod mission;
mod overrides;
mod param_store;
mod parameters;
mod profile;
mod rc;
mod schema;
mod validate;

pub use commander::{CommanderConfig, FailsafeConfig, Fence};
pub use gcs::{GcsConfig, GcsEnabled, SigningKey, signing_key};
pub use load::{
    ConfigError, DEFAULT_CONFIG, Problem, check_kept, check_set, kept_params_path, load, load_kept,
    resolve_path, write_kept,
};
pub use mission::{LoadedMission, MissionConfig, load_mission, read_mission};
pub use overrides::parse_set;
pub use param_store::{Kept, ParamStore};
pub use parameters::PARAMETERS;
pub use profile::Profile;
pub use rc::{RcChannel, RcConfig, RcMode, RcProtocol};
pub use schema::{
    Config, Console, Control, Ekf, Esc, Gps, GpsMode, Imu, Integrals, Log, Motor, Sim, Vehicle,
    WatchdogConfig,
};
pub use validate::{allowed_by_key, parse_duration_s, parse_fault_time_s, parse_seed};
