//! The parameter protocol: PARAM_REQUEST_LIST (the list paced, a few values each [`PACE`]),
//! PARAM_REQUEST_READ, PARAM_SET (checked here, kept by the owner as file work, answered
//! once kept or refused), PARAM_VALUE.

use super::{Connection, Effect, PACE, Window};
use crate::gcs::params::value_of;
use mavlink::dialects::common::*;
use std::time::Instant;

/// Parameter sets taken each second (each reads and writes files).
pub const SETS_PER_S: u64 = 5;

/// The parameter protocol's state: a list being sent, the second's sets.
pub(super) struct ParamState {
    /// The next index of a list being sent, and when it is due.
    cursor: Option<(usize, Instant)>,
    sets: Window,
}

impl ParamState {
    pub(super) fn new(now: Instant) -> Self {
        ParamState {
            cursor: None,
            sets: Window::new(now),
        }
    }

    /// PARAM_REQUEST_LIST: the list from its start, now.
    pub(super) fn start_list(&mut self, now: Instant) {
        self.cursor = Some((0, now));
    }

    /// When the list's next values are due.
    pub(super) fn next_pace(&self) -> Option<Instant> {
        self.cursor.map(|(_, at)| at)
    }
}

impl Connection {
    fn param_value(&mut self, index: usize) {
        let count = self.s.params.len() as u16;
        let Some(p) = self.s.params.get(index).copied() else {
            return;
        };
        let msg = MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: p.value as f32,
            param_count: count,
            param_index: index as u16,
            param_id: p.id.into(),
            param_type: p.kind.wire(),
        });
        self.send(&msg);
    }

    /// The next PARAM_VALUEs of a requested list, when due.
    pub(super) fn send_params(&mut self, now: Instant) {
        let Some((start, due)) = self.params.cursor else {
            return;
        };
        if now < due {
            return;
        }
        let end = (start + self.s.params_per_pace).min(self.s.params.len());
        for i in start..end {
            self.param_value(i);
        }
        self.params.cursor = (end < self.s.params.len()).then_some((end, now + PACE));
    }

    pub(super) fn on_param_read(&mut self, index: i16, id: &str) {
        let found = match usize::try_from(index) {
            Ok(i) => (i < self.s.params.len()).then_some(i),
            Err(_) => self.s.params.find(id),
        };
        match found {
            Some(i) => self.param_value(i),
            None => {
                let text = format!("parameter {id:?} (index {index}): no such parameter");
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text);
            }
        }
    }

    /// PARAM_SET: a new value that passes the link's rules goes to the owner to keep, and
    /// is answered when kept ([`Connection::handle_param_kept`]); otherwise the answer is the
    /// value as it is, with a text saying why when the set was refused.
    pub(super) fn on_param_set(&mut self, now: Instant, id: &str, value: f32) {
        let Some(index) = self.s.params.find(id) else {
            let text = format!("parameter {id:?}: no such parameter");
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, &text);
        };
        match self.param_change(now, index, value) {
            Ok(Some(effect)) => return self.effects.push_back(effect),
            Ok(None) => {}
            Err(why) => self.param_refused(index, &why),
        }
        self.param_value(index);
    }

    /// The file work keeping `value` for parameter `index`; none when it is the value
    /// already; why not when the link's rules refuse it.
    fn param_change(
        &mut self,
        now: Instant,
        index: usize,
        value: f32,
    ) -> Result<Option<Effect>, String> {
        let Some(p) = self.s.params.get(index).copied() else {
            return Ok(None);
        };
        let v = p.toml_value(value).map_err(|e| format!("{}: {e}", p.key))?;
        if value_of(&v).unwrap_or(p.value) == p.value {
            return Ok(None);
        }
        if p.flight_critical() && !self.disarmed() {
            let mode = self.status.mode.name();
            return Err(format!("{}: flight-critical, refused while {mode}", p.key));
        }
        if !self.params.sets.allows(now, 1, SETS_PER_S) {
            return Err(format!("more than {SETS_PER_S} parameter sets a second"));
        }
        let t_s = now.saturating_duration_since(self.s.boot).as_secs_f64();
        Ok(Some(Effect::KeepParam {
            index,
            param: p,
            value: v,
            t_s,
        }))
    }

    fn param_refused(&mut self, index: usize, why: &str) {
        let id = self.s.params.get(index).map_or("?", |p| p.id);
        let text = format!("parameter {id} not set: {why}");
        self.text(MavSeverity::MAV_SEVERITY_WARNING, &text);
    }

    /// The owner kept parameter `index` at `value` (from [`Effect::KeepParam`]), or could
    /// not, and why: the answer is the value after it.
    pub fn handle_param_kept(
        &mut self,
        now: Instant,
        index: usize,
        value: &toml::Value,
        kept: Result<(), String>,
    ) {
        self.tell_time(now);
        match kept {
            Ok(()) => {
                self.counts.param_sets += 1;
                if let Some(v) = value_of(value) {
                    self.s.params.set(index, v);
                    self.apply_in_flight(index, v);
                }
            }
            Err(why) => self.param_refused(index, &why),
        }
        self.param_value(index);
    }

    /// A kept value of a key that takes effect in flight goes to the flight too, as an
    /// operator input (recorded, applied at its next step).
    fn apply_in_flight(&mut self, index: usize, value: f64) {
        let key = self.s.params.get(index).map(|p| p.key);
        if let Some(key) = key.and_then(crate::core::commander::in_flight_key) {
            self.operator
                .push_back(crate::core::commander::OperatorInput::Param { key, value });
        }
    }
}
