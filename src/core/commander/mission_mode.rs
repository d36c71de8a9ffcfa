//! The commander's `mission` and `return` modes: `start` (from the ground through the
//! mission's takeoff, or from a hold), `pause` (hold where the mission has got to), `resume`,
//! `return` (the command and the failsafe action), each step's set point from the mission's
//! run, and the mission's figures (when it started and ended, its planned duration). Not in
//! the original's spec, whose path planner (5.1) only hovered.

use super::profile::Profile;
use super::{Commander, Event, Mode, Observation, Refusal};
use crate::core::mission::{Item, MissionPlan, MissionRun, Next};
use crate::core::path::PathPoint;
use std::sync::Arc;

/// When the mission flew, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MissionFigures {
    /// The first step in `mission` mode, µs.
    pub started_us: Option<i64>,
    /// The last step in `mission` mode, µs (a pause and a resume keep flying it).
    pub ended_us: Option<i64>,
    /// The planned duration of every segment begun, s.
    pub ideal_s: f64,
}

impl Commander {
    /// A ground station's mission, replacing the loaded one (its gains with it); refused
    /// while a mission is flown (pause it first). A paused mission is dropped: the vehicle
    /// holds where it is until `start`.
    pub fn load_mission(&mut self, plan: Arc<MissionPlan>, t_us: i64, out: &mut Vec<Event>) {
        let flying = self.mode == Mode::Mission
            || (self.mode == Mode::Takeoff && self.mission_after_takeoff);
        if flying {
            return out.push(Event::Refusal {
                t_us,
                command: format!("mission {}", plan.name),
                why: Refusal::MissionBeingFlown(self.mode).to_string(),
            });
        }
        if self.paused {
            self.run = None;
            self.paused = false;
        }
        self.items_done = 0;
        self.landing_item = None;
        self.gains = plan.gains.clone();
        // The plan it replaces is kept for the run's life: its gain table may still be the
        // controller's, whose swap must not be the one that frees it.
        if let Some(old) = self.mission.replace(plan) {
            self.retired.push(old);
        }
    }

    /// The item flown (a mission's landing too), or paused at.
    pub(super) fn mission_item(&self) -> Option<usize> {
        if self.mode == Mode::Land {
            return self.landing_item;
        }
        let flown = self.mode == Mode::Mission || (self.mode == Mode::Hold && self.paused);
        self.run.as_ref().filter(|_| flown).map(MissionRun::item)
    }

    /// Why `start` cannot be done now, if it cannot.
    pub(super) fn check_start(&self, est: Option<&Observation>) -> Result<(), Refusal> {
        let Some(plan) = &self.mission else {
            return Err(Refusal::NoMission);
        };
        match self.mode {
            Mode::Armed => match plan.mission.items.first() {
                Some(Item::Takeoff { .. }) => self.estimator_ready(est),
                _ => Err(Refusal::MissionWithoutTakeoff),
            },
            Mode::Hold | Mode::Position => self.position_held(),
            m => Err(Refusal::StartNeedsArmedOrHold(m)),
        }
    }

    /// A path needs the horizontal position observed: a fix fused lately.
    fn position_held(&self) -> Result<(), Refusal> {
        if self.position_known() {
            Ok(())
        } else {
            Err(Refusal::NoRecentFix)
        }
    }

    /// Why a paused mission cannot go on, if it cannot.
    pub(super) fn check_resume(&self) -> Result<(), Refusal> {
        if self.mode == Mode::Hold && self.paused && self.run.is_some() {
            self.position_held()
        } else {
            Err(Refusal::NoPausedMission(self.mode))
        }
    }

    /// `start`: from the ground the mission's takeoff first (the commander's profile), then
    /// its next item; from a hold its first item that is not a takeoff.
    pub(super) fn start_mission(
        &mut self,
        o: &Observation,
        t_us: i64,
        why: &str,
        out: &mut Vec<Event>,
    ) {
        let Some(plan) = &self.mission else { return };
        match (self.mode, plan.mission.items.first()) {
            (Mode::Armed, Some(&Item::Takeoff { height_m })) => {
                self.begin_takeoff(o, height_m, t_us, why, out);
                self.mission_after_takeoff = true;
            }
            (_, first) => {
                let skip = usize::from(matches!(first, Some(Item::Takeoff { .. })));
                self.enter_mission(skip, t_us, why, out);
            }
        }
    }

    /// Flies the loaded mission from item `first`, from the present set point.
    pub(super) fn enter_mission(
        &mut self,
        first: usize,
        t_us: i64,
        why: &str,
        out: &mut Vec<Event>,
    ) {
        let (Some(plan), Some(home)) = (&self.mission, self.home_m) else {
            return;
        };
        let mission = plan.mission.clone();
        let run = MissionRun::new(mission, self.p.mission, home, first, self.here());
        self.run = Some(run);
        self.items_done = first;
        self.paused = false;
        self.mission_after_takeoff = false;
        self.set_mode(Mode::Mission, t_us, why, out);
    }

    /// `pause`: hold where the mission's set point is, the mission kept.
    pub(super) fn pause(&mut self, t_us: i64, why: &str, out: &mut Vec<Event>) {
        let p = self.here();
        self.target_m = p.pos_m;
        self.paused = true;
        self.set_mode(Mode::Hold, t_us, why, out);
    }

    /// `resume`: the paused item again, from the hold.
    pub(super) fn resume(&mut self, t_us: i64, why: &str, out: &mut Vec<Event>) {
        let here = self.here();
        if let Some(run) = &mut self.run {
            run.replan_from(here);
        }
        self.paused = false;
        self.set_mode(Mode::Mission, t_us, why, out);
    }

    /// Back above the takeoff point at the present height, then land; without a takeoff
    /// point, land here.
    pub(super) fn begin_return(
        &mut self,
        est: Option<&Observation>,
        t_us: i64,
        why: &str,
        out: &mut Vec<Event>,
    ) {
        // Without a takeoff point or a fresh fix there is nowhere to fly back to (the path
        // would be flown blind); a landing under way goes on.
        let (Some(home), true, false) =
            (self.home_m, self.position_known(), self.mode == Mode::Land)
        else {
            return self.begin_land(est, t_us, why, out);
        };
        if self.mode == Mode::Return {
            return;
        }
        self.run = Some(MissionRun::returning(self.p.mission, home, self.here()));
        self.paused = false;
        self.set_mode(Mode::Return, t_us, why, out);
    }

    /// The set point now, as a path point: the mission's last while one flies, else the
    /// hold's target and profile, with the heading a mission left (the calibration's before).
    pub(super) fn here(&self) -> PathPoint {
        if let (Some(run), Mode::Mission | Mode::Return) = (&self.run, self.mode) {
            return run.last();
        }
        if matches!(self.mode, Mode::Position | Mode::Altitude) {
            return self.stick;
        }
        PathPoint {
            pos_m: [self.target_m[0], self.target_m[1], self.profile.z_m],
            yaw_rad: self.yaw_rad.unwrap_or(self.yaw_cal_rad),
            ..PathPoint::default()
        }
    }

    /// One step of `mission` or `return`: the run's set point, and what follows its end.
    pub(super) fn fly_path(&mut self, o: &Observation, dt_s: f64, out: &mut Vec<Event>) {
        let Some(run) = self.run.as_mut() else {
            return self.set_mode(Mode::Hold, o.t_us, "no mission", out);
        };
        let next = run.advance(dt_s);
        if self.mode == Mode::Mission {
            let f = &mut self.mission_figures;
            f.started_us.get_or_insert(o.t_us);
            f.ended_us = Some(o.t_us);
            f.ideal_s = run.ideal_s;
            // Every item the step finished (one that needs no motion finishes with the next).
            let items = &run.mission().items;
            while self.items_done < run.item() {
                let i = self.items_done;
                let name = items.get(i).map_or("?", Item::name);
                out.push(Event::Reached {
                    t_us: o.t_us,
                    item: i,
                    name,
                });
                self.items_done += 1;
            }
        }
        match next {
            Next::Fly {
                point,
                segment,
                gains,
                ..
            } => {
                self.target_m = point.pos_m;
                self.profile = Profile::at(point.pos_m[2], point.vel_m_s[2], point.acc_m_s2[2]);
                self.yaw_rad = Some(point.yaw_rad);
                self.path = Some((point, segment, gains));
            }
            Next::Land { item } => {
                // A mission's landing item is reached at its touchdown.
                if self.mode == Mode::Mission {
                    self.landing_item = Some(item);
                }
                let why = format!("{}: land", self.mode.name());
                self.begin_land(None, o.t_us, &why, out);
            }
            Next::Done => self.set_mode(Mode::Hold, o.t_us, "mission done", out),
        }
    }
}
