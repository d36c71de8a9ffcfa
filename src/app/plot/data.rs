//! What `uquad plot` draws, read from a run folder: the estimate (x_hat.log, timed by
//! kalman_in.log), the set points (setpoint.log), the motor speeds (w.log), the mode changes
//! and failsafes (mode.log), and the horizontal track against the planned one. Works on our
//! run folders and the original's (which have neither set points nor modes).

use crate::app::run_logs::RunLogs;
use std::path::Path;

/// At most this many points per series are kept (evenly picked): a 10-minute flight at
/// 100 Hz is 60 000, far more than a figure's width.
const MAX_POINTS: usize = 4000;

/// One named series over time (s) or, in the track, east and north (m).
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// A set point (drawn dashed, in the colour of the series it is the set point of).
    pub setpoint: bool,
}

/// One panel over time.
#[derive(Debug, Clone, PartialEq)]
pub struct TimePanel {
    pub title: &'static str,
    /// The vertical axis, with its unit.
    pub y_desc: &'static str,
    pub series: Vec<Series>,
}

/// A mode change or failsafe, at a time and (for the track) where the vehicle was.
#[derive(Debug, Clone, PartialEq)]
pub struct Mark {
    pub t_s: f64,
    pub label: String,
    pub failsafe: bool,
    /// East, north (m) by the estimate at that time.
    pub at_m: Option<(f64, f64)>,
}

/// The figure's content.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    pub title: String,
    pub panels: Vec<TimePanel>,
    /// Flown (the estimate) and planned (the set point), east and north in m.
    pub track: Vec<Series>,
    pub marks: Vec<Mark>,
}

/// Every `stride`-th point, so that at most [`MAX_POINTS`] remain.
fn thin(points: impl ExactSizeIterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    let stride = points.len().div_ceil(MAX_POINTS).max(1);
    points
        .step_by(stride)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect()
}

fn series(name: &str, setpoint: bool, points: Vec<(f64, f64)>) -> Series {
    Series {
        name: name.to_string(),
        points,
        setpoint,
    }
}

/// Reads the figure of `run_dir`.
pub fn figure(run_dir: &Path) -> anyhow::Result<Figure> {
    let run = RunLogs::read(run_dir)?;
    let (x_hat, w, sp) = (&run.x_hat, &run.w, &run.setpoint);
    let t: Vec<f64> = run
        .estimate_times_us()
        .iter()
        .map(|&t| t as f64 / 1e6)
        .collect();
    let est = |i: usize| thin(t.iter().zip(x_hat).map(|(&t, x)| (t, x[i])));
    let set = |i: usize| thin(sp.iter().map(|(t, v)| (*t as f64 / 1e6, v[i])));
    let pair = |name: &str, i: usize| {
        let mut v = vec![series(name, false, est(i))];
        if !sp.is_empty() {
            v.push(series(&format!("{name} set point"), true, set(i)));
        }
        v
    };
    let motors = (0..4)
        .map(|m| {
            let pts = thin(w.iter().map(|(t, v)| (*t as f64 / 1e6, v[m])));
            series(&format!("motor {m}"), false, pts)
        })
        .collect();
    let track = track(&run);
    let east_north = |x: &[f64; 15]| (-x[1], x[0]);
    let marks = marks(&run.mode_log, |t_s| {
        let k = t.partition_point(|&s| s < t_s).min(x_hat.len() - 1);
        east_north(&x_hat[k])
    });
    Ok(Figure {
        title: format!("uquad run {}", run_dir.display()),
        panels: vec![
            TimePanel {
                title: "altitude",
                y_desc: "z (m, up)",
                series: pair("z", 2),
            },
            TimePanel {
                title: "roll and pitch",
                y_desc: "angle (rad)",
                series: [pair("roll ψ", 3), pair("pitch φ", 4)].concat(),
            },
            TimePanel {
                title: "yaw",
                y_desc: "θ (rad)",
                series: pair("yaw θ", 5),
            },
            TimePanel {
                title: "motor speeds",
                y_desc: "ω (rad/s)",
                series: motors,
            },
        ],
        track,
        marks,
    })
}

/// The horizontal track, east and north (m): flown (the estimate) and, with set points, the
/// planned one.
fn track(run: &RunLogs) -> Vec<Series> {
    let east_north = |x: f64, y: f64| (-y, x);
    let flown = thin(run.x_hat.iter().map(|x| east_north(x[0], x[1])));
    let mut track = vec![series("flown (estimate)", false, flown)];
    if !run.setpoint.is_empty() {
        let planned = thin(run.setpoint.iter().map(|(_, v)| east_north(v[0], v[1])));
        track.push(series("planned (set point)", true, planned));
    }
    track
}

/// The mode changes (`T mode NAME why`) and failsafes (`T failsafe KIND ACTION`) of a
/// mode.log; `at` places a time on the track.
fn marks(mode_log: &str, at: impl Fn(f64) -> (f64, f64)) -> Vec<Mark> {
    mode_log
        .lines()
        .filter_map(|line| {
            let mut w = line.split_whitespace();
            let t_s = w.next()?.parse::<i64>().ok()? as f64 / 1e6;
            let (kind, name) = (w.next()?, w.next()?);
            let failsafe = match kind {
                "mode" => false,
                "failsafe" => true,
                _ => return None,
            };
            let label = if failsafe {
                format!("failsafe {name}")
            } else {
                name.to_string()
            };
            Some(Mark {
                t_s,
                label,
                failsafe,
                at_m: Some(at(t_s)),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mode_changes_and_failsafes_are_marks_the_rest_is_not() {
        let log = "0 mode disarmed start\n1000000 in gcs arm | ok\n2000000 beat gcs\n\
                   2500000 mode armed command arm\n9000000 failsafe link-loss land\n\
                   9500000 reached 1 goto\n";
        let m = marks(log, |t| (t, -t));
        let labels: Vec<&str> = m.iter().map(|m| m.label.as_str()).collect();
        assert_eq!(labels, ["disarmed", "armed", "failsafe link-loss"]);
        assert_eq!(m[2].t_s, 9.0);
        assert!(m[2].failsafe && !m[1].failsafe);
        assert_eq!(m[1].at_m, Some((2.5, -2.5)));
    }

    #[test]
    fn long_series_are_thinned_evenly() {
        let pts = thin((0..10_000).map(|i| (i as f64, f64::from(i))));
        assert!(
            pts.len() <= MAX_POINTS && pts.len() >= MAX_POINTS / 2,
            "{}",
            pts.len()
        );
        assert_eq!(pts[0], (0.0, 0.0));
        let short = thin((0..10).map(|i| (f64::from(i), f64::NAN)));
        assert!(short.is_empty(), "points that are not numbers are left out");
    }
}
