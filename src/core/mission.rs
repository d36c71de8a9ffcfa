//! Missions: a list of items (`takeoff`, `goto`, `orbit`, `hold`, `return`, `land`) and the
//! run that turns each item into path segments as it is reached, from where the vehicle is.
//! Lines are flown nose first (the heading turns in place toward the next point first), and a
//! circle with the heading along it, so every segment is one of the trims the gains are
//! designed for: hover, straight flight at a speed, a turn of a radius at a speed.
//!
//! Positions are metres from the takeoff point (x north, y west) and heights above it. The
//! commander flies `takeoff` and `land` with its own profiles; the rest is here. Not in the
//! original's spec (its planner, 5.1, only hovered; its gains along paths, 4.5, stayed in
//! Matlab).

use crate::core::control::{Gains, Integrators};
use crate::core::lqr::{self, Mat4, Mat16};
use crate::core::math::{atan2, cos, sin};
use crate::core::path::{Circle, Line, PathPoint, Segment, SpeedProfile};
use crate::core::trim::{self, PathShape};
use std::collections::VecDeque;
use std::f64::consts::PI;

/// One mission item.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Item {
    /// Climb to this height above the takeoff point (first item only).
    Takeoff { height_m: f64 },
    /// Fly a straight line to this point (x, y from the takeoff point, z above it).
    Goto { at_m: [f64; 3], speed_m_s: f64 },
    /// Fly to the circle, then around it `turns` times at the present height.
    Orbit {
        centre_m: [f64; 2],
        radius_m: f64,
        speed_m_s: f64,
        turns: f64,
        left: bool,
    },
    /// Hover where the last item ended.
    Hold { seconds: f64 },
    /// Fly back above the takeoff point at the present height.
    Return,
    /// Land where the vehicle is (last item only).
    Land,
}

impl Item {
    pub fn name(&self) -> &'static str {
        match self {
            Item::Takeoff { .. } => "takeoff",
            Item::Goto { .. } => "goto",
            Item::Orbit { .. } => "orbit",
            Item::Hold { .. } => "hold",
            Item::Return => "return",
            Item::Land => "land",
        }
    }
}

/// A mission as loaded: checked to start with at most one takeoff and end with at most one
/// land.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mission {
    pub items: Vec<Item>,
}

/// A mission ready to fly: its items and the gains designed along its paths (before it is
/// handed to the flight, so the control path only swaps them in). `name` is the file in the
/// run folder it was read from, as mode.log records a ground station's upload.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MissionPlan {
    pub name: String,
    pub mission: Mission,
    pub gains: std::sync::Arc<GainTable>,
}

/// How missions are flown (`mission.*`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Largest acceleration along a path, m/s².
    pub acc_m_s2: f64,
    /// Turns in place: largest yaw rate, rad/s, and yaw acceleration, rad/s².
    pub yaw_rate_rad_s: f64,
    pub yaw_acc_rad_s2: f64,
    /// Speed of a `return`, m/s.
    pub return_m_s: f64,
}

/// Which gains a segment is flown with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GainKey {
    /// The profile's gains (hover, turns in place, holds).
    Profile,
    Straight {
        speed_m_s: f64,
    },
    Circle {
        radius_m: f64,
        speed_m_s: f64,
        left: bool,
    },
}

impl GainKey {
    /// The trim the gains are designed about (nose first, course 0).
    pub fn shape(self) -> Option<PathShape> {
        match self {
            GainKey::Profile => None,
            GainKey::Straight { speed_m_s } => Some(PathShape::Straight {
                speed_m_s,
                course_rad: 0.0,
            }),
            GainKey::Circle {
                radius_m,
                speed_m_s,
                left,
            } => Some(PathShape::Circle {
                radius_m,
                speed_m_s,
                course_rad: 0.0,
                left,
            }),
        }
    }
}

/// The gains designed for a mission's segments, by key.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GainTable {
    entries: Vec<(GainKey, Gains)>,
}

impl GainTable {
    pub fn get(&self, key: GainKey) -> Option<&Gains> {
        self.entries.iter().find(|(k, _)| *k == key).map(|(_, g)| g)
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// A fingerprint of every gain (FNV-1a over their bits, in order): mode.log records it
    /// with an uploaded mission, so a replay that plans different gains (another profile)
    /// says so instead of flying something else.
    pub fn fingerprint(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let values = self.entries.iter().flat_map(|(_, g)| {
            g.k_prop
                .iter()
                .flatten()
                .chain(g.k_int.iter().flatten())
                .copied()
        });
        for v in values {
            for b in v.to_bits().to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        }
        h
    }

    /// Designs the gains of every segment kind `mission` can fly (and its `return`s, which
    /// a failsafe may ask for at any time), about each one's trim, with the profile's weights.
    pub fn design(
        mission: &Mission,
        limits: &Limits,
        mass_kg: f64,
        integrators: Integrators,
        q: &Mat16,
        r: &Mat4,
    ) -> Result<GainTable, String> {
        let mut keys = vec![GainKey::Straight {
            speed_m_s: limits.return_m_s,
        }];
        for item in &mission.items {
            keys.extend(item_keys(item));
        }
        let mut table = GainTable::default();
        for key in keys {
            if table.get(key).is_some() {
                continue;
            }
            let Some(shape) = key.shape() else { continue };
            let t = trim::trim(shape, mass_kg).map_err(|e| format!("{key:?}: {e}"))?;
            let d = lqr::design_path(mass_kg, &t, integrators, q, r)
                .map_err(|e| format!("{key:?}: {e}"))?;
            let (kp, ki) = (d.k_prop(), d.k_int());
            let gains = Gains {
                k_prop: std::array::from_fn(|m| std::array::from_fn(|j| kp[(m, j)])),
                k_int: std::array::from_fn(|m| std::array::from_fn(|j| ki[(m, j)])),
            };
            table.entries.push((key, gains));
        }
        Ok(table)
    }
}

/// The gain keys an item's segments use.
fn item_keys(item: &Item) -> Vec<GainKey> {
    match *item {
        Item::Goto { speed_m_s, .. } => vec![GainKey::Straight { speed_m_s }],
        Item::Orbit {
            radius_m,
            speed_m_s,
            left,
            ..
        } => vec![
            GainKey::Straight { speed_m_s },
            GainKey::Circle {
                radius_m,
                speed_m_s,
                left,
            },
        ],
        _ => vec![],
    }
}

/// What the run asks of the commander at a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Next {
    /// Fly this set point with these gains.
    Fly {
        point: PathPoint,
        segment: Segment,
        gains: GainKey,
    },
    /// The next item is a landing (its index).
    Land { item: usize },
    /// Every item is done.
    Done,
}

/// A mission being flown.
#[derive(Debug, Clone)]
pub struct MissionRun {
    mission: Mission,
    limits: Limits,
    home_m: [f64; 3],
    item: usize,
    plan: VecDeque<(Segment, GainKey)>,
    /// Time into the plan's first segment, s.
    t_s: f64,
    /// The last set point flown: the next item's plan starts there.
    last: PathPoint,
    /// Where the plan so far ends (while planning).
    plan_end: PathPoint,
    /// The planned duration of the segments planned so far (an item's when it is reached), s.
    pub ideal_s: f64,
}

impl MissionRun {
    /// A run from item `first`, starting at `from` (position and heading).
    pub fn new(
        mission: Mission,
        limits: Limits,
        home_m: [f64; 3],
        first: usize,
        from: PathPoint,
    ) -> Self {
        let mut run = MissionRun {
            mission,
            limits,
            home_m,
            item: first,
            plan: VecDeque::new(),
            t_s: 0.0,
            last: from,
            plan_end: from,
            ideal_s: 0.0,
        };
        run.plan_item();
        run
    }

    /// A `return` then a landing, from `from`: the return mode's plan.
    pub fn returning(limits: Limits, home_m: [f64; 3], from: PathPoint) -> Self {
        let mission = Mission {
            items: vec![Item::Return, Item::Land],
        };
        MissionRun::new(mission, limits, home_m, 0, from)
    }

    /// The item being flown (0-based); those before it are done.
    pub fn item(&self) -> usize {
        self.item
    }

    pub fn mission(&self) -> &Mission {
        &self.mission
    }

    /// The last set point flown (a pause holds there).
    pub fn last(&self) -> PathPoint {
        self.last
    }

    /// Plans the current item again from `from` (a resume after a pause). What was planned and
    /// not flown leaves the planned duration.
    pub fn replan_from(&mut self, from: PathPoint) {
        let unflown: f64 = self.plan.iter().map(|(s, _)| s.duration_s()).sum();
        self.ideal_s -= (unflown - self.t_s).max(0.0);
        self.last = from;
        self.plan.clear();
        self.t_s = 0.0;
        self.plan_item();
    }

    /// Advances by `dt_s` and says what to fly.
    pub fn advance(&mut self, dt_s: f64) -> Next {
        self.t_s += dt_s;
        loop {
            let Some(&(seg, gains)) = self.plan.front() else {
                // Nothing planned: a landing, the end, or an item that needs no motion.
                match self.mission.items.get(self.item) {
                    Some(Item::Land) => return Next::Land { item: self.item },
                    None => return Next::Done,
                    Some(_) => {
                        self.item += 1;
                        self.plan_item();
                        continue;
                    }
                }
            };
            if self.t_s < seg.duration_s() {
                self.last = seg.at(self.t_s);
                return Next::Fly {
                    point: self.last,
                    segment: seg,
                    gains,
                };
            }
            // The segment is done; what is left of the step goes on into the next one.
            self.t_s -= seg.duration_s();
            self.last = seg.end();
            self.plan.pop_front();
            if self.plan.is_empty() {
                self.item += 1;
                self.plan_item();
            }
        }
    }

    /// Plans the current item's segments from the last set point (nothing for a takeoff, a
    /// landing or past the end).
    fn plan_item(&mut self) {
        let Some(&item) = self.mission.items.get(self.item) else {
            return;
        };
        let l = self.limits;
        let (home, from) = (self.home_m, self.last);
        self.plan_end = from;
        match item {
            Item::Land | Item::Takeoff { .. } => {}
            Item::Hold { seconds } => self.push(
                Segment::Hold {
                    at_m: from.pos_m,
                    yaw_rad: from.yaw_rad,
                    duration_s: seconds,
                },
                GainKey::Profile,
            ),
            Item::Goto { at_m, speed_m_s } => {
                let to = [home[0] + at_m[0], home[1] + at_m[1], home[2] + at_m[2]];
                self.line_to(to, speed_m_s);
            }
            Item::Return => self.line_to([home[0], home[1], from.pos_m[2]], l.return_m_s),
            Item::Orbit {
                centre_m,
                radius_m,
                speed_m_s,
                turns,
                left,
            } => self.orbit(
                [home[0] + centre_m[0], home[1] + centre_m[1]],
                radius_m,
                speed_m_s,
                turns,
                left,
            ),
        }
    }

    fn push(&mut self, seg: Segment, gains: GainKey) {
        self.ideal_s += seg.duration_s();
        self.plan_end = seg.end();
        self.plan.push_back((seg, gains));
    }

    /// Heading to `yaw` (the nearest way), in place, if it is not there already.
    fn turn_to(&mut self, yaw: f64) {
        let from = self.plan_end;
        let to = nearest_angle(yaw, from.yaw_rad);
        if (to - from.yaw_rad).abs() < 1e-3 {
            return;
        }
        let profile = SpeedProfile::new(
            (to - from.yaw_rad).abs(),
            self.limits.yaw_rate_rad_s,
            self.limits.yaw_acc_rad_s2,
        );
        self.push(
            Segment::Turn {
                at_m: from.pos_m,
                from_rad: from.yaw_rad,
                to_rad: to,
                profile,
            },
            GainKey::Profile,
        );
    }

    /// Nose toward `to` (when it is more than 10 cm away horizontally), then a line to it.
    fn line_to(&mut self, to: [f64; 3], speed_m_s: f64) {
        let from = self.plan_end.pos_m;
        let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
        if dx.hypot(dy) > 0.1 {
            self.turn_to(atan2(dy, dx));
        }
        let d2: f64 = (0..3).map(|i| (to[i] - from[i]).powi(2)).sum();
        if d2.sqrt() < 1e-3 {
            return;
        }
        let line = Line::new(
            from,
            to,
            speed_m_s,
            self.limits.acc_m_s2,
            self.plan_end.yaw_rad,
        );
        self.push(Segment::Line(line), GainKey::Straight { speed_m_s });
    }

    /// To the circle's nearest point, the nose along it, then around it.
    fn orbit(&mut self, centre: [f64; 2], radius_m: f64, speed_m_s: f64, turns: f64, left: bool) {
        let p = self.plan_end.pos_m;
        let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
        // From the centre itself, any point will do: north.
        let start = if dx.hypot(dy) < 1e-6 {
            0.0
        } else {
            atan2(dy, dx)
        };
        let entry = [
            centre[0] + radius_m * cos(start),
            centre[1] + radius_m * sin(start),
            p[2],
        ];
        self.line_to(entry, speed_m_s);
        let sign = if left { 1.0 } else { -1.0 };
        self.turn_to(start + sign * PI / 2.0);
        let circle = Circle {
            centre_m: centre,
            z_m: p[2],
            radius_m,
            start_rad: start,
            left,
            yaw_rad: self.plan_end.yaw_rad,
            profile: SpeedProfile::new(
                2.0 * PI * radius_m * turns,
                speed_m_s,
                self.limits.acc_m_s2,
            ),
        };
        self.push(
            Segment::Circle(circle),
            GainKey::Circle {
                radius_m,
                speed_m_s,
                left,
            },
        );
    }
}

/// `angle` plus a whole number of turns, as near as possible to `near`.
pub fn nearest_angle(angle: f64, near: f64) -> f64 {
    let turns = ((near - angle) / (2.0 * PI)).round();
    angle + turns * 2.0 * PI
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits {
        acc_m_s2: 0.5,
        yaw_rate_rad_s: 0.8,
        yaw_acc_rad_s2: 1.0,
        return_m_s: 1.0,
    };

    fn square() -> Mission {
        let goto = |x: f64, y: f64| Item::Goto {
            at_m: [x, y, 2.0],
            speed_m_s: 1.0,
        };
        Mission {
            items: vec![
                Item::Takeoff { height_m: 2.0 },
                goto(10.0, 0.0),
                goto(10.0, 10.0),
                goto(0.0, 10.0),
                goto(0.0, 0.0),
                Item::Land,
            ],
        }
    }

    /// Flies `run` at 100 Hz until it asks for a landing or ends; the items reached, the
    /// largest step of the set point, the time flown.
    fn fly(run: &mut MissionRun) -> (Vec<usize>, f64, f64, Next) {
        let (mut reached, mut jump, mut t) = (Vec::new(), 0.0f64, 0.0);
        let mut prev = run.last();
        for _ in 0..100_000 {
            let next = run.advance(0.01);
            t += 0.01;
            reached.extend(reached.len()..run.item());
            match next {
                Next::Fly { point, .. } => {
                    let d: f64 = (0..3)
                        .map(|i| (point.pos_m[i] - prev.pos_m[i]).powi(2))
                        .sum();
                    jump = jump.max(d.sqrt()).max((point.yaw_rad - prev.yaw_rad).abs());
                    prev = point;
                }
                _ => return (reached, jump, t, next),
            }
        }
        panic!("the mission did not end");
    }

    #[test]
    fn a_square_flies_nose_first_and_smoothly_to_its_landing() {
        let home = [0.0, 0.0, 0.0];
        let from = PathPoint {
            pos_m: [0.0, 0.0, 2.0],
            yaw_rad: 0.3,
            ..PathPoint::default()
        };
        let mut run = MissionRun::new(square(), LIMITS, home, 0, from);
        let (reached, jump, t, end) = fly(&mut run);
        assert_eq!(reached, vec![0, 1, 2, 3, 4], "{end:?}");
        assert!(matches!(end, Next::Land { item: 5, .. }), "{end:?}");
        // 1 m/s at 100 Hz: no set point moves more than 1 cm (or 0.8 rad/s of heading) a step.
        assert!(jump <= 0.0101, "{jump}");
        // Four sides of 10 + π s, a first turn of 0.3 rad and three of π/2.
        assert!(
            run.ideal_s > 4.0 * (10.0 + PI) && (t - run.ideal_s).abs() < 0.02,
            "{t}"
        );
        let p = run.last();
        assert!(p.pos_m[0].abs() < 1e-9 && p.pos_m[1].abs() < 1e-9);
        // Facing the way the last side flew (east: −y), having turned left at each corner
        // (north, west, south, east: unwrapped, 3π/2).
        assert!((p.yaw_rad - 1.5 * PI).abs() < 1e-9, "{}", p.yaw_rad);
    }

    #[test]
    fn an_orbit_flies_to_the_circle_then_around_it() {
        let mission = Mission {
            items: vec![Item::Orbit {
                centre_m: [0.0, 0.0],
                radius_m: 5.0,
                speed_m_s: 1.0,
                turns: 2.0,
                left: true,
            }],
        };
        let from = PathPoint {
            pos_m: [0.0, 0.0, 2.0],
            ..PathPoint::default()
        };
        let mut run = MissionRun::new(mission, LIMITS, [0.0; 3], 0, from);
        let mut on_circle = 0;
        let mut keys = Vec::new();
        loop {
            match run.advance(0.01) {
                Next::Fly { segment, gains, .. } => {
                    if !keys.contains(&gains) {
                        keys.push(gains);
                    }
                    if let Segment::Circle(c) = segment {
                        on_circle += 1;
                        assert!(segment.distance_m(run.last().pos_m) < 1e-9);
                        assert_eq!(c.radius_m, 5.0);
                    }
                }
                Next::Done => {
                    assert_eq!(run.item(), 1);
                    break;
                }
                other => panic!("{other:?}"),
            }
        }
        // Out to the circle (straight at 1 m/s), a quarter turn in place, two turns round.
        assert_eq!(
            keys,
            vec![
                GainKey::Straight { speed_m_s: 1.0 },
                GainKey::Profile,
                GainKey::Circle {
                    radius_m: 5.0,
                    speed_m_s: 1.0,
                    left: true
                }
            ]
        );
        let circle_s = SpeedProfile::new(20.0 * PI, 1.0, 0.5).duration_s();
        assert!((on_circle as f64 * 0.01 - circle_s).abs() < 0.02);
        assert!((run.last().yaw_rad - (PI / 2.0 + 4.0 * PI)).abs() < 1e-9);
    }

    #[test]
    fn gains_are_designed_for_every_segment_kind() {
        let mut q = Mat16::identity();
        q[(2, 2)] = 1e4;
        let r = Mat4::identity() * 0.1;
        let mut m = square();
        m.items.push(Item::Orbit {
            centre_m: [0.0, 0.0],
            radius_m: 5.0,
            speed_m_s: 2.0,
            turns: 1.0,
            left: false,
        });
        let t = GainTable::design(&m, &LIMITS, 1.55, Integrators::XYZTheta, &q, &r).unwrap();
        // Straight at 1 m/s (the sides and the return), at 2 m/s (to the circle), the circle.
        assert_eq!(t.len(), 3);
        assert!(t.get(GainKey::Straight { speed_m_s: 2.0 }).is_some());
        assert!(t.get(GainKey::Profile).is_none());
    }
}
