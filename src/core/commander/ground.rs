//! The armed vehicle's clock and the ground's rules: from the moment it arms, the commander is
//! ticked at every IMU frame (during the ESC ramp and the calibration too, before any Kalman
//! step) and judges the link and the GPS as their inputs arrive, whether or not one was ever
//! seen. On the ground a failsafe disarms, and so does an armed vehicle that does not take off
//! within `commander.disarm_ground_s` (PX4's COM_DISARM_PRFLT). In any armed mode, a tilt
//! beyond `commander.crash_tilt_rad` for `commander.crash_s`, or a takeoff still on the ground
//! after `commander.takeoff_timeout_s`, is a crash: the motors halt (PX4's FD_FAIL and
//! ArduPilot's crash check).

use super::profile::Profile;
use super::{Commander, EscRequest, Event, Failsafe, Mode, Observation};
use crate::core::model::GRAVITY_M_S2;

/// A takeoff has left the ground once the estimate is this far above its start, m (or half
/// the height asked, if lower).
const LIFTOFF_M: f64 = 0.3;

impl Commander {
    /// One IMU frame at `t_us`: the failsafes judged on time (link, GPS) from arming, and the
    /// ground's rules. A request to stop (disarmed on the ground) or to halt.
    pub fn tick(&mut self, t_us: i64, out: &mut Vec<Event>) -> Option<EscRequest> {
        match self.mode {
            m if m.airborne() => self.timed_failsafes(t_us, out),
            Mode::Armed => self.on_the_ground(t_us, out),
            _ => None,
        }
    }

    /// The receiver delivered a fix at `t_us` (gps.mode = "gpsd"), fused or not.
    pub fn gps_fix(&mut self, t_us: i64) {
        self.fix_rx_us = Some(t_us);
    }

    /// The ESCs run (their start-up ramp done) since an arm: the start-up is over once a
    /// Kalman step follows, and a takeoff may be asked for.
    pub fn escs_running(&mut self) {
        if self.mode == super::Mode::Armed {
            self.escs_running = true;
        }
    }

    /// Armed on the ground: a failsafe's condition (during the start-up too) or no takeoff
    /// within `disarm_ground_s` of the start-up's end disarms.
    fn on_the_ground(&mut self, t_us: i64, out: &mut Vec<Event>) -> Option<EscRequest> {
        let p = self.p;
        let (link_lost, gps_stale) = self.timed_conditions(t_us);
        let rc_lost = self.rc_lost_at(t_us);
        let rc_action = p.rc.map_or(super::Action::Land, |rc| rc.action);
        let conditions = [
            (Failsafe::LinkLoss, link_lost, p.link_action),
            (Failsafe::GpsLoss, gps_stale, p.gps_loss_action),
            (Failsafe::RcLoss, rc_lost, rc_action),
        ];
        if let Some((kind, _, action)) = conditions.into_iter().find(|c| c.1) {
            out.push(Event::Failsafe { t_us, kind, action });
            let why = format!("failsafe {} on the ground", kind.name());
            self.disarm(t_us, &why, out);
            return Some(EscRequest::Stop);
        }
        let idle_s = self.ground_since_us.map(|s| (t_us - s) as f64 / 1e6);
        if idle_s.is_some_and(|s| s >= p.disarm_ground_s) {
            let why = format!(
                "no takeoff within commander.disarm_ground_s = {} s",
                p.disarm_ground_s
            );
            self.disarm(t_us, &why, out);
            return Some(EscRequest::Stop);
        }
        None
    }

    /// A takeoff (or a mission from the ground) with a receiver needs a fix delivered (and,
    /// once one was fused, fused) within `control.gps_hold_timeout_s`: the GPS failsafe's own
    /// freshness.
    pub(super) fn fix_ready(&self, t_us: i64) -> Result<(), super::Refusal> {
        let p = &self.p;
        let fresh = self.fix_rx_us.is_some()
            && self
                .gps_reference_us()
                .is_some_and(|f| (t_us - f) as f64 / 1e6 <= p.gps_timeout_s);
        if !p.gps_live || fresh {
            return Ok(());
        }
        Err(super::Refusal::NoFix {
            timeout_s: p.gps_timeout_s,
        })
    }

    /// In the air by its mode (hold, mission, return) but on the ground by its estimate
    /// (under half of `control.manual.z_min_m` above the takeoff point: a hold at the lowest
    /// height is not the ground) for half of `disarm_ground_s`: something holds it down, or
    /// it came down; it lands, and the touchdown disarms.
    pub(super) fn grounded_in_flight(&mut self, o: &Observation, out: &mut Vec<Event>) {
        let ground_m = self.home_m.map_or(0.0, |h| h[2]);
        let low = matches!(
            self.mode,
            Mode::Hold | Mode::Mission | Mode::Return | Mode::Position | Mode::Altitude
        ) && self.p.start != super::Start::Flying
            && o.pos_m[2] - ground_m < 0.5 * self.p.z_min_m;
        if !low {
            self.low_since_us = None;
            return;
        }
        // Half the ground's time: the landing that follows must end within it.
        let since = *self.low_since_us.get_or_insert(o.t_us);
        if (o.t_us - since) as f64 / 1e6 >= 0.5 * self.p.disarm_ground_s {
            self.low_since_us = None;
            let why = format!(
                "on the ground in {} for half of commander.disarm_ground_s = {} s",
                self.mode.name(),
                self.p.disarm_ground_s
            );
            self.begin_land(Some(o), o.t_us, &why, out);
            // The landing begins where the vehicle is: on the ground.
            self.profile = Profile::at(o.pos_m[2], 0.0, 0.0);
        }
    }

    /// A crash or a flip, in any armed mode: tilted beyond `crash_tilt_rad` (the estimate's,
    /// or the accelerometer's while it feels about one g: a vehicle lying on its side, which
    /// an estimate on a failed gyro may not see) for `crash_s`, or a takeoff that has not
    /// left the ground (by the estimate and the barometer) `takeoff_timeout_s` after it began
    /// and has not reached its height.
    pub(super) fn crashed(&mut self, o: &Observation) -> Option<EscRequest> {
        // Profiles that start flying (the original's, the 2012 flights) keep their behaviour:
        // their replays stay byte-exact.
        let armed = self.mode == Mode::Armed || self.mode.airborne();
        if !armed || self.p.start == super::Start::Flying {
            return None;
        }
        let p = self.p;
        let secs = |since: i64| (o.t_us - since) as f64 / 1e6;
        let tilt_rad = o.tilt_rad.max(acc_tilt_rad(o.acc_m_s2));
        self.tilt_since_us = (tilt_rad > p.crash_tilt_rad || tilt_rad.is_nan())
            .then(|| self.tilt_since_us.unwrap_or(o.t_us));
        if self.tilt_since_us.is_some_and(|s| secs(s) >= p.crash_s) {
            return Some(EscRequest::Crash);
        }
        if self.mode != Mode::Takeoff {
            return None;
        }
        let ground_m = self.home_m.map_or(0.0, |h| h[2]);
        let liftoff_m = LIFTOFF_M.min(0.5 * (self.target_m[2] - ground_m));
        // The estimate and the barometer must both say so: an estimate on a failed sensor can
        // fly on while the vehicle tumbles at the ground (a failed barometer: the estimate
        // alone).
        let baro_up_m = self.baro_m - self.takeoff_baro_m;
        let baro_says = baro_up_m >= liftoff_m || baro_up_m.is_nan();
        // Judged at every step past the timeout, not latched: a vehicle that bounced up once
        // and fell back is still on the ground.
        self.lifted = o.pos_m[2] - ground_m >= liftoff_m && baro_says;
        let late = self
            .takeoff_us
            .is_some_and(|s| secs(s) > p.takeoff_timeout_s);
        (!self.lifted && late).then_some(EscRequest::Crash)
    }
}

/// The tilt the accelerometer reads, rad, while its specific force is within half a g of one
/// g (resting or hovering); 0 otherwise (a climb, a fall: it says nothing of the tilt then).
fn acc_tilt_rad(acc_m_s2: [f64; 3]) -> f64 {
    let [x, y, z] = acc_m_s2;
    let norm = (x * x + y * y + z * z).sqrt();
    if (norm - GRAVITY_M_S2).abs() > 0.5 * GRAVITY_M_S2 {
        return 0.0;
    }
    x.hypot(y).atan2(z)
}
