//! The graded failsafes: `link-loss`, `gps-loss`, `geofence` and `estimator`, each firing once
//! a run with its configured action (`land`, `hold`, or `kill` where nothing else is safe).
//! The link rule follows the original's `check_net` (spec 8.2), landing instead of cutting.

use super::{Commander, EscRequest, Event, Mode, Observation};

/// What a failsafe does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    Land,
    Hold,
    Kill,
}

impl Action {
    pub fn name(self) -> &'static str {
        match self {
            Action::Land => "land",
            Action::Hold => "hold",
            Action::Kill => "kill",
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
    /// The graded failsafes, in the air.
    pub(super) fn failsafes(
        &mut self,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        let t = o.t_us;
        let secs = |since: i64| (t - since) as f64 / 1e6;
        let p = self.p;
        let link_lost = self
            .link_seen_us
            .is_some_and(|s| secs(s) > p.link_timeout_s);
        if link_lost {
            return self.fire(Failsafe::LinkLoss, p.link_action, o, out);
        }
        let gps_stale = self.last_fix_us.is_some_and(|s| secs(s) > p.gps_timeout_s);
        self.hold_xy = !gps_stale;
        if gps_stale {
            // Attitude and altitude are held at once; the action comes after a grace time.
            let since = *self.gps_lost_us.get_or_insert(t);
            self.record(Failsafe::GpsLoss, p.gps_loss_action, t, out);
            if secs(since) >= p.gps_loss_land_s && !self.acted.contains(&Failsafe::GpsLoss) {
                self.acted.push(Failsafe::GpsLoss);
                return self.act(p.gps_loss_action, Failsafe::GpsLoss, o, out);
            }
        } else {
            self.gps_lost_us = None;
        }
        if !gps_stale && self.last_fix_us.is_some() && self.outside_fence(o) {
            return self.fire(Failsafe::Geofence, p.fence_action, o, out);
        }
        let bad = o.test_ratio_max > 1.0;
        let since = if bad {
            *self.ekf_bad_since_us.get_or_insert(t)
        } else {
            t
        };
        if !bad {
            self.ekf_bad_since_us = None;
        }
        if bad && secs(since) >= p.ekf_bad_s {
            return self.fire(Failsafe::Estimator, p.ekf_action, o, out);
        }
        None
    }

    fn outside_fence(&self, o: &Observation) -> bool {
        let Some(h) = self.home_m else {
            return false;
        };
        let r = (o.pos_m[0] - h[0]).hypot(o.pos_m[1] - h[1]);
        r > self.p.fence_radius_m || o.pos_m[2] - h[2] > self.p.fence_alt_max_m
    }

    /// Records a failsafe the first time it fires in this run.
    fn record(&mut self, kind: Failsafe, action: Action, t_us: i64, out: &mut Vec<Event>) {
        if !self.fired.contains(&kind) {
            self.fired.push(kind);
            out.push(Event::Failsafe { t_us, kind, action });
        }
    }

    /// A failsafe fires and its action is taken, once per run: the operator may then choose
    /// another mode.
    fn fire(
        &mut self,
        kind: Failsafe,
        action: Action,
        o: &Observation,
        out: &mut Vec<Event>,
    ) -> Option<EscRequest> {
        if self.acted.contains(&kind) {
            return None;
        }
        self.acted.push(kind);
        self.record(kind, action, o.t_us, out);
        self.act(action, kind, o, out)
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
            _ => {}
        }
        None
    }
}
