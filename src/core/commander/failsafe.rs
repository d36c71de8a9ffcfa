//! The graded failsafes: `link-loss`, `gps-loss`, `geofence` and `estimator`, each firing once
//! a run with its configured action (`land`, `hold`, `return`, or `kill` where nothing else is
//! safe).
//! The link rule follows the original's `check_net` (spec 8.2), landing instead of cutting.

use super::{Commander, EscRequest, Event, Mode, Observation};

/// Without fixes the fence is judged this many standard deviations of the position's grown
/// uncertainty further out: the dead-reckoned place is a guess, and the fence must hold for
/// where the vehicle may be.
const FENCE_SIGMAS: f64 = 2.0;

/// A barometer without an altitude for this long is lost, s: a sensor loss, acted on at once
/// (a single bad reading is left out of its step and ridden through).
pub const BARO_LOST_S: f64 = 0.5;

/// Without fixes, the gyros' roll and pitch bias learnt to move by more than this ends the
/// `gps-loss` ride-through at once, rad/s. A gyro changing while nothing holds the position
/// was flown meanwhile as a tilt (about the bias's size times the seconds taken to learn
/// it): on the IMU's angles alone (`ekf.r_field` 0) nothing then shows that tilt and the
/// vehicle flies off on it while the ride-through waits; with the magnetometer's field the
/// tilt is corrected, but a sensor is changing under a blind position, and the vehicle lands
/// rather than ride on. The filter's own wander without fixes stayed under 0.013 rad/s over a
/// ride-through in the simulator (seeds 1-6); a 0.05 rad/s step passed the limit within 3 s.
pub const UNAIDED_BIAS_MAX_RAD_S: f64 = 0.015;

/// What a failsafe does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    Land,
    Hold,
    Kill,
    /// Fly back above the takeoff point, then land.
    Return,
}

impl Action {
    pub fn name(self) -> &'static str {
        match self {
            Action::Land => "land",
            Action::Hold => "hold",
            Action::Kill => "kill",
            Action::Return => "return",
        }
    }
}

/// The graded failsafes; the watchdog's causes stay halts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failsafe {
    LinkLoss,
    GpsLoss,
    Geofence,
    Estimator,
    /// The pilot's radio lost (`failsafe.rc_timeout_s`, or the receiver's failsafe).
    RcLoss,
}

impl Failsafe {
    pub fn name(self) -> &'static str {
        match self {
            Failsafe::LinkLoss => "link-loss",
            Failsafe::GpsLoss => "gps-loss",
            Failsafe::Geofence => "geofence",
            Failsafe::Estimator => "estimator",
            Failsafe::RcLoss => "rc-loss",
        }
    }
}

impl Failsafe {
    const ALL: [Failsafe; 5] = [
        Failsafe::LinkLoss,
        Failsafe::GpsLoss,
        Failsafe::Geofence,
        Failsafe::Estimator,
        Failsafe::RcLoss,
    ];
}

impl Commander {
    /// The failsafe acting now whose condition persists and whose action is not a hold: an
    /// operator's hold or mission would fly on against it (a lost link is not one: a command
    /// is the link back).
    pub(super) fn acting_failsafe(&self) -> Option<Failsafe> {
        let p = &self.p;
        Failsafe::ALL.into_iter().find(|&k| {
            let action = match k {
                // A lost link or radio is not one: a command (a stick) is the link back.
                Failsafe::LinkLoss | Failsafe::RcLoss => return false,
                Failsafe::GpsLoss => p.gps_loss_action,
                Failsafe::Geofence => p.fence_action,
                Failsafe::Estimator => p.ekf_action,
            };
            self.acted[k as usize] && action != Action::Hold
        })
    }

    /// The failsafes judged on a Kalman step, in the air: the fence (on the dead-reckoned
    /// position grown by its uncertainty while no fix comes) and the estimator's gates. The
    /// link and GPS are judged at every frame from arming ([`Commander::tick`]).
    pub(super) fn failsafes(
        &mut self,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let p = self.p;
        // A position never observed (no receiver, no fix fused) has no fence to keep.
        let observed = p.gps_live || self.last_fix_us.is_some();
        let fence = observed && self.outside_fence(o);
        let ekf_bad = self.estimator_bad(o);
        let mut request = None;
        if !p.gps_live {
            // Fused fixes (fake or recorded GPS): judged on the step that fuses them, as the
            // original's profiles always were.
            request = self.gps_failsafe(o.t_us, Some(o), out);
        }
        // Without the gyro the attitude is the model's guess for seconds: no hold or return
        // flies on it.
        let ekf_action = match p.ekf_action {
            Action::Hold | Action::Return if o.gyro_lost => Action::Land,
            a => a,
        };
        let checks = [
            (Failsafe::Geofence, fence, fence, p.fence_action),
            (Failsafe::Estimator, ekf_bad, ekf_bad, ekf_action),
        ];
        for (kind, on, act_now, action) in checks {
            request = request.or(self.edge(kind, on, act_now, action, o.t_us, Some(o), out));
        }
        request
    }

    /// The link's and the GPS's failsafes at `t_us`, in the air: the link silent for
    /// `link_timeout_s` since its last beat or command; no fix for `gps_timeout_s` since the
    /// last one, or since arming if none came (gps.mode = "gpsd"; otherwise once one was
    /// fused). Without fixes attitude and altitude are held at once; the action waits its
    /// grace.
    pub(super) fn timed_failsafes(
        &mut self,
        t_us: i64,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let p = self.p;
        let (link_lost, _) = self.timed_conditions(t_us);
        let est = self.observed;
        let link = self.edge(
            Failsafe::LinkLoss,
            link_lost,
            link_lost,
            p.link_action,
            t_us,
            est.as_ref(),
            out,
        );
        let gps = if p.gps_live {
            self.gps_failsafe(t_us, est.as_ref(), out)
        } else {
            None
        };
        let rc = p.rc.and_then(|rc| {
            let lost = self.rc_lost_at(t_us);
            self.edge(
                Failsafe::RcLoss,
                lost,
                lost,
                rc.action,
                t_us,
                est.as_ref(),
                out,
            )
        });
        link.or(gps).or(rc)
    }

    /// The GPS's failsafe at `t_us`: attitude and altitude held at once while stale, the
    /// action after its grace.
    fn gps_failsafe(
        &mut self,
        t_us: i64,
        est: Option<&Observation>,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let p = self.p;
        let (_, gps_stale) = self.timed_conditions(t_us);
        self.hold_xy = !gps_stale;
        // The sticks fly on without a position: what `altitude` is for.
        if gps_stale && self.mode == Mode::Position {
            self.enter_sticks(super::StickMode::Altitude, t_us, "gps lost", out);
        }
        // Lost since the moment the last fix went stale: the same whichever frame notices it.
        self.gps_lost_us = gps_stale.then(|| self.gps_stale_since(t_us));
        // A pilot flying `altitude` needs no position: while one is on the sticks its action
        // waits (and is taken the moment no one is).
        let flown = self.mode == Mode::Altitude && self.pilot_on_sticks(t_us);
        // A tilt flown unseen (a bias learnt without fixes) is not ridden through.
        let tilt_unseen = est.is_some_and(|o| o.bias_unaided_rad_s > UNAIDED_BIAS_MAX_RAD_S);
        let gps_due = !flown
            && self
                .gps_lost_us
                .is_some_and(|s| tilt_unseen || (t_us - s) as f64 / 1e6 >= p.gps_loss_land_s);
        let action = p.gps_loss_action;
        self.edge(
            Failsafe::GpsLoss,
            gps_stale,
            gps_due,
            action,
            t_us,
            est,
            out,
        )
    }

    /// Whether the link is lost and the GPS stale at `t_us`.
    pub(super) fn timed_conditions(&self, t_us: i64) -> (bool, bool) {
        let p = &self.p;
        let secs = |since: i64| (t_us - since) as f64 / 1e6;
        let link_lost = self
            .link_seen_us
            .is_some_and(|s| secs(s) > p.link_timeout_s);
        let gps_stale = self
            .gps_reference_us()
            .is_some_and(|s| secs(s) > p.gps_timeout_s);
        (link_lost, gps_stale)
    }

    /// A fix this step. Its position fused: the receiver is healthy. Its velocity alone, the
    /// position left out by the gate (a multipath glitch): still healthy while the positions
    /// have been left out for less than `failsafe.gps_loss_land_s`, so a glitch is ridden
    /// through; a receiver whose positions stay inconsistent longer is unhealthy, as a lost
    /// one (the gps-loss path).
    pub(super) fn note_fix(&mut self, o: &Observation) {
        if o.gps_fused {
            self.position_gated_since_us = None;
            self.last_fix_us = Some(o.t_us);
            self.sigma_at_fix_m = o.pos_sigma_m;
        } else if o.gps_velocity_fused {
            let since = *self.position_gated_since_us.get_or_insert(o.t_us);
            if ((o.t_us - since) as f64 / 1e6) < self.p.gps_loss_land_s {
                self.last_fix_us = Some(o.t_us);
            }
        }
    }

    /// The time the GPS's freshness is judged from: the newest fix delivered, or the arming
    /// when none came since (gpsd), and once one was fused the newest fused if older (a
    /// receiver whose positions the filter's gate leaves out past `gps_loss_land_s` is
    /// unhealthy: lost, as a silent one; see [`Commander::note_fix`]); the newest fused fix
    /// otherwise.
    pub(super) fn gps_reference_us(&self) -> Option<i64> {
        if self.p.gps_live {
            // The pre-arm check asked for a recent fix; with none since, arming starts the clock.
            let delivered = self.fix_rx_us.or(self.armed_us);
            match (delivered, self.last_fix_us) {
                (Some(d), Some(fused)) => Some(d.min(fused)),
                (d, _) => d,
            }
        } else {
            self.last_fix_us
        }
    }

    fn gps_stale_since(&self, t_us: i64) -> i64 {
        let timeout_us = (self.p.gps_timeout_s * 1e6) as i64;
        self.gps_reference_us()
            .map_or(t_us, |r| r.saturating_add(timeout_us).min(t_us))
    }

    /// One failsafe's condition at this step: recorded when it begins, acted on once when
    /// `act_now`, forgotten when it ends.
    #[allow(clippy::too_many_arguments)]
    fn edge(
        &mut self,
        kind: Failsafe,
        on: bool,
        act_now: bool,
        action: Action,
        t_us: i64,
        est: Option<&Observation>,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let k = kind as usize;
        if !on {
            (self.recorded[k], self.acted[k]) = (false, false);
            return None;
        }
        if !self.recorded[k] {
            self.recorded[k] = true;
            out.push(Event::Failsafe { t_us, kind, action });
        }
        if act_now && !self.acted[k] {
            self.acted[k] = true;
            return self.act(action, kind, t_us, est, out);
        }
        None
    }

    /// The estimate's failsafe condition: a group outside its gate too long, or a sensor lost.
    fn estimator_bad(&mut self, o: &Observation) -> bool {
        // Both judged every step: each keeps its own clock.
        let timed_out = self.gates_timed_out(o);
        let lost = self.sensor_lost(o);
        timed_out || lost
    }

    /// A sensor the estimate has lost: the gyro stuck, or the barometer silent for
    /// [`BARO_LOST_S`]. Not waited on for `failsafe.ekf_bad_s`: nothing will bring it back.
    fn sensor_lost(&mut self, o: &Observation) -> bool {
        let since = if o.baro_alt_m.is_finite() {
            None
        } else {
            Some(self.baro_out_since_us.unwrap_or(o.t_us))
        };
        self.baro_out_since_us = since;
        let baro_lost = since.is_some_and(|s| (o.t_us - s) as f64 / 1e6 >= BARO_LOST_S);
        o.gyro_lost || baro_lost
    }

    /// The attitude, the altitude or the fixes' velocity outside its gate for
    /// `failsafe.ekf_bad_s`, each timed apart (the velocity across the steps between fixes).
    /// The positions of fixes with a velocity are not judged here: a position jump with a
    /// consistent velocity is the receiver's glitch, and positions left out too long make it
    /// unhealthy, the gps-loss path's ([`Commander::note_fix`]); a velocity outside its gate
    /// is the estimate's own error (a tilt it does not see).
    fn gates_timed_out(&mut self, o: &Observation) -> bool {
        let r = o.ratios;
        // A fix without a velocity (a receiver that gives none, the joint fusion): its
        // position's ratio, as it was judged before the fixes' rows were gated apart.
        let fixes = o.gps_velocity_ratio.or(r.gps);
        let groups = [Some(r.attitude), Some(r.altitude), fixes];
        for (since, ratio) in self.ekf_bad_since_us.iter_mut().zip(groups) {
            match ratio {
                Some(v) if v > 1.0 || v.is_nan() => *since = Some(since.unwrap_or(o.t_us)),
                Some(_) => *since = None,
                None => {}
            }
        }
        let limit_s = self.p.ekf_bad_s;
        self.ekf_bad_since_us
            .iter()
            .flatten()
            .any(|s| (o.t_us - s) as f64 / 1e6 >= limit_s)
    }

    /// Outside the fence: the estimate, dead-reckoned while no fix comes; once the fixes are
    /// lost (none for `gps_timeout_s`) grown by [`FENCE_SIGMAS`] times what its uncertainty
    /// has grown since the last one (between fixes it grows and shrinks at their pace, and
    /// the fence is judged on the estimate). The growth is the variance's, √(σ² − σ²_fix): a
    /// doubt the last fix left, such as the receiver's bias (`core::ekf_gps_bias`), adds to
    /// it, and must not shrink the margin the dead reckoning needs.
    fn outside_fence(&self, o: &Observation) -> bool {
        let Some(h) = self.home_m else {
            return false;
        };
        let lost = self
            .last_fix_us
            .is_some_and(|t| (o.t_us - t) as f64 / 1e6 > self.p.gps_timeout_s);
        let grown_m = if lost {
            let grown_m2 = o.pos_sigma_m.powi(2) - self.sigma_at_fix_m.powi(2);
            FENCE_SIGMAS * grown_m2.max(0.0).sqrt()
        } else {
            0.0
        };
        // Not a number (a covariance gone bad) is left to the estimator's own failsafe.
        let grown_m = if grown_m.is_finite() { grown_m } else { 0.0 };
        let r = (o.pos_m[0] - h[0]).hypot(o.pos_m[1] - h[1]) + grown_m;
        // Not a number (a position never observed): outside.
        !(r <= self.p.fence_radius_m && o.pos_m[2] - h[2] <= self.p.fence_alt_max_m)
    }

    /// A failsafe's action. Without a position a return cannot be flown: it lands in place.
    fn act(
        &mut self,
        action: Action,
        kind: Failsafe,
        t_us: i64,
        est: Option<&Observation>,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let why = format!("failsafe {}", kind.name());
        match action {
            Action::Kill => return Some(EscRequest::Kill),
            Action::Return if self.position_known() => self.begin_return(est, t_us, &why, out),
            Action::Land | Action::Return => self.begin_land(est, t_us, &why, out),
            // A landing goes on: a hold would leave a vehicle that was coming down (a pilot's
            // or another failsafe's landing) hovering on.
            Action::Hold if !matches!(self.mode, Mode::Hold | Mode::Land) => {
                self.set_mode(Mode::Hold, t_us, &why, out)
            }
            Action::Hold => {}
        }
        None
    }
}
