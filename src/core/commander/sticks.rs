//! The pilot's stick modes (spec: none; PX4's Position and Altitude modes are the reference):
//! `position` flies the sticks as a horizontal velocity, a climb rate and a yaw rate, the set
//! point moving at them and stopping where they are let go; `altitude` flies them as a tilt,
//! a climb rate and a yaw rate, with no position needed. The sticks are the radio's while it
//! is heard, else a ground station's joystick (MANUAL_CONTROL) while it sends, else centred.

use super::profile::Profile;
use super::{Commander, Event, Mode, Observation};
use crate::core::mission::GainKey;
use crate::core::path::Segment;

/// A mode the sticks fly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StickMode {
    Position,
    Altitude,
}

impl StickMode {
    pub fn mode(self) -> Mode {
        match self {
            StickMode::Position => Mode::Position,
            StickMode::Altitude => Mode::Altitude,
        }
    }

    pub fn name(self) -> &'static str {
        self.mode().name()
    }

    pub fn from_name(s: &str) -> Option<StickMode> {
        [StickMode::Position, StickMode::Altitude]
            .into_iter()
            .find(|m| m.name() == s)
    }
}

/// How far a full stick moves the vehicle (`rc.max_speed_m_s`, `rc.max_climb_m_s`,
/// `rc.max_yaw_rate_rad_s`, `control.manual.max_tilt_rad`): the radio's and a ground
/// station's joystick alike.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StickLimits {
    pub max_speed_m_s: f64,
    pub max_climb_m_s: f64,
    pub max_yaw_rate_rad_s: f64,
    pub max_tilt_rad: f64,
}

/// The throttle's band about its centre that holds the height: a throttle stick has no
/// spring, and the pilot finds its centre by feel.
pub const THROTTLE_CENTRE_BAND: f64 = 0.1;

/// Armed on the ground with a stick mode selected, the throttle raised above this takes off
/// (PX4 asks for its upper part as well: a throttle nudged off its low stop is not a takeoff).
pub const TAKEOFF_THROTTLE: f64 = 0.5;

/// The position set point is kept this close to the estimate horizontally, m: a vehicle held
/// back (by wind, by its tilt limit) does not leave a set point running away ahead of it, so
/// it stops near where it is when the sticks are let go.
pub const LEASH_M: f64 = 2.0;

/// The set point stays this far inside the fence, m: the sticks do not fly the vehicle into
/// its failsafe.
pub const FENCE_MARGIN_M: f64 = 1.0;

/// In `altitude`, the roll and pitch sticks tilt the vehicle from this share of their travel
/// on; nearer the centre the velocity is damped instead (a joystick's jitter of a step or two
/// does not switch between the two at every message).
pub const TILT_STICK_MIN: f64 = 0.05;

/// A ground station's joystick counts this long after its last message, s; then the sticks
/// are centred (the vehicle holds).
pub const GCS_STICKS_S: f64 = 0.5;

/// The throttle as a climb rate's share: 0 inside the centre band, ±1 at the ends.
pub fn climb_share(throttle: f64) -> f64 {
    let t = throttle.clamp(-1.0, 1.0);
    let past = (t.abs() - THROTTLE_CENTRE_BAND).max(0.0) / (1.0 - THROTTLE_CENTRE_BAND);
    past.copysign(t)
}

impl Commander {
    /// The sticks now (roll, pitch, yaw, throttle; each −1…1): the radio's while it is
    /// heard, else a ground station's joystick while it sends, else centred (the vehicle
    /// holds). A lost radio's sticks are never flown.
    pub fn sticks_at(&self, t_us: i64) -> [f64; 4] {
        if self.rc_heard(t_us) {
            return self.rc.sticks;
        }
        self.gcs_sticks_now(t_us).unwrap_or([0.0; 4])
    }

    /// A radio is configured and heard at `t_us`.
    fn rc_heard(&self, t_us: i64) -> bool {
        self.p.rc.is_some() && !self.rc_lost_at(t_us)
    }

    /// A ground station's joystick, while it sends.
    fn gcs_sticks_now(&self, t_us: i64) -> Option<[f64; 4]> {
        self.gcs_sticks
            .filter(|&(_, at)| (t_us - at) as f64 / 1e6 <= GCS_STICKS_S)
            .map(|(s, _)| s)
    }

    /// A ground station's joystick (MANUAL_CONTROL) at `t_us`, each axis −1…1 (a reading
    /// that is not a number is not one).
    pub fn gcs_sticks(&mut self, sticks: [f64; 4], t_us: i64) {
        if sticks.iter().all(|v| v.is_finite()) {
            self.gcs_sticks = Some((sticks.map(|v| v.clamp(-1.0, 1.0)), t_us));
        }
    }

    /// The stick mode selected for a takeoff by throttle: the radio's mode switch while a
    /// radio is configured, else the ground station's last choice.
    pub(super) fn stick_selection(&self) -> Option<StickMode> {
        if self.p.rc.is_some() {
            self.rc.stick_mode
        } else {
            self.stick_choice
        }
    }

    /// Someone is on the sticks: the radio heard, or a ground station's joystick sending.
    pub(super) fn pilot_on_sticks(&self, t_us: i64) -> bool {
        self.rc_heard(t_us) || self.gcs_sticks_now(t_us).is_some()
    }

    /// Enters a stick mode from the present set point. `position` without a position (no
    /// fix fused, or none lately) is `altitude`: what the sticks can fly.
    pub(super) fn enter_sticks(
        &mut self,
        m: StickMode,
        t_us: i64,
        why: &str,
        out: &mut Vec<Event>,
    ) {
        let (mode, why) = match m {
            StickMode::Position if !self.position_known() => {
                (Mode::Altitude, format!("{why} (no position: altitude)"))
            }
            m => (m.mode(), why.to_string()),
        };
        let mut start = self.here();
        start.acc_m_s2 = [0.0; 3];
        start.yaw_rate_rad_s = 0.0;
        self.stick = start;
        // The throttle climbs only once it has been to its centre in this mode: a mode
        // chosen with the throttle away from it (a ground station's choice while the radio's
        // throttle rests low; the end of a takeoff by throttle) holds the height till then.
        self.throttle_centred = false;
        self.set_mode(mode, t_us, &why, out);
    }

    /// One step of a stick mode: the set point moved by the sticks, within the heights and
    /// the fence, on a leash to the estimate; the guidance's parts from it.
    pub(super) fn fly_sticks(&mut self, o: &Observation, dt_s: f64) {
        let l = self.p.sticks;
        let [roll, pitch, yaw, throttle] = self.sticks_at(o.t_us);
        self.throttle_centred |= climb_share(throttle) == 0.0;
        let climb_m_s = if self.throttle_centred {
            climb_share(throttle) * l.max_climb_m_s
        } else {
            0.0
        };
        let position = self.mode == Mode::Position;
        // Forward and left in the heading's frame, turned into the world's (x forward, y
        // left, z up): the pitch stick forward flies forward, the roll stick right flies right.
        let (fwd, left) = if position {
            (pitch * l.max_speed_m_s, -roll * l.max_speed_m_s)
        } else {
            (0.0, 0.0)
        };
        let (s, c) = self.stick.yaw_rad.sin_cos();
        let want_m_s = [c * fwd - s * left, s * fwd + c * left, climb_m_s];
        // The yaw stick right turns clockwise seen from above: the heading (counter-clockwise
        // about z up) decreases.
        self.move_stick_point(want_m_s, -yaw * l.max_yaw_rate_rad_s, dt_s);
        if !position {
            let p = &mut self.stick;
            p.pos_m[0] = o.pos_m[0];
            p.pos_m[1] = o.pos_m[1];
            p.vel_m_s[..2].fill(0.0);
            p.acc_m_s2[..2].fill(0.0);
        }
        self.bound_stick_point(o);
        // Centred, the sticks ask no tilt: the velocity is damped where the filter observes
        // it, as a hold without a position does (PX4's Altitude mode drifts instead).
        let tilting = !position && (roll.abs() >= TILT_STICK_MIN || pitch.abs() >= TILT_STICK_MIN);
        self.tilt_rad = tilting.then_some([roll * l.max_tilt_rad, pitch * l.max_tilt_rad]);
        self.guide_by_sticks(position);
    }

    /// The stick set point's velocity toward `want_m_s` (the horizontal at
    /// `mission.acc_m_s2`, the vertical at `commander.climb_acc_m_s2`), its position and
    /// heading moved over `dt_s`.
    fn move_stick_point(&mut self, want_m_s: [f64; 3], yaw_rate_rad_s: f64, dt_s: f64) {
        let p = &mut self.stick;
        let old = p.vel_m_s;
        let dv = [want_m_s[0] - old[0], want_m_s[1] - old[1]];
        let max_dv = self.p.mission.acc_m_s2 * dt_s;
        let scale = (max_dv / dv[0].hypot(dv[1])).min(1.0);
        let max_dvz = self.p.climb_acc_m_s2 * dt_s;
        let dvz = (want_m_s[2] - old[2]).clamp(-max_dvz, max_dvz);
        p.vel_m_s = [old[0] + dv[0] * scale, old[1] + dv[1] * scale, old[2] + dvz];
        for (i, v_old) in old.into_iter().enumerate() {
            p.pos_m[i] += p.vel_m_s[i] * dt_s;
            p.acc_m_s2[i] = if dt_s > 0.0 {
                (p.vel_m_s[i] - v_old) / dt_s
            } else {
                0.0
            };
        }
        p.yaw_rate_rad_s = yaw_rate_rad_s;
        p.yaw_rad += yaw_rate_rad_s * dt_s;
    }

    /// The commander's set point, profile, heading and path from the stick set point.
    fn guide_by_sticks(&mut self, position: bool) {
        let p = self.stick;
        self.target_m = p.pos_m;
        self.profile = Profile::at(p.pos_m[2], p.vel_m_s[2], p.acc_m_s2[2]);
        self.yaw_rad = Some(p.yaw_rad);
        self.path = position.then_some((
            p,
            Segment::Hold {
                at_m: p.pos_m,
                yaw_rad: p.yaw_rad,
                duration_s: 0.0,
            },
            GainKey::Profile,
        ));
    }

    /// The stick set point within the heights every set point keeps, within [`LEASH_M`] of
    /// the estimate, and inside the fence by [`FENCE_MARGIN_M`] (last: the hard limit); a
    /// bound reached stops the motion across it.
    fn bound_stick_point(&mut self, o: &Observation) {
        let home = self.home_m.unwrap_or(o.pos_m);
        let heights = self.p.height_range_m();
        let p = &mut self.stick;
        let height_m = p.pos_m[2] - home[2];
        if height_m < *heights.start() || height_m > *heights.end() {
            p.pos_m[2] = home[2] + height_m.clamp(*heights.start(), *heights.end());
            (p.vel_m_s[2], p.acc_m_s2[2]) = (0.0, 0.0);
        }
        let radius_m = (self.p.fence_radius_m - FENCE_MARGIN_M).max(0.0);
        for (centre, limit_m) in [(o.pos_m, LEASH_M), (home, radius_m)] {
            let d = [p.pos_m[0] - centre[0], p.pos_m[1] - centre[1]];
            let r = d[0].hypot(d[1]);
            if r > limit_m && r.is_finite() {
                let u = [d[0] / r, d[1] / r];
                p.pos_m[0] = centre[0] + u[0] * limit_m;
                p.pos_m[1] = centre[1] + u[1] * limit_m;
                // The velocity's part outward is dropped.
                let out_m_s = (p.vel_m_s[0] * u[0] + p.vel_m_s[1] * u[1]).max(0.0);
                p.vel_m_s[0] -= out_m_s * u[0];
                p.vel_m_s[1] -= out_m_s * u[1];
                p.acc_m_s2[..2].fill(0.0);
            }
        }
    }

    /// Armed on the ground, started up, a stick mode selected, and the throttle raised past
    /// [`TAKEOFF_THROTTLE`] after it was seen at its centre or below with the ESCs running (a
    /// throttle left up is not a pilot's raise): the takeoff to the profile's hover height,
    /// then the stick mode. A raise the takeoff's checks refuse is refused as a `takeoff`
    /// would be, and the throttle must come low again.
    pub(super) fn takeoff_by_throttle(&mut self, o: &Observation, out: &mut Vec<Event>) {
        let ready = self.mode == Mode::Armed && self.escs_running && self.ground_since_us.is_some();
        let (Some(m), true, true) = (self.stick_selection(), ready, self.pilot_on_sticks(o.t_us))
        else {
            // Only a low throttle seen while a stick mode is selected and someone is on the
            // sticks counts: a throttle raised under another mode is not a raise in this one.
            self.throttle_low_seen = false;
            return;
        };
        let throttle = self.sticks_at(o.t_us)[3];
        if climb_share(throttle) <= 0.0 {
            self.throttle_low_seen = true;
        }
        if !self.throttle_low_seen || throttle < TAKEOFF_THROTTLE {
            return;
        }
        self.throttle_low_seen = false;
        if let Err(why) = self.estimator_ready(Some(o)).and(self.fix_ready(o.t_us)) {
            return self.refuse(super::Command::Takeoff(None), o.t_us, why, out);
        }
        let why = format!("throttle raised in {}", m.name());
        let alt = self.p.hover_z_m;
        self.begin_takeoff(o, alt, o.t_us, &why, out);
        self.sticks_after_takeoff = true;
    }

    /// A takeoff by throttle reached its height: the stick mode selected now (the switch
    /// may have moved during the climb), or `hold` if none is.
    pub(super) fn after_throttle_takeoff(&mut self, t_us: i64, out: &mut Vec<Event>) {
        let why = "takeoff height reached";
        match self.stick_selection() {
            Some(m) => self.enter_sticks(m, t_us, why, out),
            None => self.set_mode(Mode::Hold, t_us, why, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_throttle_centre_band_holds_and_its_ends_are_full_rate() {
        assert_eq!(climb_share(0.0), 0.0);
        assert_eq!(climb_share(0.09), 0.0);
        assert_eq!(climb_share(-0.1), 0.0);
        assert_eq!(climb_share(1.0), 1.0);
        assert_eq!(climb_share(-1.0), -1.0);
        assert!((climb_share(0.55) - 0.5).abs() < 1e-12);
        assert_eq!(climb_share(7.0), 1.0);
    }

    #[test]
    fn stick_modes_by_name() {
        assert_eq!(StickMode::from_name("position"), Some(StickMode::Position));
        assert_eq!(StickMode::from_name("altitude"), Some(StickMode::Altitude));
        assert_eq!(StickMode::from_name("hold"), None);
    }
}
