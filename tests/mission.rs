//! Missions end to end: `uquad sim --mission` flies the square and the orbit of
//! config/missions/ from takeoff to touchdown, reports its track against the planned path,
//! replays to the same bytes; bad mission files are refused by file, item and key.

mod common;
use common::*;
use serde_json::Value;
use std::path::Path;

/// `uquad sim --fast --mission FILE ARGS`: its exit status and report.
fn mission(file: &str, args: &[&str]) -> (bool, Value, tempfile::TempDir) {
    let mut all = vec!["--fast", "--config", "config/uquad.toml", "--mission", file];
    all.extend_from_slice(args);
    let (status, r, logs) = sim_report(&all);
    (status.success(), r, logs)
}

/// Flown from takeoff to touchdown, near its planned duration, on track; the run replays to
/// the same bytes. Returns the report.
fn flies(file: &str, items: usize) -> Value {
    let (ok, r, _logs) = mission(file, &[]);
    assert!(ok, "{r}");
    let want = [
        "disarmed", "armed", "takeoff", "mission", "land", "disarmed",
    ];
    assert_eq!(report_modes(&r), want, "{r}");
    assert!(r["halt"].is_null() && r["deadline_misses"] == 0, "{r}");
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("no {k}: {r}"));
    // The estimate follows the path within 0.5 m; the truth within the simulated receiver's
    // error (a u-blox NEO-M8N: a bias of 2 m that wanders over a minute) on top.
    assert!(f("track_est_rms_m") <= 0.5, "{r}");
    assert!(f("track_rms_m") <= 2.5 && f("track_max_m") < 4.0, "{r}");
    assert!((f("mission_s") - f("mission_ideal_s")).abs() < 0.5, "{r}");
    assert!(
        r["touchdown"]["from_takeoff_m"].as_f64().unwrap() < 5.0,
        "{r}"
    );
    let run = Path::new(r["run_dir"].as_str().unwrap()).to_path_buf();
    // Every item was reached, in order: the takeoff at its height, the landing at its
    // touchdown.
    let mode_log = std::fs::read_to_string(run.join("mode.log")).unwrap();
    let reached: Vec<usize> = mode_log
        .lines()
        .filter_map(|l| l.split_once(" reached ")?.1.split(' ').next()?.parse().ok())
        .collect();
    assert_eq!(reached, (0..items).collect::<Vec<_>>(), "{mode_log}");
    // The run folder keeps the mission; the replay flies it again to the same bytes.
    assert!(run.join("mission.toml").is_file());
    assert_replays_same(&run, &["mode.log", "w.log", "x_hat.log", "int.log"]);
    motors_calm(&run, &r);
    r
}

/// While the mission flies the motors move smoothly and stay off their lower limit (a torque
/// observer faster than its inputs' noise makes them chatter down to w_min under the
/// receiver's errors).
fn motors_calm(run: &Path, r: &Value) {
    let t = |i: usize| r["modes"][i]["t_s"].as_f64().unwrap();
    // From the mission's start to the landing: modes 3 and 4.
    let (from, to) = (t(3) + 1.0, t(4));
    let w: Vec<Vec<f64>> = numbers(&run.join("w.log"))
        .into_iter()
        .filter(|row| row[0] > from && row[0] < to)
        .collect();
    assert!(w.len() > 1000, "{} commands in the mission", w.len());
    let steps = w
        .windows(2)
        .flat_map(|p| (1..5).map(move |m| (p[1][m] - p[0][m]).abs()));
    let mean = steps.clone().sum::<f64>() / steps.count() as f64;
    let lowest = w
        .iter()
        .flat_map(|row| row[1..].to_vec())
        .fold(f64::MAX, f64::min);
    eprintln!("motors in the mission: mean |dw| {mean:.2} rad/s a step, lowest {lowest:.0} rad/s");
    assert!(mean < 2.0, "the motors chatter: {mean:.2} rad/s a step");
    assert!(lowest > 250.0, "a motor went down to {lowest:.0} rad/s");
}

#[test]
fn the_square_is_flown_on_track_and_replays_exactly() {
    flies("config/missions/square.toml", 6);
}

#[test]
fn the_orbit_is_flown_on_track_and_replays_exactly() {
    flies("config/missions/orbit.toml", 4);
}

#[test]
fn bad_missions_are_refused_by_file_item_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "[[item]]\nkind = \"goto\"\nat_m = [100.0, 0.0, 2.0]\nspeed_m_s = 1.0\n",
            "item 1 (goto): at_m reaches 100.0 m from the takeoff point: outside fence.radius_m",
        ),
        (
            "[[item]]\nkind = \"orbit\"\ncentre_m = [0.0, 0.0]\nradius_m = 5.0\nspeed_m_s = 0.0\nturns = 1.0\n",
            "item 1 (orbit): speed_m_s = 0: expected 0.05..10 m/s",
        ),
        (
            "[[item]]\nkind = \"land\"\n[[item]]\nkind = \"hold\"\nseconds = 1.0\n",
            "item 1: a landing can only be the last item",
        ),
        ("[[item]]\nkind = \"jump\"\n", "unknown variant `jump`"),
        (
            "[[item]]\nkind = \"hold\"\nsecs = 1.0\n",
            "unknown field `secs`",
        ),
    ];
    for (text, named) in cases {
        let file = dir.path().join("m.toml");
        std::fs::write(&file, text).unwrap();
        let o = uquad(
            &root(),
            &["sim", "--fast", "--mission", file.to_str().unwrap()],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{named}: {err}");
        assert!(err.contains(named), "{named}: {err}");
        assert!(err.contains("m.toml"), "{err}");
    }
    // The 2012 profile has no position control: a mission is refused with the reason.
    let o = uquad(
        &root(),
        &[
            "sim",
            "--fast",
            "--config",
            "config/flight-2012-05.toml",
            "--mission",
            "config/missions/square.toml",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("missions need position control"), "{err}");
}
