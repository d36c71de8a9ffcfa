//! The safety campaign's seven invariants, judged on one run: its summary (with what the true
//! vehicle did), its mode.log, the profile's settings and the faults it struck. Each broken
//! invariant is a [`Finding`] naming its number and what was seen; the run's outcome is a short
//! word for the table.

use crate::app::campaign::cases::Run;
use crate::app::commander_report::CommanderReport;
use crate::app::report::SimSummary;
use crate::config::Config;
use crate::core::commander::{Action, Failsafe, Mode, Params};
use crate::core::flight::sequence::REFUSALS_MAX;
use crate::core::watchdog::TripReason;
use crate::sim::faults::Fault;

/// A broken invariant.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    pub invariant: u8,
    pub seen: String,
}

/// One frame's worth of slack on a configured time, s.
const SLACK_S: f64 = 0.05;

/// Every broken invariant of a run.
pub fn judge(run: &Run, s: &SimSummary, mode_log: &str, cfg: &Config) -> Vec<Finding> {
    let p = cfg.commander_params();
    // The report's lists, built once for every rule.
    let r = s.fly.commander.report();
    let mut out = Vec::new();
    let mut broken = |invariant: u8, seen: String| out.push(Finding { invariant, seen });
    escs_stopped(s, &mut broken);
    disarmed(s, &r, &p, &mut broken);
    touchdowns(run, s, &p, &mut broken);
    halts_in_air(run, s, &mut broken);
    fence(s, &p, &mut broken);
    failsafes_in_time(run, s, &r, &p, cfg, &mut broken);
    report_is_mode_log(s, &r, mode_log, &mut broken);
    out
}

/// 1: every ESC's last writes are zero then disable, or the ESC is named as unconfirmed.
fn escs_stopped(s: &SimSummary, broken: &mut impl FnMut(u8, String)) {
    let unconfirmed: Vec<String> = s
        .fly
        .halt
        .iter()
        .flat_map(|h| h.unconfirmed.iter().flatten())
        .map(|a| format!("0x{a:02x}"))
        .collect();
    for e in &s.esc_end {
        // An ESC never started was only ever disabled.
        let never_started = e.last_writes.iter().all(|w| w == "disable");
        let stopped = !e.enabled && (e.last_writes == ["speed 0", "disable"] || never_started);
        if !stopped && !unconfirmed.contains(&e.address) {
            broken(
                1,
                format!(
                    "ESC {} ended {} after {:?}, not named unconfirmed",
                    e.address,
                    if e.enabled { "enabled" } else { "disabled" },
                    e.last_writes
                ),
            );
        }
    }
}

/// 2: the run ends disarmed (or halted), and the motors never idle on the ground past
/// `disarm_ground_s` + 1 s once the start-up is over.
fn disarmed(s: &SimSummary, r: &CommanderReport, p: &Params, broken: &mut impl FnMut(u8, String)) {
    let last = r.modes.last().map_or("disarmed", |m| m.mode);
    if !matches!(last, "disarmed" | "kill") {
        broken(2, format!("the run ended in mode {last}"));
    }
    let Some(safety) = &s.safety else { return };
    if safety.ground_run_max_s > p.disarm_ground_s + 1.0 {
        broken(
            2,
            format!(
                "motors ran on the ground for {:.2} s outside a takeoff (disarm_ground_s {} s)",
                safety.ground_run_max_s, p.disarm_ground_s
            ),
        );
    }
}

/// Faults after which the estimate keeps a position (the slow touchdown applies).
fn keeps_position(run: &Run) -> bool {
    run.inject.iter().all(|(f, _)| {
        !matches!(
            f,
            Fault::GpsLoss | Fault::BaroFail | Fault::GyroStuck | Fault::ImuGarbage
        )
    })
}

/// 3: every contact with the ground before a halt at ≤ 1 m/s, and at ≤ `land_slow_m_s` +
/// 0.25 m/s where the faults left a position estimate.
fn touchdowns(run: &Run, s: &SimSummary, p: &Params, broken: &mut impl FnMut(u8, String)) {
    let Some(safety) = &s.safety else { return };
    let halt_s = s
        .fly
        .halt
        .map_or(f64::INFINITY, |h| h.trip.event_us as f64 / 1e6);
    let limit = if keeps_position(run) {
        p.land_slow_m_s + 0.25
    } else {
        1.0
    };
    for c in safety
        .contacts
        .iter()
        .filter(|c| c.t_s < halt_s && c.mode != "fall")
    {
        if c.v_m_s > limit + 1e-9 {
            broken(
                3,
                format!(
                    "touched the ground at {:.2} s at {:.2} m/s in {} (limit {limit:.2} m/s)",
                    c.t_s, c.v_m_s, c.mode
                ),
            );
        }
    }
}

/// Faults that leave the estimator without an attitude it can trust.
fn blinds_attitude(run: &Run) -> bool {
    run.inject
        .iter()
        .any(|(f, _)| matches!(f, Fault::GyroStuck | Fault::ImuGarbage))
}

/// 4: a halt in the air only for a cause on the one list; `estimator` only when the attitude
/// is gone.
fn halts_in_air(run: &Run, s: &SimSummary, broken: &mut impl FnMut(u8, String)) {
    let (Some(h), Some(safety)) = (&s.fly.halt, &s.safety) else {
        return;
    };
    if !safety.halt_in_air {
        return;
    }
    let reason = h.trip.reason;
    let fall = safety
        .contacts
        .iter()
        .rfind(|c| c.mode == "fall")
        .map_or(String::new(), |c| format!(", fell at {:.1} m/s", c.v_m_s));
    if !reason.may_halt_in_air() || (reason == TripReason::Estimator && !blinds_attitude(run)) {
        broken(
            4,
            format!(
                "halt {} in the air with an attitude left{fall}",
                reason.name()
            ),
        );
    }
}

/// 5: the true vehicle within the fence's radius + 10 m.
fn fence(s: &SimSummary, p: &Params, broken: &mut impl FnMut(u8, String)) {
    let Some(safety) = &s.safety else { return };
    if safety.max_from_start_m > p.fence_radius_m + 10.0 {
        broken(
            5,
            format!(
                "{:.1} m from the start (fence radius {} m)",
                safety.max_from_start_m, p.fence_radius_m
            ),
        );
    }
}

/// When the vehicle armed and when it stopped being armed (disarmed or halted), s.
fn armed_spans(r: &CommanderReport, simulated_s: f64) -> Vec<(f64, f64)> {
    let mut spans = Vec::new();
    let mut from = None;
    for m in &r.modes {
        match (m.mode, from) {
            ("disarmed" | "kill", Some(a)) => {
                spans.push((a, m.t_s));
                from = None;
            }
            ("disarmed" | "kill", None) => {}
            (_, None) => from = Some(m.t_s),
            (_, Some(_)) => {}
        }
    }
    if let Some(a) = from {
        spans.push((a, simulated_s));
    }
    spans
}

/// 6: a lost link, lost fixes or a silent IMU acted on within the configured time while armed.
fn failsafes_in_time(
    run: &Run,
    s: &SimSummary,
    r: &CommanderReport,
    p: &Params,
    cfg: &Config,
    broken: &mut impl FnMut(u8, String),
) {
    let spans = armed_spans(r, s.simulated_s);
    for &(fault, at_s) in &run.inject {
        let (what, timeout_s) = match fault {
            Fault::LinkLoss => ("link-loss", p.link_timeout_s),
            Fault::GpsLoss if p.gps_live => ("gps-loss", p.gps_timeout_s),
            Fault::ImuStall => ("imu-timeout", cfg.watchdog.imu_timeout_ms as f64 / 1000.0),
            _ => continue,
        };
        for &(armed_s, until_s) in &spans {
            let due_s = at_s.max(armed_s) + timeout_s + SLACK_S;
            if until_s <= due_s || s.simulated_s <= due_s {
                continue;
            }
            // A halt for any cause by then stopped the motors too.
            let acted = r.failsafes.iter().any(|f| f.kind == what && f.t_s <= due_s)
                || s.fly
                    .halt
                    .is_some_and(|h| h.trip.event_us as f64 / 1e6 <= due_s);
            if !acted {
                broken(
                    6,
                    format!("{what} not acted on by {due_s:.2} s (armed until {until_s:.2} s)"),
                );
            }
        }
    }
    gps_loss_action_in_time(s.simulated_s, r, &spans, p, broken);
}

/// 6, the GPS's second step: a `gps-loss` recorded in the air is followed by its action
/// (a landing or a return; nothing for `hold`) within `failsafe.gps_loss_land_s`, unless
/// the vehicle was disarmed or halted by then, or was landing already and still is.
fn gps_loss_action_in_time(
    simulated_s: f64,
    r: &CommanderReport,
    spans: &[(f64, f64)],
    p: &Params,
    broken: &mut impl FnMut(u8, String),
) {
    let Some(f) = r
        .failsafes
        .iter()
        .find(|f| f.kind == Failsafe::GpsLoss.name())
    else {
        return;
    };
    if f.action == Action::Hold.name() {
        return;
    }
    let due_s = f.t_s + p.gps_loss_land_s + SLACK_S;
    let armed_then = spans.iter().any(|&(a, until)| a <= f.t_s && until > due_s);
    let acting = |mode: &str| matches!(mode, "land" | "return" | "disarmed" | "kill");
    // A landing already under way (another failsafe's, say) is the action itself, if it is
    // still landing (or done) when the action is due.
    let in_force = |t_s: f64| r.modes.iter().rev().find(|m| m.t_s <= t_s).map(|m| m.mode);
    let landing_kept = in_force(f.t_s) == Some("land")
        && matches!(in_force(due_s), Some("land" | "disarmed" | "kill"));
    let acted = landing_kept
        || r.modes
            .iter()
            .any(|m| m.t_s >= f.t_s && m.t_s <= due_s && acting(m.mode));
    if armed_then && simulated_s > due_s && !acted {
        broken(
            6,
            format!(
                "gps-loss at {:.2} s: no {} by {due_s:.2} s (failsafe.gps_loss_land_s {} s)",
                f.t_s, f.action, p.gps_loss_land_s
            ),
        );
    }
}

/// 7: the report's modes, failsafes, halt and refusal count are mode.log's.
fn report_is_mode_log(
    s: &SimSummary,
    r: &CommanderReport,
    mode_log: &str,
    broken: &mut impl FnMut(u8, String),
) {
    let (mut modes, mut failsafes, mut refusals) = (Vec::new(), Vec::new(), 0u64);
    let (mut modes_now, mut reentries) = (None::<String>, 0u64);
    for line in mode_log.lines() {
        let mut words = line.split(' ');
        let (Some(t), Some(kind)) = (words.next(), words.next()) else {
            continue;
        };
        let t_s = t.parse::<i64>().map_or(f64::NAN, |t_us| t_us as f64 / 1e6);
        match kind {
            "mode" => {
                let mode = words.next().unwrap_or("").to_string();
                // A re-entry of the mode it was in: the report lists the first ones.
                if modes_now.replace(mode.clone()).as_ref() == Some(&mode) {
                    reentries += 1;
                    if reentries > REFUSALS_MAX {
                        continue;
                    }
                }
                modes.push((mode, t_s));
            }
            "failsafe" => failsafes.push((words.next().unwrap_or("").to_string(), t_s)),
            "refused" => refusals += 1,
            _ => {}
        }
    }
    let report_modes: Vec<(String, f64)> = r
        .modes
        .iter()
        .map(|m| (m.mode.to_string(), m.t_s))
        .collect();
    let report_failsafes: Vec<(String, f64)> = r
        .failsafes
        .iter()
        .map(|f| (f.kind.to_string(), f.t_s))
        .collect();
    if report_modes != modes {
        broken(
            7,
            format!("modes: report {report_modes:?}, mode.log {modes:?}"),
        );
    }
    if report_failsafes != failsafes {
        broken(
            7,
            format!("failsafes: report {report_failsafes:?}, mode.log {failsafes:?}"),
        );
    }
    if r.refusals_total != refusals {
        broken(
            7,
            format!("refusals: report {}, mode.log {refusals}", r.refusals_total),
        );
    }
    if r.mode_reentries_total != reentries {
        broken(
            7,
            format!(
                "re-entries: report {}, mode.log {reentries}",
                r.mode_reentries_total
            ),
        );
    }
    if let Some(h) = &s.fly.halt {
        let named = r
            .modes
            .iter()
            .any(|m| m.mode == Mode::Kill.name() && m.why == h.trip.reason.name());
        if !named {
            broken(7, format!("halt {} not in the modes", h.trip.reason.name()));
        }
    }
}

/// The run's outcome in a word or two: how it ended.
pub fn outcome(s: &SimSummary) -> String {
    let r = s.fly.commander.report();
    if let Some(h) = &s.fly.halt {
        return format!("halt {}", h.trip.reason.name());
    }
    if let Some(e) = &s.fly.error {
        return format!("error: {}", e.chars().take(40).collect::<String>());
    }
    if r.modes.iter().all(|m| m.mode == Mode::Disarmed.name()) {
        return "not armed".to_string();
    }
    let flew = r.modes.iter().any(|m| m.mode == Mode::Takeoff.name());
    match (r.failsafes.first(), flew) {
        (Some(f), true) => format!("{} {}", f.kind, f.action),
        (Some(f), false) => format!("{} on ground", f.kind),
        (None, true) if r.touchdown.is_some() => "landed".to_string(),
        (None, true) => "no touchdown".to_string(),
        (None, false) => "disarmed on ground".to_string(),
    }
}
