//! The commander's part of a run's report: `modes`, `touchdown`, `takeoff`, `failsafes` and
//! `refusals` (the JSON fields both `fly --report` and `sim --report` carry), and its line in
//! the exit summary.

use crate::core::commander::Event;
pub use crate::core::commander::Summary as CommanderSummary;
use crate::core::flight::sequence::REFUSALS_MAX;
use serde::Serialize;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModeEntry {
    pub mode: &'static str,
    pub t_s: f64,
    pub why: String,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FailsafeEntry {
    pub kind: &'static str,
    pub t_s: f64,
    pub action: &'static str,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RefusalEntry {
    pub command: String,
    pub t_s: f64,
    pub why: String,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TouchdownEntry {
    pub t_s: f64,
    /// Vertical speed at touchdown, m/s.
    pub v_m_s: f64,
    /// Horizontal distance from the takeoff point, m.
    pub from_takeoff_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TakeoffEntry {
    /// The takeoff's height above its start, m.
    pub target_m: f64,
    /// How far the climb's first peak went past the height then held, m (0 when it did not).
    pub overshoot_m: f64,
}

/// The report's commander fields.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CommanderReport {
    pub modes: Vec<ModeEntry>,
    pub touchdown: Option<TouchdownEntry>,
    pub takeoff: Option<TakeoffEntry>,
    pub failsafes: Vec<FailsafeEntry>,
    /// The first refusals (mode.log has every one): `refusals_total` counts them all and
    /// `refusal_last` is the newest, so a flood of refused commands is summarised, not lost.
    pub refusals: Vec<RefusalEntry>,
    pub refusals_total: u64,
    pub refusal_last: Option<RefusalEntry>,
    /// Re-entries of the mode the vehicle was in (a `hold` while holding): `modes` lists the
    /// first ones, `mode_reentries_total` counts them all, `mode_reentry_last` is the newest.
    pub mode_reentries_total: u64,
    pub mode_reentry_last: Option<ModeEntry>,
}

fn secs(t_us: i64) -> f64 {
    t_us as f64 / 1e6
}

impl CommanderSummary {
    pub fn report(&self) -> CommanderReport {
        let mut r = CommanderReport {
            modes: Vec::new(),
            touchdown: self.figures.touchdown.map(|t| TouchdownEntry {
                t_s: secs(t.t_us),
                v_m_s: t.v_m_s,
                from_takeoff_m: t.from_takeoff_m,
            }),
            takeoff: self.figures.takeoff.map(|t| TakeoffEntry {
                target_m: t.target_m,
                overshoot_m: t.overshoot_m,
            }),
            failsafes: Vec::new(),
            refusals: Vec::new(),
            refusals_total: self.refusals_total,
            mode_reentries_total: self.reentries_total,
            mode_reentry_last: match &self.reentry_last {
                Some(Event::Mode { t_us, mode, why }) => Some(ModeEntry {
                    mode: mode.name(),
                    t_s: secs(*t_us),
                    why: why.clone(),
                }),
                _ => None,
            },
            refusal_last: match &self.refusal_last {
                Some(Event::Refusal { t_us, command, why }) => Some(RefusalEntry {
                    command: command.clone(),
                    t_s: secs(*t_us),
                    why: why.clone(),
                }),
                _ => None,
            },
        };
        for e in &self.events {
            match e {
                Event::Mode { t_us, mode, why } => r.modes.push(ModeEntry {
                    mode: mode.name(),
                    t_s: secs(*t_us),
                    why: why.clone(),
                }),
                Event::Failsafe { t_us, kind, action } => r.failsafes.push(FailsafeEntry {
                    kind: kind.name(),
                    t_s: secs(*t_us),
                    action: action.name(),
                }),
                Event::Refusal { t_us, command, why } => r.refusals.push(RefusalEntry {
                    command: command.clone(),
                    t_s: secs(*t_us),
                    why: why.clone(),
                }),
                Event::Reached { .. } => {}
            }
        }
        r
    }

    /// The exit summary's line: the modes in order, the failsafes and refusals.
    pub fn text(&self) -> String {
        let r = self.report();
        let modes: Vec<String> = r
            .modes
            .iter()
            .map(|m| format!("{} {:.1}s", m.mode, m.t_s))
            .collect();
        let mut s = format!("modes: {}", modes.join(" -> "));
        if let Some(t) = r.takeoff {
            s += &format!(
                "; takeoff to {:.2} m, overshoot {:.3} m",
                t.target_m, t.overshoot_m
            );
        }
        if let Some(t) = r.touchdown {
            s += &format!(
                "; touchdown at {:.1} s, {:.2} m/s, {:.1} m from the takeoff",
                t.t_s, t.v_m_s, t.from_takeoff_m
            );
        }
        for f in &r.failsafes {
            s += &format!("\n  failsafe {} at {:.1} s: {}", f.kind, f.t_s, f.action);
        }
        for f in &r.refusals {
            s += &format!("\n  refused {} at {:.1} s: {}", f.command, f.t_s, f.why);
        }
        let unlisted = r.refusals_total.saturating_sub(r.refusals.len() as u64);
        if let (true, Some(f)) = (unlisted > 0, &r.refusal_last) {
            s += &format!(
                "\n  {unlisted} more refusals (mode.log has them), the last {} at {:.1} s: {}",
                f.command, f.t_s, f.why
            );
        }
        let unlisted = r.mode_reentries_total.saturating_sub(REFUSALS_MAX);
        if let (true, Some(m)) = (unlisted > 0, &r.mode_reentry_last) {
            s += &format!(
                "\n  {unlisted} more re-entries of a mode (mode.log has them), the last {} at {:.1} s: {}",
                m.mode, m.t_s, m.why
            );
        }
        s
    }
}
