//! The `mission` section (how missions and returns are flown) and mission files
//! (`config/missions/*.toml`): a list of `[[item]]` tables, each with a `kind` and its keys,
//! read into `core::mission::Mission` with every problem named by file, item and key.

use crate::core::commander::Params;
use crate::core::control::Integrators;
use crate::core::lqr::{Mat4, Mat16};
use crate::core::mission::{GainTable, Item, Limits, Mission, MissionPlan, MissionRun, Next};
use crate::core::path::PathPoint;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MissionConfig {
    /// Largest acceleration along a path, m/s².
    pub acc_m_s2: f64,
    /// Turns in place toward the next point: largest yaw rate, rad/s, and yaw acceleration,
    /// rad/s².
    pub yaw_rate_rad_s: f64,
    pub yaw_acc_rad_s2: f64,
    /// Speed of `return` (the item, the command and the failsafe action), m/s.
    pub return_m_s: f64,
    /// Speed of a ground station's waypoints and orbits until a DO_CHANGE_SPEED item sets
    /// one, m/s.
    pub speed_m_s: f64,
    /// Fly straight lines and circles with gains designed about their trim (`uquad lqr
    /// --path`); false: the profile's gains everywhere.
    pub path_gains: bool,
}

impl Default for MissionConfig {
    fn default() -> Self {
        MissionConfig {
            acc_m_s2: 0.5,
            yaw_rate_rad_s: 0.8,
            yaw_acc_rad_s2: 1.0,
            return_m_s: 1.0,
            speed_m_s: 1.0,
            path_gains: true,
        }
    }
}

impl MissionConfig {
    pub fn limits(&self) -> Limits {
        Limits {
            acc_m_s2: self.acc_m_s2,
            yaw_rate_rad_s: self.yaw_rate_rad_s,
            yaw_acc_rad_s2: self.yaw_acc_rad_s2,
            return_m_s: self.return_m_s,
        }
    }
}

/// A mission ready to fly (its items and the gains designed along its paths, before the
/// flight, so the control path only swaps them in), its file and the file's text (kept in
/// the run folder).
#[derive(Debug, Clone)]
pub struct LoadedMission {
    pub path: PathBuf,
    pub text: String,
    pub plan: Arc<MissionPlan>,
    /// The planned duration of its path items flown from the takeoff point, s.
    pub nominal_s: f64,
}

impl super::Profile {
    /// This profile with the mission in `path`, checked against it (see
    /// [`Profile::plan_mission`](super::Profile::plan_mission)).
    pub fn with_mission(mut self, path: &Path) -> Result<super::Profile, String> {
        let text = read_mission(path)?;
        let plan = self.plan_mission(path, &text)?;
        let nominal_s = nominal_s(&plan.mission, &self.config.commander_params());
        self.mission = Some(Arc::new(LoadedMission {
            path: path.to_path_buf(),
            text,
            plan: Arc::new(plan),
            nominal_s,
        }));
        Ok(self)
    }

    /// The mission `text` (read from `path`, which names it in errors and gives the plan its
    /// name) checked against this profile: missions need position control (integrators x, y,
    /// z, θ); with `mission.path_gains` the gains of every segment kind are designed now.
    /// Deterministic: a replay designs the same gains from the same text.
    pub fn plan_mission(&self, path: &Path, text: &str) -> Result<MissionPlan, String> {
        let c = &self.config;
        let integrators = c.control.integrator_set();
        if integrators != Some(Integrators::XYZTheta) || c.control.states != 12 {
            return Err(format!(
                "mission {}: missions need position control (control.integrators = \
                 \"x,y,z,theta\" and control.states = 12); this profile has {:?}, {} states",
                path.display(),
                c.control.integrators,
                c.control.states
            ));
        }
        let params = c.commander_params();
        let mission = parse_mission(path, text, &params)?;
        let gains = if c.mission.path_gains {
            let q = Mat16::from_row_slice(&self.lqr_q);
            let r = Mat4::from_row_slice(&self.lqr_r);
            GainTable::design(
                &mission,
                &params.mission,
                c.vehicle.mass_kg,
                Integrators::XYZTheta,
                &q,
                &r,
            )
            .map_err(|e| format!("mission {}: gains along its paths: {e}", path.display()))?
        } else {
            GainTable::default()
        };
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Ok(MissionPlan {
            name,
            mission,
            gains: Arc::new(gains),
        })
    }
}

/// The planned duration of the mission's path items, flown from above the takeoff point at
/// the hover height (the simulation's default length follows it).
fn nominal_s(mission: &Mission, p: &Params) -> f64 {
    let z = match mission.items.first() {
        Some(Item::Takeoff { height_m }) => *height_m,
        _ => p.hover_z_m,
    };
    let from = PathPoint {
        pos_m: [0.0, 0.0, z],
        ..PathPoint::default()
    };
    let mut run = MissionRun::new(mission.clone(), p.mission, [0.0; 3], 0, from);
    // At most a day, in steps of 0.1 s.
    for _ in 0..864_000 {
        if !matches!(run.advance(0.1), Next::Fly { .. }) {
            break;
        }
    }
    run.ideal_s
}

/// One `[[item]]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
enum RawItem {
    Takeoff {
        height_m: f64,
    },
    Goto {
        at_m: [f64; 3],
        speed_m_s: f64,
    },
    Orbit {
        centre_m: [f64; 2],
        radius_m: f64,
        speed_m_s: f64,
        turns: f64,
        #[serde(default = "left")]
        turn: String,
    },
    Hold {
        seconds: f64,
    },
    Return {},
    Land {},
}

fn left() -> String {
    "left".into()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMission {
    #[serde(default)]
    item: Vec<RawItem>,
}

/// Reads and checks the mission in `path` against the commander's bounds (heights, the
/// fence). Errors name the file, the item (1-based) and the key.
pub fn load_mission(path: &Path, p: &Params) -> Result<Mission, String> {
    parse_mission(path, &read_mission(path)?, p)
}

/// A mission file's text, bounded (see `config::bounded`).
pub fn read_mission(path: &Path) -> Result<String, String> {
    super::bounded::read_text(path, super::bounded::FileKind::Mission)
        .map_err(|e| format!("cannot read the mission {}: {e}", path.display()))
}

/// [`load_mission`] on the file's text (`path` names it in errors).
fn parse_mission(path: &Path, text: &str, p: &Params) -> Result<Mission, String> {
    let raw: RawMission =
        toml::from_str(text).map_err(|e| format!("mission {}: {}", path.display(), e.message()))?;
    let mut items = Vec::with_capacity(raw.item.len());
    for (i, r) in raw.item.iter().enumerate() {
        let item = check_item(r, p).map_err(|e| {
            format!(
                "mission {}: item {} ({}): {e}",
                path.display(),
                i + 1,
                kind(r)
            )
        })?;
        items.push(item);
    }
    check_order(&items).map_err(|e| format!("mission {}: {e}", path.display()))?;
    Ok(Mission { items })
}

fn kind(r: &RawItem) -> &'static str {
    match r {
        RawItem::Takeoff { .. } => "takeoff",
        RawItem::Goto { .. } => "goto",
        RawItem::Orbit { .. } => "orbit",
        RawItem::Hold { .. } => "hold",
        RawItem::Return {} => "return",
        RawItem::Land {} => "land",
    }
}

/// `value` within `lo..=hi` (finite), else the key, value and range.
fn within(key: &str, value: f64, lo: f64, hi: f64, unit: &str) -> Result<f64, String> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(format!("{key} = {value}: expected {lo}..{hi} {unit}"))
    }
}

/// A speed along a path: above 0, at most 10 m/s.
fn speed(value: f64) -> Result<f64, String> {
    within("speed_m_s", value, 0.05, 10.0, "m/s")
}

fn check_item(r: &RawItem, p: &Params) -> Result<Item, String> {
    // The limits every set point keeps (`Params::height_range_m`, `Params::inside_fence`).
    let heights = p.height_range_m();
    let (z_min, z_max) = (*heights.start(), *heights.end());
    let inside = |key: &str, x: f64, y: f64, reach: f64| {
        let r = x.hypot(y) + reach;
        if p.inside_fence(r) {
            Ok(())
        } else {
            Err(format!(
                "{key} reaches {r:.1} m from the takeoff point: outside fence.radius_m = {} m",
                p.fence_radius_m
            ))
        }
    };
    Ok(match r {
        RawItem::Takeoff { height_m } => Item::Takeoff {
            height_m: within("height_m", *height_m, z_min, z_max, "m")?,
        },
        RawItem::Goto { at_m, speed_m_s } => {
            inside("at_m", at_m[0], at_m[1], 0.0)?;
            within("at_m[2] (height)", at_m[2], z_min, z_max, "m")?;
            Item::Goto {
                at_m: *at_m,
                speed_m_s: speed(*speed_m_s)?,
            }
        }
        RawItem::Orbit {
            centre_m,
            radius_m,
            speed_m_s,
            turns,
            turn,
        } => {
            let radius_m = within("radius_m", *radius_m, 0.5, 100.0, "m")?;
            inside("the circle", centre_m[0], centre_m[1], radius_m)?;
            let left = match turn.as_str() {
                "left" => true,
                "right" => false,
                other => return Err(format!("turn = {other:?}: expected \"left\" or \"right\"")),
            };
            Item::Orbit {
                centre_m: *centre_m,
                radius_m,
                speed_m_s: speed(*speed_m_s)?,
                turns: within("turns", *turns, 0.01, 100.0, "")?,
                left,
            }
        }
        RawItem::Hold { seconds } => Item::Hold {
            seconds: within("seconds", *seconds, 0.0, 3600.0, "s")?,
        },
        RawItem::Return {} => Item::Return,
        RawItem::Land {} => Item::Land,
    })
}

/// A takeoff only first, a landing only last, something to fly.
fn check_order(items: &[Item]) -> Result<(), String> {
    if items.is_empty() {
        return Err("no [[item]]: nothing to fly".into());
    }
    for (i, item) in items.iter().enumerate() {
        match item {
            Item::Takeoff { .. } if i != 0 => {
                return Err(format!(
                    "item {}: a takeoff can only be the first item",
                    i + 1
                ));
            }
            Item::Land if i + 1 != items.len() => {
                return Err(format!(
                    "item {}: a landing can only be the last item",
                    i + 1
                ));
            }
            _ => {}
        }
    }
    Ok(())
}
