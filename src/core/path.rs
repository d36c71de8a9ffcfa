//! Paths the planner flies, as pure geometry and timing: a hold at a point, a turn of the
//! heading in place, a straight line and a circle, each sampled at a time into it as a set
//! point (position, velocity, acceleration, heading and its rate). Lines and circles follow a
//! smooth speed profile from rest to rest: the speed rises as a raised cosine, so the
//! acceleration is continuous (no step in the attitude the controller is asked for) and the
//! jerk bounded by 2·A²/V. Spec 5.1 names the original's STRAIGHT and CIRCULAR paths, which it
//! never built. Units: m, m/s, m/s², rad, rad/s, s; x north, y west, z up.

use crate::core::math::{cos, sin};
use std::f64::consts::PI;

/// One set point along a path.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PathPoint {
    pub pos_m: [f64; 3],
    pub vel_m_s: [f64; 3],
    pub acc_m_s2: [f64; 3],
    /// Heading (yaw), rad, unwrapped: it keeps counting past ±π as the estimate's yaw does.
    pub yaw_rad: f64,
    pub yaw_rate_rad_s: f64,
}

/// Distance along a path against time: from rest to rest, at most `speed` and `acc`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedProfile {
    pub distance: f64,
    /// The cruise speed (lower than asked when the path is too short to reach it).
    pub cruise: f64,
    /// Each of the two ramps' duration, s.
    pub ramp_s: f64,
}

impl SpeedProfile {
    /// The profile over `distance` at `speed`, accelerating at most `acc` (units of any
    /// length: metres, radians).
    pub fn new(distance: f64, speed: f64, acc: f64) -> Self {
        // A raised-cosine ramp to V takes π·V/(2·A) and covers half of V times that; two
        // ramps cover V·ramp. Too short a path lowers V until the ramps alone cover it.
        let distance = distance.max(0.0);
        let mut cruise = speed;
        if distance < cruise * cruise * PI / (2.0 * acc) {
            cruise = (2.0 * acc * distance / PI).sqrt();
        }
        let ramp_s = PI * cruise / (2.0 * acc);
        SpeedProfile {
            distance,
            cruise,
            ramp_s,
        }
    }

    pub fn duration_s(&self) -> f64 {
        if self.cruise <= 0.0 {
            return 0.0;
        }
        // Cruise covers what the ramps do not.
        2.0 * self.ramp_s + (self.distance - self.cruise * self.ramp_s) / self.cruise
    }

    /// Distance, speed and acceleration at `t_s` (clamped to the profile).
    pub fn at(&self, t_s: f64) -> (f64, f64, f64) {
        let total = self.duration_s();
        if total.is_nan() || total <= 0.0 {
            return (self.distance, 0.0, 0.0);
        }
        let t = t_s.clamp(0.0, total);
        let (v, ramp) = (self.cruise, self.ramp_s);
        let w = PI / ramp;
        let up = |t: f64| {
            (
                v / 2.0 * (t - sin(w * t) / w),
                v / 2.0 * (1.0 - cos(w * t)),
                v / 2.0 * w * sin(w * t),
            )
        };
        if t < ramp {
            up(t)
        } else if t > total - ramp {
            let (s, sv, sa) = up(total - t);
            (self.distance - s, sv, -sa)
        } else {
            (v * ramp / 2.0 + v * (t - ramp), v, 0.0)
        }
    }
}

/// A straight line from rest to rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    pub from_m: [f64; 3],
    pub to_m: [f64; 3],
    pub yaw_rad: f64,
    pub profile: SpeedProfile,
}

/// A circle about a vertical axis at a constant height, the heading along the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub centre_m: [f64; 2],
    pub z_m: f64,
    pub radius_m: f64,
    /// Where on the circle it starts (angle from north toward west), rad.
    pub start_rad: f64,
    /// Counter-clockwise seen from above.
    pub left: bool,
    /// The heading at the start, rad (unwrapped).
    pub yaw_rad: f64,
    /// Over the arc length.
    pub profile: SpeedProfile,
}

/// One piece of a path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Segment {
    /// Stay at a point with a heading.
    Hold {
        at_m: [f64; 3],
        yaw_rad: f64,
        duration_s: f64,
    },
    /// Turn the heading in place (over the yaw difference's profile).
    Turn {
        at_m: [f64; 3],
        from_rad: f64,
        to_rad: f64,
        profile: SpeedProfile,
    },
    Line(Line),
    Circle(Circle),
}

impl Segment {
    pub fn duration_s(&self) -> f64 {
        match self {
            Segment::Hold { duration_s, .. } => *duration_s,
            Segment::Turn { profile, .. } => profile.duration_s(),
            Segment::Line(l) => l.profile.duration_s(),
            Segment::Circle(c) => c.profile.duration_s(),
        }
    }

    /// The set point at `t_s` into the segment.
    pub fn at(&self, t_s: f64) -> PathPoint {
        match *self {
            Segment::Hold { at_m, yaw_rad, .. } => PathPoint {
                pos_m: at_m,
                yaw_rad,
                ..PathPoint::default()
            },
            Segment::Turn {
                at_m,
                from_rad,
                to_rad,
                profile,
            } => {
                let (s, v, _) = profile.at(t_s);
                let sign = if to_rad >= from_rad { 1.0 } else { -1.0 };
                PathPoint {
                    pos_m: at_m,
                    yaw_rad: from_rad + sign * s,
                    yaw_rate_rad_s: sign * v,
                    ..PathPoint::default()
                }
            }
            Segment::Line(l) => l.at(t_s),
            Segment::Circle(c) => c.at(t_s),
        }
    }

    /// Where the segment ends, and its heading there.
    pub fn end(&self) -> PathPoint {
        self.at(self.duration_s())
    }

    /// Horizontal distance from `p_m` to the segment's track, m (a turn and a hold: their
    /// point).
    pub fn distance_m(&self, p_m: [f64; 3]) -> f64 {
        match self {
            Segment::Hold { at_m, .. } | Segment::Turn { at_m, .. } => {
                (p_m[0] - at_m[0]).hypot(p_m[1] - at_m[1])
            }
            Segment::Line(l) => l.distance_m(p_m),
            Segment::Circle(c) => c.distance_m(p_m),
        }
    }
}

impl Line {
    /// A line from `from_m` to `to_m` at `speed_m_s`, accelerating at most `acc_m_s2`, flown
    /// with the heading `yaw_rad`.
    pub fn new(from_m: [f64; 3], to_m: [f64; 3], speed_m_s: f64, acc_m_s2: f64, yaw: f64) -> Self {
        let d: f64 = (0..3).map(|i| (to_m[i] - from_m[i]).powi(2)).sum::<f64>();
        Line {
            from_m,
            to_m,
            yaw_rad: yaw,
            profile: SpeedProfile::new(d.sqrt(), speed_m_s, acc_m_s2),
        }
    }

    fn unit(&self) -> [f64; 3] {
        let d = self.profile.distance;
        if d <= 0.0 {
            return [0.0; 3];
        }
        std::array::from_fn(|i| (self.to_m[i] - self.from_m[i]) / d)
    }

    fn at(&self, t_s: f64) -> PathPoint {
        let (s, v, a) = self.profile.at(t_s);
        let u = self.unit();
        PathPoint {
            pos_m: std::array::from_fn(|i| self.from_m[i] + u[i] * s),
            vel_m_s: u.map(|c| c * v),
            acc_m_s2: u.map(|c| c * a),
            yaw_rad: self.yaw_rad,
            yaw_rate_rad_s: 0.0,
        }
    }

    fn distance_m(&self, p: [f64; 3]) -> f64 {
        let (a, b) = (self.from_m, self.to_m);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len2 = dx * dx + dy * dy;
        let t = if len2 > 0.0 {
            (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
    }
}

impl Circle {
    fn sign(&self) -> f64 {
        if self.left { 1.0 } else { -1.0 }
    }

    fn at(&self, t_s: f64) -> PathPoint {
        let (s, v, a) = self.profile.at(t_s);
        let (r, k) = (self.radius_m, self.sign());
        let angle = self.start_rad + k * s / r;
        let (sa, ca) = (sin(angle), cos(angle));
        // Tangent (direction of travel) and the inward normal.
        let tangent = [-k * sa, k * ca];
        let inward = [-ca, -sa];
        let centripetal = v * v / r;
        PathPoint {
            pos_m: [
                self.centre_m[0] + r * ca,
                self.centre_m[1] + r * sa,
                self.z_m,
            ],
            vel_m_s: [v * tangent[0], v * tangent[1], 0.0],
            acc_m_s2: [
                a * tangent[0] + centripetal * inward[0],
                a * tangent[1] + centripetal * inward[1],
                0.0,
            ],
            yaw_rad: self.yaw_rad + k * s / r,
            yaw_rate_rad_s: k * v / r,
        }
    }

    fn distance_m(&self, p: [f64; 3]) -> f64 {
        ((p[0] - self.centre_m[0]).hypot(p[1] - self.centre_m[1]) - self.radius_m).abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_speed_profile_is_smooth_and_covers_the_distance() {
        for (d, v, a) in [(10.0, 1.0, 0.5), (0.3, 1.0, 0.5), (31.4, 1.0, 0.5)] {
            let p = SpeedProfile::new(d, v, a);
            let total = p.duration_s();
            let n = 20_000;
            let (mut s_prev, mut v_prev, mut a_prev) = p.at(0.0);
            assert_eq!((s_prev, v_prev, a_prev), (0.0, 0.0, 0.0));
            let dt = total / n as f64;
            let mut integral = 0.0;
            for i in 1..=n {
                let (s, vel, acc) = p.at(i as f64 * dt);
                integral += (vel + v_prev) / 2.0 * dt;
                assert!(
                    vel <= v + 1e-12 && acc.abs() <= a + 1e-12,
                    "{d}: {vel} {acc}"
                );
                // Continuous acceleration: no step between samples.
                assert!((acc - a_prev).abs() < 2.0 * 2.0 * a * a / p.cruise * dt + 1e-9);
                assert!(s >= s_prev - 1e-12);
                (s_prev, v_prev, a_prev) = (s, vel, acc);
            }
            assert!((s_prev - d).abs() < 1e-9 && v_prev.abs() < 1e-12);
            assert!((integral - d).abs() < 1e-6 * d.max(1.0), "{d}: {integral}");
        }
        // Ramps of π·V/(2·A) = π s at 1 m/s and 0.5 m/s²: 10 m take 10 + π s.
        let p = SpeedProfile::new(10.0, 1.0, 0.5);
        assert!((p.duration_s() - (10.0 + PI)).abs() < 1e-12);
    }

    #[test]
    fn a_circle_turns_its_heading_with_the_path() {
        let c = Circle {
            centre_m: [1.0, 2.0],
            z_m: 2.0,
            radius_m: 5.0,
            start_rad: -PI / 2.0,
            left: true,
            yaw_rad: 0.0,
            profile: SpeedProfile::new(2.0 * PI * 5.0 * 2.0, 1.0, 0.5),
        };
        let seg = Segment::Circle(c);
        let end = seg.end();
        // Two turns: back at the start, the heading 4π on.
        assert!((end.pos_m[0] - 1.0).abs() < 1e-9 && (end.pos_m[1] - (2.0 - 5.0)).abs() < 1e-9);
        assert!((end.yaw_rad - 4.0 * PI).abs() < 1e-9);
        // At cruise: the velocity along the heading, the acceleration v²/r inward.
        let mid = seg.at(seg.duration_s() / 2.0);
        let heading = [cos(mid.yaw_rad), sin(mid.yaw_rad)];
        let vn = mid.vel_m_s[0].hypot(mid.vel_m_s[1]);
        assert!((vn - 1.0).abs() < 1e-12);
        assert!((mid.vel_m_s[0] * heading[0] + mid.vel_m_s[1] * heading[1] - 1.0).abs() < 1e-9);
        assert!((mid.acc_m_s2[0].hypot(mid.acc_m_s2[1]) - 0.2).abs() < 1e-12);
        assert!(seg.distance_m(mid.pos_m) < 1e-9);
        assert!((seg.distance_m([1.0, 2.0, 0.0]) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn a_line_goes_from_rest_to_rest_and_measures_its_track() {
        let l = Segment::Line(Line::new([0.0, 0.0, 2.0], [10.0, 0.0, 2.0], 1.0, 0.5, 0.0));
        assert_eq!(l.at(0.0).pos_m, [0.0, 0.0, 2.0]);
        let end = l.end();
        assert!((end.pos_m[0] - 10.0).abs() < 1e-12 && end.vel_m_s[0] == 0.0);
        assert!((l.distance_m([5.0, 0.3, 9.0]) - 0.3).abs() < 1e-12);
        assert!((l.distance_m([-3.0, 4.0, 0.0]) - 5.0).abs() < 1e-12);
        assert!((l.distance_m([13.0, 4.0, 0.0]) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn a_turn_ramps_the_heading() {
        let t = Segment::Turn {
            at_m: [0.0; 3],
            from_rad: 1.0,
            to_rad: 1.0 - PI / 2.0,
            profile: SpeedProfile::new(PI / 2.0, 0.8, 1.0),
        };
        assert_eq!(t.at(0.0).yaw_rad, 1.0);
        assert!((t.end().yaw_rad - (1.0 - PI / 2.0)).abs() < 1e-12);
        assert!(t.at(t.duration_s() / 2.0).yaw_rate_rad_s < 0.0);
    }
}
