//! The graded failsafes: `link-loss`, `gps-loss`, `geofence` and `estimator`, each firing once
//! a run with its configured action (`land`, `hold`, `return`, or `kill` where nothing else is
//! safe).
//! The link rule follows the original's `check_net` (spec 8.2), landing instead of cutting.

use super::{Commander, EscRequest, Event, Mode, Observation};

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
}

impl Failsafe {
    pub fn name(self) -> &'static str {
        match self {
            Failsafe::LinkLoss => "link-loss",
            Failsafe::GpsLoss => "gps-loss",
            Failsafe::Geofence => "geofence",
            Failsafe::Estimator => "estimator",
        }
    }
}

impl Commander {
    /// The graded failsafes, in the air: each condition is checked on every step; a
    /// failsafe is recorded when its condition begins and acts once while it lasts.
    pub(super) fn failsafes(
        &mut self,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let (t, p) = (o.t_us, self.p);
        let secs = |since: i64| (t - since) as f64 / 1e6;
        let link_lost = self
            .link_seen_us
            .is_some_and(|s| secs(s) > p.link_timeout_s);
        let gps_stale = self.last_fix_us.is_some_and(|s| secs(s) > p.gps_timeout_s);
        // Without fixes attitude and altitude are held at once; the action waits its grace.
        self.hold_xy = !gps_stale;
        self.gps_lost_us = if gps_stale {
            Some(self.gps_lost_us.unwrap_or(t))
        } else {
            None
        };
        let gps_due = self
            .gps_lost_us
            .is_some_and(|s| secs(s) >= p.gps_loss_land_s);
        let fence = !gps_stale && self.last_fix_us.is_some() && self.outside_fence(o);
        let ekf_bad = self.estimator_bad(o);
        let checks = [
            (Failsafe::LinkLoss, link_lost, link_lost, p.link_action),
            (Failsafe::GpsLoss, gps_stale, gps_due, p.gps_loss_action),
            (Failsafe::Geofence, fence, fence, p.fence_action),
            (Failsafe::Estimator, ekf_bad, ekf_bad, p.ekf_action),
        ];
        let mut request = None;
        for (kind, on, act_now, action) in checks {
            request = request.or(self.edge(kind, on, act_now, action, o, out));
        }
        request
    }

    /// One failsafe's condition at this step: recorded when it begins, acted on once when
    /// `act_now`, forgotten when it ends.
    fn edge(
        &mut self,
        kind: Failsafe,
        on: bool,
        act_now: bool,
        action: Action,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let k = kind as usize;
        if !on {
            (self.recorded[k], self.acted[k]) = (false, false);
            return None;
        }
        if !self.recorded[k] {
            self.recorded[k] = true;
            out.push(Event::Failsafe {
                t_us: o.t_us,
                kind,
                action,
            });
        }
        if act_now && !self.acted[k] {
            self.acted[k] = true;
            return self.act(action, kind, o, out);
        }
        None
    }

    /// A measurement group outside its gate for `failsafe.ekf_bad_s`: each group's time is
    /// kept across the steps that do not measure it (GPS between fixes).
    fn estimator_bad(&mut self, o: &Observation) -> bool {
        let r = o.ratios;
        let groups = [Some(r.attitude), Some(r.altitude), r.gps];
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

    fn outside_fence(&self, o: &Observation) -> bool {
        let Some(h) = self.home_m else {
            return false;
        };
        let r = (o.pos_m[0] - h[0]).hypot(o.pos_m[1] - h[1]);
        r > self.p.fence_radius_m || o.pos_m[2] - h[2] > self.p.fence_alt_max_m
    }

    fn act(
        &mut self,
        action: Action,
        kind: Failsafe,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let (t_us, why) = (o.t_us, format!("failsafe {}", kind.name()));
        match action {
            Action::Kill => return Some(EscRequest::Kill),
            Action::Land => self.begin_land(Some(o), t_us, &why, out),
            Action::Hold if self.mode != Mode::Hold => self.set_mode(Mode::Hold, t_us, &why, out),
            Action::Return => self.begin_return(Some(o), t_us, &why, out),
            _ => {}
        }
        None
    }
}
