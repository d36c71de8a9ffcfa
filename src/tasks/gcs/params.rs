//! The parameter protocol: PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET, PARAM_VALUE;
//! a set value is kept by `store`.

use super::link::Link;
use super::state::Gcs;
use crate::gcs::params::{Param, value_of};
use mavlink::dialects::common::*;
use std::time::Instant;

/// Parameter sets taken each second (each reads and writes files).
const SETS_PER_S: u64 = 5;

impl Gcs {
    fn param_value(&mut self, index: usize, link: &mut Link) {
        let count = self.ctx.params.len() as u16;
        let Some(p) = self.ctx.params.get(index).copied() else {
            return;
        };
        let msg = MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: p.value as f32,
            param_count: count,
            param_index: index as u16,
            param_id: p.id.into(),
            param_type: p.kind.wire(),
        });
        self.send(&msg, link);
    }

    /// The next PARAM_VALUEs of a requested list.
    pub(super) fn send_params(&mut self, link: &mut Link) {
        let Some(start) = self.param_cursor else {
            return;
        };
        let end = (start + self.params_per_tick).min(self.ctx.params.len());
        for i in start..end {
            self.param_value(i, link);
        }
        self.param_cursor = (end < self.ctx.params.len()).then_some(end);
    }

    pub(super) fn on_param_read(&mut self, index: i16, id: &str, link: &mut Link) {
        let found = match usize::try_from(index) {
            Ok(i) => (i < self.ctx.params.len()).then_some(i),
            Err(_) => self.ctx.params.find(id),
        };
        match found {
            Some(i) => self.param_value(i, link),
            None => {
                let text = format!("parameter {id:?} (index {index}): no such parameter");
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text, link);
            }
        }
    }

    /// PARAM_SET: the answer is the parameter's value after it — the old one, with a text
    /// saying why, when the set is refused.
    pub(super) fn on_param_set(&mut self, id: &str, value: f32, link: &mut Link) {
        let Some(i) = self.ctx.params.find(id) else {
            let text = format!("parameter {id:?}: no such parameter");
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, &text, link);
        };
        let Some(p) = self.ctx.params.get(i).copied() else {
            return;
        };
        match self.keep(&p, value) {
            Ok(Some(kept)) => {
                self.report.param_sets += 1;
                self.ctx.params.set(i, kept);
            }
            Ok(None) => {}
            Err(why) => {
                let text = format!("parameter {} not set: {why}", p.id);
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text, link);
            }
        }
        self.param_value(i, link);
    }

    /// The value kept for `p`; none when it is the value already.
    fn keep(&mut self, p: &Param, value: f32) -> Result<Option<f64>, String> {
        let v = p.toml_value(value).map_err(|e| format!("{}: {e}", p.key))?;
        let kept = value_of(&v).unwrap_or(p.value);
        if kept == p.value {
            return Ok(None);
        }
        if p.flight_critical() && !self.disarmed() {
            let mode = self.mode.name();
            return Err(format!("{}: flight-critical, refused while {mode}", p.key));
        }
        if !self.param_sets.allows(Instant::now(), 1, SETS_PER_S) {
            return Err(format!("more than {SETS_PER_S} parameter sets a second"));
        }
        let t_s = self.ctx.beats.us(Instant::now()) as f64 / 1e6;
        self.ctx.store.set(p, v, t_s)?;
        Ok(Some(kept))
    }
}
