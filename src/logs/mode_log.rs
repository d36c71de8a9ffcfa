//! The `mode` stream (mode.log): the commander's inputs (operator commands with the pre-arm
//! verdict an `arm` got, link beats, GPS fixes delivered, manual keys, a ground station's
//! missions) and outputs
//! (mode changes, failsafes, refusals, mission items reached), one per line after the time
//! in µs. `uquad replay` reads the inputs back and
//! writes the outputs again, so a replayed run's mode.log is the same bytes.
//!
//! ```text
//! 0 run 20261126-220553-3f9a1c2e
//! 1000000 in gcs arm | ok
//! 1000000 mode armed command arm
//! 12000000 in console takeoff 1.5
//! 30500000 failsafe link-loss land
//! 31000000 refused disarm | in the air (land): land first, or kill
//! 2000000 beat gcs
//! 2100000 key 101
//! 2200000 fix
//! 2300000 escs running
//! 2400000 param commander.land_m_s 0.3
//! 2500000 mission mission-1.toml gains caeb2603ff2b78ed
//! ```
//!
//! The first line names the run (its config.toml and gps.log headers name it too); a replay
//! refuses a mode.log of another run, inputs out of time order or after the run's last frame
//! (an expired one excepted: it is recorded at the run's end), and quotes at most
//! [`QUOTE_MAX`] bytes of a bad line.
//!
//! A ground station's mission is recorded by the name of the file the link wrote into the
//! run folder and a fingerprint of the gains planned for it; a replay plans it again from that
//! file and refuses gains that differ (another profile) instead of flying something else.

use crate::core::commander::{Command, Event, LinkSource, OperatorInput};
use crate::core::control::ManualCommand;
use crate::core::mission::MissionPlan;
use std::fmt::Write;
use std::sync::Arc;

/// Bytes of a bad line an error quotes.
pub const QUOTE_MAX: usize = 80;

/// `text` for an error message: whole when short, else its first [`QUOTE_MAX`] bytes (at a
/// character boundary) and its length.
pub fn quote(text: &str) -> String {
    if text.len() <= QUOTE_MAX {
        return format!("{text:?}");
    }
    let mut end = QUOTE_MAX;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{:?}… ({} bytes)", &text[..end], text.len())
}

/// An error message cut to at most four quotes' worth (a bad line can be megabytes long).
fn clip(mut e: String) -> String {
    let max = 4 * QUOTE_MAX;
    if e.len() > max {
        let mut end = max;
        while !e.is_char_boundary(end) {
            end -= 1;
        }
        let len = e.len();
        e.truncate(end);
        e.push_str(&format!("… ({len} bytes)"));
    }
    e
}

/// Appends the run's line, the first of its mode.log.
pub fn write_run(out: &mut String, run_id: &str) {
    let _ = writeln!(out, "0 run {run_id}");
}

/// The run a mode.log names on its first line; `None` for one that names none (written
/// before runs had ids).
pub fn read_run(text: &str) -> Option<&str> {
    let first = text.lines().next()?.trim_end_matches('\r');
    first.strip_prefix("0 run ")
}

/// Appends an output line.
pub fn write_event(out: &mut String, e: &Event) {
    let _ = match e {
        Event::Mode { t_us, mode, why } => writeln!(out, "{t_us} mode {} {why}", mode.name()),
        Event::Failsafe { t_us, kind, action } => {
            writeln!(out, "{t_us} failsafe {} {}", kind.name(), action.name())
        }
        Event::Refusal { t_us, command, why } => writeln!(out, "{t_us} refused {command} | {why}"),
        Event::Reached { t_us, item, name } => writeln!(out, "{t_us} reached {item} {name}"),
    };
}

/// Appends an input line; an `arm` carries its verdict (`ok` or the failing check).
pub fn write_input(
    out: &mut String,
    t_us: i64,
    input: &OperatorInput,
    verdict: Option<&Result<(), String>>,
) {
    let _ = match input {
        OperatorInput::Beat(src) => writeln!(out, "{t_us} beat {}", src.name()),
        OperatorInput::GpsFix => writeln!(out, "{t_us} fix"),
        OperatorInput::EscsRunning => writeln!(out, "{t_us} escs running"),
        OperatorInput::Param { key, value } => writeln!(out, "{t_us} param {key} {value}"),
        OperatorInput::Rc(r) if r.lost => writeln!(out, "{t_us} rc lost"),
        OperatorInput::Rc(r) => {
            let [roll, pitch, yaw, throttle] = r.sticks;
            let kill = if r.kill { "on" } else { "off" };
            let mode = r
                .stick_mode
                .map_or(String::new(), |m| format!(" mode {}", m.name()));
            writeln!(
                out,
                "{t_us} rc kill {kill} sticks {roll} {pitch} {yaw} {throttle}{mode}"
            )
        }
        OperatorInput::Sticks([roll, pitch, yaw, throttle]) => {
            writeln!(out, "{t_us} sticks {roll} {pitch} {yaw} {throttle}")
        }
        OperatorInput::Key(k) => writeln!(out, "{t_us} key {}", k.key()),
        OperatorInput::Mission(plan) => writeln!(
            out,
            "{t_us} mission {} gains {:016x}",
            plan.name,
            plan.gains.fingerprint()
        ),
        OperatorInput::Command(c, src) => {
            let _ = write!(out, "{t_us} in {} {c}", src.name());
            match verdict {
                Some(Ok(())) => writeln!(out, " | ok"),
                Some(Err(why)) => writeln!(out, " | {why}"),
                None => writeln!(out),
            }
        }
        // `T expired WAITED_US` then the input's own line without its time.
        OperatorInput::Expired { input, waited_us } => {
            let mut inner = String::new();
            write_input(&mut inner, t_us, input, None);
            let body = inner.split_once(' ').map_or("", |(_, b)| b);
            write!(out, "{t_us} expired {waited_us} {body}")
        }
    };
}

/// One recorded input: its time, the input and an `arm`'s verdict.
pub type RecordedInput = (i64, OperatorInput, Result<(), String>);

/// Inputs later than this after the run's last recorded frame are not of the run, µs (a
/// week: a run that stays up, disarmed, records its inputs long after its last frame).
pub const LATE_MAX_US: i64 = 7 * 86_400 * 1_000_000;

/// The inputs of a mode.log, in order; output lines are skipped. A line that is not
/// understood is an error naming its number: one out of time order (inputs never go back),
/// at a negative time, more than [`LATE_MAX_US`] after `last_frame_us` (the run's last
/// recorded frame), or a `run` line not first. `mission` gives the plan of a recorded
/// mission's file name.
pub fn read_inputs(
    text: &str,
    last_frame_us: i64,
    mission: &mut dyn FnMut(&str) -> Result<Arc<MissionPlan>, String>,
) -> Result<Vec<RecordedInput>, String> {
    let mut inputs: Vec<RecordedInput> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() || (n == 0 && read_run(line).is_some()) {
            continue;
        }
        let input = parse_input(line, mission)
            .and_then(|i| check_time(i, inputs.last(), last_frame_us))
            .map_err(|e| format!("line {}: {}", n + 1, clip(e)))?;
        inputs.extend(input);
    }
    Ok(inputs)
}

/// An input's time: not negative, not before the previous input's, not far beyond the run's
/// last frame (inputs after it are applied after it, as the run did: a run that never
/// calibrated records no frame at all).
fn check_time(
    input: Option<RecordedInput>,
    previous: Option<&RecordedInput>,
    last_frame_us: i64,
) -> Result<Option<RecordedInput>, String> {
    let Some((t_us, i, v)) = input else {
        return Ok(None);
    };
    if t_us < 0 {
        return Err(format!("time {t_us} µs is before the run's start"));
    }
    if let Some((before_us, ..)) = previous
        && t_us < *before_us
    {
        return Err(format!(
            "time {t_us} µs is before the previous input's ({before_us} µs): inputs are recorded in order"
        ));
    }
    if t_us > last_frame_us.saturating_add(LATE_MAX_US) {
        return Err(format!(
            "time {t_us} µs is more than a week after the run's last frame ({last_frame_us} µs): not of this run"
        ));
    }
    Ok(Some((t_us, i, v)))
}

/// The commander's `kill` of a mode.log (the watchdog's halt): its time and reason, which a
/// replay, having no watchdog, takes from the run.
pub fn read_halt(text: &str) -> Option<(i64, String)> {
    text.lines().find_map(|line| {
        let mut parts = line.trim_end_matches('\r').splitn(4, ' ');
        let t_us = parts.next()?.parse().ok()?;
        (parts.next()? == "mode" && parts.next()? == "kill")
            .then(|| (t_us, parts.next().unwrap_or("").to_string()))
    })
}

fn parse_input(
    line: &str,
    mission: &mut dyn FnMut(&str) -> Result<Arc<MissionPlan>, String>,
) -> Result<Option<RecordedInput>, String> {
    let mut parts = line.splitn(3, ' ');
    let t_us: i64 = parts
        .next()
        .and_then(|t| t.parse().ok())
        .ok_or_else(|| format!("no time in µs at the start of {}", quote(line)))?;
    let kind = parts.next().unwrap_or("");
    let rest = parts.next().unwrap_or("");
    let source = |name: &str| {
        LinkSource::from_any_name(name)
            .ok_or_else(|| format!("unknown link source {}", quote(name)))
    };
    let input = match kind {
        "beat" => OperatorInput::Beat(source(rest)?),
        "fix" if rest.is_empty() => OperatorInput::GpsFix,
        "escs" if rest == "running" => OperatorInput::EscsRunning,
        "param" => parse_param(rest)?,
        "rc" => OperatorInput::Rc(parse_rc(rest)?),
        "sticks" => OperatorInput::Sticks(
            parse_sticks(&rest.split(' ').collect::<Vec<_>>())
                .ok_or_else(|| format!("sticks: {} is not `R P Y T`, each -1 to 1", quote(rest)))?,
        ),
        "key" => {
            let k = rest.parse::<u8>().ok().and_then(ManualCommand::from_key);
            OperatorInput::Key(k.ok_or_else(|| format!("unknown key {}", quote(rest)))?)
        }
        "mission" => OperatorInput::Mission(recorded_mission(rest, mission)?),
        "in" => return parse_command(t_us, rest, source).map(Some),
        "expired" => return parse_expired(t_us, rest, mission).map(Some),
        "mode" | "failsafe" | "refused" | "reached" => return Ok(None),
        "run" => return Err("a run line only starts a mode.log".into()),
        _ => return Err(format!("unknown record {}", quote(kind))),
    };
    Ok(Some((t_us, input, Ok(()))))
}

/// `KEY VALUE`: a parameter changed in flight; the key one that takes effect in flight, the
/// value a finite number.
fn parse_param(rest: &str) -> Result<OperatorInput, String> {
    let (key, value) = rest.split_once(' ').unwrap_or((rest, ""));
    let key = crate::core::commander::in_flight_key(key)
        .ok_or_else(|| format!("param: {} does not take effect in flight", quote(key)))?;
    // Every key that takes effect in flight is a speed, a height or a time: above 0.
    let value = value
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0)
        .ok_or_else(|| format!("param {key}: {} is not a number above 0", quote(value)))?;
    Ok(OperatorInput::Param { key, value })
}

/// Four stick positions, each a number from -1 to 1.
fn parse_sticks(words: &[&str]) -> Option<[f64; 4]> {
    let [r, p, y, t] = words else { return None };
    let mut v = [0.0; 4];
    for (x, w) in v.iter_mut().zip([r, p, y, t]) {
        *x = w.parse::<f64>().ok().filter(|x| (-1.0..=1.0).contains(x))?;
    }
    Some(v)
}

/// `lost`, or `kill on|off sticks ROLL PITCH YAW THROTTLE [mode position|altitude]` (each
/// stick a number from -1 to 1): the pilot's radio.
fn parse_rc(rest: &str) -> Result<crate::core::commander::RcReport, String> {
    let bad = || {
        format!(
            "rc: {} is not `lost` nor `kill on|off sticks R P Y T [mode position|altitude]`",
            quote(rest)
        )
    };
    if rest == "lost" {
        return Ok(crate::core::commander::RcReport::LOST);
    }
    let words: Vec<&str> = rest.split(' ').collect();
    let (kill, sticks, stick_mode) = match words.as_slice() {
        ["kill", k, "sticks", r, p, y, t] => (*k, [*r, *p, *y, *t], None),
        ["kill", k, "sticks", r, p, y, t, "mode", m] => (
            *k,
            [*r, *p, *y, *t],
            Some(crate::core::commander::StickMode::from_name(m).ok_or_else(bad)?),
        ),
        _ => return Err(bad()),
    };
    let kill = match kill {
        "on" => true,
        "off" => false,
        _ => return Err(bad()),
    };
    Ok(crate::core::commander::RcReport {
        lost: false,
        kill,
        sticks: parse_sticks(&sticks).ok_or_else(bad)?,
        stick_mode,
    })
}

/// `WAITED_US KIND ...`: an input that expired, recorded by its own line's kind and body.
fn parse_expired(
    t_us: i64,
    rest: &str,
    mission: &mut dyn FnMut(&str) -> Result<Arc<MissionPlan>, String>,
) -> Result<RecordedInput, String> {
    let (waited, body) = rest.split_once(' ').unwrap_or((rest, ""));
    // One level only: an expired input inside another is no record (and no recursion).
    if body.starts_with("expired") {
        return Err("expired: an expired input inside another".into());
    }
    let waited_us: i64 = waited
        .parse()
        .ok()
        .filter(|w| *w >= 0)
        .ok_or_else(|| format!("expired: no waiting time in µs in {}", quote(waited)))?;
    match parse_input(&format!("{t_us} {body}"), mission)? {
        Some((_, input, _)) if input.expires() => Ok((
            t_us,
            OperatorInput::Expired {
                input: Box::new(input),
                waited_us,
            },
            Ok(()),
        )),
        _ => Err("expired: not a command, a key or a mission".into()),
    }
}

/// `NAME gains FINGERPRINT`: the plan of file NAME, whose gains must be the ones flown.
fn recorded_mission(
    rest: &str,
    mission: &mut dyn FnMut(&str) -> Result<Arc<MissionPlan>, String>,
) -> Result<Arc<MissionPlan>, String> {
    let (name, flown) = match rest.split_once(" gains ") {
        Some((n, f)) => (n, Some(f)),
        None => (rest, None),
    };
    let plan = mission(name)?;
    let now = format!("{:016x}", plan.gains.fingerprint());
    match flown {
        Some(f) if f != now => Err(format!(
            "mission {name}: its gains now (fingerprint {now}) are not the ones flown ({f}): \
             replay it with the run's own configuration"
        )),
        _ => Ok(plan),
    }
}

fn parse_command(
    t_us: i64,
    rest: &str,
    source: impl Fn(&str) -> Result<LinkSource, String>,
) -> Result<RecordedInput, String> {
    let (src, body) = rest.split_once(' ').unwrap_or((rest, ""));
    let (cmd, verdict) = match body.split_once(" | ") {
        Some((c, "ok")) => (c, Ok(())),
        Some((c, why)) => (c, Err(why.to_string())),
        None => (body, Ok(())),
    };
    let cmd = Command::parse(cmd)?;
    Ok((t_us, OperatorInput::Command(cmd, source(src)?), verdict))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::commander::{Action, Failsafe, Mode};

    #[test]
    fn inputs_read_back_as_written_and_outputs_are_skipped() {
        let mut s = String::new();
        let arm = OperatorInput::Command(Command::Arm, LinkSource::Gcs);
        write_input(&mut s, 5, &arm, Some(&Err("gps: no fix".into())));
        write_input(&mut s, 6, &arm, Some(&Ok(())));
        let takeoff = OperatorInput::Command(Command::Takeoff(Some(1.5)), LinkSource::Console);
        write_input(&mut s, 7, &takeoff, None);
        write_input(&mut s, 8, &OperatorInput::Beat(LinkSource::Terminal), None);
        let key = OperatorInput::Key(ManualCommand::from_key(b'e').unwrap());
        write_input(&mut s, 9, &key, None);
        let plan = Arc::new(MissionPlan {
            name: "mission-1.toml".into(),
            ..MissionPlan::default()
        });
        write_input(&mut s, 11, &OperatorInput::Mission(plan.clone()), None);
        write_event(
            &mut s,
            &Event::Mode {
                t_us: 6,
                mode: Mode::Armed,
                why: "command arm".into(),
            },
        );
        let fs = Event::Failsafe {
            t_us: 10,
            kind: Failsafe::LinkLoss,
            action: Action::Land,
        };
        write_event(&mut s, &fs);
        let mut asked = Vec::new();
        let mut resolve = |name: &str| {
            asked.push(name.to_string());
            Ok(plan.clone())
        };
        let got = read_inputs(&s, i64::MAX, &mut resolve).unwrap();
        assert_eq!(
            got,
            vec![
                (5, arm.clone(), Err("gps: no fix".to_string())),
                (6, arm, Ok(())),
                (7, takeoff, Ok(())),
                (8, OperatorInput::Beat(LinkSource::Terminal), Ok(())),
                (9, key, Ok(())),
                (11, OperatorInput::Mission(plan.clone()), Ok(())),
            ]
        );
        assert_eq!(asked, ["mission-1.toml"]);
        assert!(s.contains("10 failsafe link-loss land\n"), "{s}");
        let kill = Event::Mode {
            t_us: 12,
            mode: Mode::Kill,
            why: "imu-timeout".into(),
        };
        write_event(&mut s, &kill);
        assert_eq!(read_halt(&s), Some((12, "imu-timeout".to_string())));
        let n = read_inputs(&s, i64::MAX, &mut |_| Ok(plan.clone()))
            .unwrap()
            .len();
        assert_eq!(n, 6, "a kill is an output");
    }

    #[test]
    fn a_motor_test_reads_back_with_its_verdict() {
        let test = OperatorInput::Command(
            Command::MotorTest {
                motor: 2,
                throttle_pct: 12.5,
                duration_s: 1.5,
            },
            LinkSource::Gcs,
        );
        let mut s = String::new();
        let why = "esc: no acknowledgement from 0x6b".to_string();
        write_input(&mut s, 3, &test, Some(&Err(why.clone())));
        write_input(&mut s, 4, &test, Some(&Ok(())));
        assert_eq!(
            s,
            format!("3 in gcs motor 2 12.5 1.5 | {why}\n4 in gcs motor 2 12.5 1.5 | ok\n")
        );
        let mut none = |name: &str| Err(format!("no file {name}"));
        let got = read_inputs(&s, i64::MAX, &mut none).unwrap();
        assert_eq!(got, vec![(3, test.clone(), Err(why)), (4, test, Ok(()))]);
        for bad in [
            "5 in gcs motor 1.5 10 1",
            "5 in gcs motor 1 10",
            "5 in gcs motor 300 1 1",
        ] {
            assert!(read_inputs(bad, i64::MAX, &mut none).is_err(), "{bad}");
        }
    }

    #[test]
    fn an_expired_input_reads_back_expired() {
        let arm = OperatorInput::Command(Command::Arm, LinkSource::Gcs);
        let expired = OperatorInput::Expired {
            input: Box::new(arm),
            waited_us: 2_400_000,
        };
        let key = OperatorInput::Expired {
            input: Box::new(OperatorInput::Key(ManualCommand::from_key(b'e').unwrap())),
            waited_us: 5,
        };
        let mut s = String::new();
        write_input(&mut s, 7, &expired, None);
        write_input(&mut s, 8, &key, None);
        assert_eq!(s, "7 expired 2400000 in gcs arm\n8 expired 5 key 101\n");
        let mut none = |name: &str| Err(format!("no file {name}"));
        let got = read_inputs(&s, i64::MAX, &mut none).unwrap();
        assert_eq!(got, vec![(7, expired, Ok(())), (8, key, Ok(()))]);
        // Only an operator's asking expires; a negative wait or a nested one is no record.
        for bad in [
            "5 expired 3 beat gcs",
            "5 expired -3 in gcs arm",
            "5 expired 3 expired 3 fix",
        ] {
            assert!(read_inputs(bad, i64::MAX, &mut none).is_err(), "{bad}");
        }
    }

    #[test]
    fn inputs_out_of_order_before_the_start_or_after_the_last_frame_are_refused() {
        let mut none = |name: &str| Err(format!("no file {name}"));
        let mut read = |text: &str| read_inputs(text, 1000, &mut none);
        assert_eq!(read("0 run r-1\n5 beat gcs\n5 fix\n").unwrap().len(), 2);
        let e = read("7 beat gcs\n5 fix\n").unwrap_err();
        assert!(
            e.starts_with("line 2: time 5 µs is before the previous input's"),
            "{e}"
        );
        let e = read("-5 beat gcs\n").unwrap_err();
        assert!(
            e.starts_with("line 1: time -5 µs is before the run's start"),
            "{e}"
        );
        let e = read("9223372036854775807 in gcs arm\n").unwrap_err();
        assert!(
            e.contains("a week after the run's last frame (1000 µs)"),
            "{e}"
        );
        // Inputs after the last frame (a run that stayed up; an expired one recorded at the
        // run's end) are the run's.
        assert_eq!(
            read("5000 expired 2000000 in gcs arm\n6000 fix\n")
                .unwrap()
                .len(),
            2
        );
        // Nested expired inputs are refused without recursing (20 000 deep: no overflow).
        let deep = format!("0 {}in gcs arm\n", "expired 0 ".repeat(20_000));
        assert!(read(&deep).unwrap_err().contains("inside another"));
        let e = read("5 fix\n0 run r-1\n").unwrap_err();
        assert!(e.contains("a run line only starts a mode.log"), "{e}");
        assert_eq!(read_run("0 run r-1\n5 fix\n"), Some("r-1"));
        assert_eq!(read_run("5 fix\n"), None);
        // A long bad line is quoted by a prefix and its length, not whole.
        let long = format!("5 in gcs {}\n", "x".repeat(50_000_000));
        let e = read(&long).unwrap_err();
        assert!(e.len() < 400, "{}", e.len());
        assert!(e.ends_with("bytes)"), "{e}");
    }

    #[test]
    fn a_line_not_understood_is_named() {
        let mut none = |name: &str| Err(format!("no file {name}"));
        let e = read_inputs("5 beat gcs\nxx beat\n", i64::MAX, &mut none).unwrap_err();
        assert!(e.starts_with("line 2:"), "{e}");
        assert!(read_inputs("5 in gcs fly\n", i64::MAX, &mut none).is_err());
        let e = read_inputs("5 mission m.toml\n", i64::MAX, &mut none).unwrap_err();
        assert_eq!(e, "line 1: no file m.toml");
        // Gains planned now that differ from the ones flown are refused.
        let mut some = |_: &str| Ok(Arc::new(MissionPlan::default()));
        let e = read_inputs(
            "5 mission m.toml gains 0000000000000001\n",
            i64::MAX,
            &mut some,
        )
        .unwrap_err();
        assert!(e.contains("not the ones flown"), "{e}");
    }
}
