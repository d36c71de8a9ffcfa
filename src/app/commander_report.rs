//! The commander's part of a run's report: `modes`, `touchdown`, `takeoff`, `failsafes` and
//! `refusals` (the JSON fields both `fly --report` and `sim --report` carry), and its line in
//! the exit summary.

pub use crate::core::commander::Summary as CommanderSummary;
use crate::core::commander::{Event, Figures, Mode};
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

/// One flight of the run: from an arming to the disarm (or the kill) that ended it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlightEntry {
    pub armed_s: f64,
    /// The first takeoff of the flight; none when it never took off.
    pub takeoff_s: Option<f64>,
    /// When and why it ended (`disarmed` or `kill`); none while it went on at the run's end.
    pub end_s: Option<f64>,
    pub end_mode: Option<&'static str>,
    pub end_why: Option<String>,
    pub takeoff: Option<TakeoffEntry>,
    pub touchdown: Option<TouchdownEntry>,
}

fn takeoff_entry(f: &Figures) -> Option<TakeoffEntry> {
    f.takeoff.map(|t| TakeoffEntry {
        target_m: t.target_m,
        overshoot_m: t.overshoot_m,
    })
}

fn touchdown_entry(f: &Figures) -> Option<TouchdownEntry> {
    f.touchdown.map(|t| TouchdownEntry {
        t_s: secs(t.t_us),
        v_m_s: t.v_m_s,
        from_takeoff_m: t.from_takeoff_m,
    })
}

/// The run's flights from its mode changes (an arming begins one, a disarm or a kill ends
/// it), each with its figures (`flights`, one per arming in order).
fn flights(events: &[Event], figures: &[Figures]) -> Vec<FlightEntry> {
    let mut out: Vec<FlightEntry> = Vec::new();
    for e in events {
        let Event::Mode { t_us, mode, why } = e else {
            continue;
        };
        let open = out.last_mut().filter(|f| f.end_s.is_none());
        match (mode, open) {
            (Mode::Armed, _) => {
                let f = figures.get(out.len()).copied().unwrap_or_default();
                out.push(FlightEntry {
                    armed_s: secs(*t_us),
                    takeoff_s: None,
                    end_s: None,
                    end_mode: None,
                    end_why: None,
                    takeoff: takeoff_entry(&f),
                    touchdown: touchdown_entry(&f),
                });
            }
            (Mode::Takeoff, Some(f)) => {
                f.takeoff_s.get_or_insert(secs(*t_us));
            }
            (Mode::Disarmed | Mode::Kill, Some(f)) => {
                f.end_s = Some(secs(*t_us));
                f.end_mode = Some(mode.name());
                f.end_why = Some(why.clone());
            }
            _ => {}
        }
    }
    out
}

/// The report's commander fields.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CommanderReport {
    pub modes: Vec<ModeEntry>,
    /// Each flight of the run (one per arming); `takeoff` and `touchdown` are the first's.
    pub flights: Vec<FlightEntry>,
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
            flights: flights(&self.events, &self.flights),
            touchdown: touchdown_entry(&self.figures),
            takeoff: takeoff_entry(&self.figures),
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
        if r.flights.len() > 1 {
            for (n, f) in r.flights.iter().enumerate() {
                s += &flight_line(n + 1, f);
            }
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

/// The exit summary's line of one flight of several.
fn flight_line(n: usize, f: &FlightEntry) -> String {
    let mut s = format!("\n  flight {n}: armed {:.1} s", f.armed_s);
    if let Some(t) = f.takeoff_s {
        s += &format!(", takeoff {t:.1} s");
    }
    if let Some(t) = &f.touchdown {
        s += &format!(", touchdown {:.1} s at {:.2} m/s", t.t_s, t.v_m_s);
    }
    match (f.end_s, f.end_mode) {
        (Some(t), Some(m)) => s += &format!(", {m} {t:.1} s"),
        _ => s += ", still armed at the end",
    }
    s
}
