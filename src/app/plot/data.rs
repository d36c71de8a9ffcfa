//! What `uquad plot` draws, read from a run folder: the estimate (x_hat.log, timed by
//! kalman_in.log), the set points (setpoint.log), the simulated truth (truth.log, a `sim`
//! run's), the motor speeds (w.log), the innovation test ratios against their gate
//! (innov.log), the mode changes and failsafes (mode.log), and the horizontal track against
//! the planned one. Works on our run folders and the original's (which have neither set
//! points, truth, ratios nor modes).

use crate::app::log_lines::{EstimateTimes, LogLines};
use crate::logs;
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
    /// The simulated truth (drawn in black).
    pub truth: bool,
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
#[cfg(test)]
fn thin(points: impl ExactSizeIterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    let mut keep = Keep::new(points.len());
    points.for_each(|p| keep.push(p));
    keep.points
}

/// Keeps every `stride`-th of `len` points (the first included, those that are not numbers
/// left out), so that at most [`MAX_POINTS`] remain: a series read a point at a time.
#[derive(Debug, Clone)]
struct Keep {
    stride: usize,
    seen: usize,
    points: Vec<(f64, f64)>,
}

impl Keep {
    fn new(len: usize) -> Keep {
        Keep {
            stride: len.div_ceil(MAX_POINTS).max(1),
            seen: 0,
            points: Vec::with_capacity(len.min(MAX_POINTS)),
        }
    }

    /// Every `stride`-th drawable point: the stride counts only points that have a value, so
    /// a sparse series (the fixes' ratios, one step in a hundred) is not skipped whole when
    /// its steps fall between the stride's.
    fn push(&mut self, p: (f64, f64)) {
        if !(p.0.is_finite() && p.1.is_finite()) {
            return;
        }
        if self.seen.is_multiple_of(self.stride) {
            self.points.push(p);
        }
        self.seen += 1;
    }
}

fn series(name: &str, setpoint: bool, points: Vec<(f64, f64)>) -> Series {
    Series {
        name: name.to_string(),
        points,
        setpoint,
        truth: false,
    }
}

fn truth_series(name: &str, points: Vec<(f64, f64)>) -> Series {
    Series {
        truth: true,
        ..series(name, false, points)
    }
}

/// The five series of a state log row (z, roll, pitch, yaw, and the track east-north) from
/// `x` holding x y z ψ φ θ first.
fn push_pose(t_s: f64, x: &[f64], k: &mut [Keep; 5]) {
    for (keep, i) in k.iter_mut().zip([2, 3, 4, 5]) {
        keep.push((t_s, x[i]));
    }
    k[4].push((-x[1], x[0]));
}

/// The records of `name` in `run_dir` that `parse` reads; 0 when it is missing.
fn count<T>(
    run_dir: &Path,
    name: &str,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> anyhow::Result<usize> {
    let Some(mut lines) = LogLines::open(&run_dir.join(name))? else {
        return Ok(0);
    };
    let mut n = 0;
    while lines.next(&parse)?.is_some() {
        n += 1;
    }
    Ok(n)
}

/// The points of one log's `N` series, kept evenly (the log counted first): `each` pushes a
/// record's point into each series' keeper; with the log's warning, if lines were skipped.
fn read_series<T, const N: usize>(
    run_dir: &Path,
    name: &str,
    parse: impl Fn(&[&str]) -> Result<T, String>,
    mut each: impl FnMut(&T, u64, &mut [Keep; N]) -> anyhow::Result<()>,
) -> anyhow::Result<([Keep; N], Option<String>)> {
    let len = count(run_dir, name, &parse)?;
    let mut keeps: [Keep; N] = std::array::from_fn(|_| Keep::new(len));
    let Some(mut lines) = LogLines::open(&run_dir.join(name))? else {
        return Ok((keeps, None));
    };
    while let Some(r) = lines.next(&parse)? {
        each(&r, lines.last_index(), &mut keeps)?;
    }
    Ok((keeps, lines.warning()))
}

/// The pose series of a log whose rows are a time and `N` values, x y z ψ φ θ first
/// (setpoint.log, truth.log).
fn timed_poses<const N: usize>(
    run_dir: &Path,
    name: &str,
) -> anyhow::Result<([Keep; 5], Option<String>)> {
    read_series(
        run_dir,
        name,
        logs::parse_time_and::<N>,
        |(t, v), _, k: &mut [Keep; 5]| {
            push_pose(*t as f64 / 1e6, v, k);
            Ok(())
        },
    )
}

/// Reads the figure of `run_dir`, each log a line at a time (twice: once to count its
/// records, once to keep every so many): memory does not grow with the run's length. A
/// log's skipped lines (over-long, cut off, not understood) are told on stderr.
pub fn figure(run_dir: &Path) -> anyhow::Result<Figure> {
    let marks_t = marks(run_dir)?;
    let mut at_m: Vec<Option<(f64, f64)>> = vec![None; marks_t.len()];
    let mut last_at = None;
    let mut times = EstimateTimes::open(run_dir)?;
    // Estimates: z, roll, pitch, yaw over time, and the flown track.
    let (est, warning) = read_series(
        run_dir,
        "x_hat.log",
        logs::parse_x_hat,
        |x, index, k: &mut [Keep; 5]| {
            let t_s = times.at(index)? as f64 / 1e6;
            push_pose(t_s, &x[..], k);
            // A mark is placed where the first estimate at or after its time was.
            for (m, at) in marks_t.iter().zip(at_m.iter_mut()) {
                if at.is_none() && t_s >= m.t_s {
                    *at = Some((-x[1], x[0]));
                }
            }
            last_at = Some((-x[1], x[0]));
            Ok(())
        },
    )?;
    let (set, set_warning) = timed_poses::<6>(run_dir, "setpoint.log")?;
    let (truth, truth_warning) = timed_poses::<15>(run_dir, "truth.log")?;
    let (ratios, ratio_warning) = ratio_series(run_dir)?;
    let (w, w_warning) = read_series(
        run_dir,
        "w.log",
        logs::parse_time_and_4,
        |(t, v), _, k: &mut [Keep; 4]| {
            for (m, keep) in k.iter_mut().enumerate() {
                keep.push((*t as f64 / 1e6, v[m]));
            }
            Ok(())
        },
    )?;
    let warnings = [
        warning,
        times.warning(),
        set_warning,
        w_warning,
        truth_warning,
        ratio_warning,
    ];
    for w in warnings.into_iter().flatten() {
        eprintln!("warning: {w}");
    }
    if est[0].seen == 0 {
        anyhow::bail!(
            "{}: no estimates (x_hat.log missing, or no line of it could be read)",
            run_dir.display()
        );
    }
    let has_set = set[0].seen > 0;
    let has_truth = truth[0].seen > 0;
    let [z, roll, pitch, yaw, flown] = est;
    let [z_set, roll_set, pitch_set, yaw_set, planned] = set;
    let [z_true, roll_true, pitch_true, yaw_true, true_track] = truth;
    let pair = |name: &str, e: Keep, s: Keep, t: Keep| {
        let mut v = vec![series(name, false, e.points)];
        if has_set {
            v.push(series(&format!("{name} set point"), true, s.points));
        }
        if has_truth {
            v.push(truth_series(&format!("{name} truth"), t.points));
        }
        v
    };
    let motors = w
        .into_iter()
        .enumerate()
        .map(|(m, k)| series(&format!("motor {m}"), false, k.points))
        .collect();
    let mut track = vec![series("flown (estimate)", false, flown.points)];
    if has_set {
        track.push(series("planned (set point)", true, planned.points));
    }
    if has_truth {
        track.push(truth_series("flown (truth)", true_track.points));
    }
    let marks = marks_t
        .into_iter()
        .zip(at_m)
        .map(|(m, at)| Mark {
            at_m: at.or(last_at),
            ..m
        })
        .collect();
    let mut panels = vec![
        TimePanel {
            title: "altitude",
            y_desc: "z (m, up)",
            series: pair("z", z, z_set, z_true),
        },
        TimePanel {
            title: "roll and pitch",
            y_desc: "angle (rad)",
            series: [
                pair("roll ψ", roll, roll_set, roll_true),
                pair("pitch φ", pitch, pitch_set, pitch_true),
            ]
            .concat(),
        },
        TimePanel {
            title: "yaw",
            y_desc: "θ (rad)",
            series: pair("yaw θ", yaw, yaw_set, yaw_true),
        },
        TimePanel {
            title: "motor speeds",
            y_desc: "ω (rad/s)",
            series: motors,
        },
    ];
    panels.extend(ratios);
    Ok(Figure {
        title: format!("uquad run {}", run_dir.display()),
        panels,
        track,
        marks,
    })
}

/// The innovation test ratios of innov.log on a log scale, with the gate (a ratio of 1);
/// `None` when the run has none (the original's).
fn ratio_series(run_dir: &Path) -> anyhow::Result<(Option<TimePanel>, Option<String>)> {
    let mut span_s: Option<(f64, f64)> = None;
    let (k, warning) = read_series(
        run_dir,
        "innov.log",
        logs::InnovRecord::parse_fields,
        |r, _, k: &mut [Keep; 3]| {
            let t_s = r.t_us as f64 / 1e6;
            let (first, _) = span_s.get_or_insert((t_s, t_s));
            span_s = Some((*first, t_s));
            let g = r.ratios.gps.unwrap_or(f64::NAN);
            for (keep, ratio) in k.iter_mut().zip([r.ratios.attitude, r.ratios.altitude, g]) {
                // A ratio of 0 has no logarithm: left out, as a NaN is.
                keep.push((t_s, ratio.log10()));
            }
            Ok(())
        },
    )?;
    let Some((t0, t1)) = span_s else {
        return Ok((None, warning));
    };
    let [attitude, altitude, gps] = k;
    let mut series_ = vec![
        series("attitude", false, attitude.points),
        series("altitude", false, altitude.points),
    ];
    if !gps.points.is_empty() {
        series_.push(series("gps", false, gps.points));
    }
    series_.push(series("gate (ratio 1)", true, vec![(t0, 0.0), (t1, 0.0)]));
    let panel = TimePanel {
        title: "innovation test ratios",
        y_desc: "log10 ratio (gate at 0)",
        series: series_,
    };
    Ok((Some(panel), warning))
}

/// The marks of the run's mode.log (at most [`MAX_POINTS`]: a ground station repeating a
/// command all flight long would fill the figure), not yet placed on the track.
fn marks(run_dir: &Path) -> anyhow::Result<Vec<Mark>> {
    let mut marks = Vec::new();
    let Some(mut lines) = LogLines::open(&run_dir.join("mode.log"))? else {
        return Ok(marks);
    };
    while marks.len() < MAX_POINTS
        && let Some(line) = lines.next_raw()?
    {
        marks.extend(mark(line));
    }
    Ok(marks)
}

/// A mode change (`T mode NAME why`) or failsafe (`T failsafe KIND ACTION`) line as a mark
/// (placed on the track later); other lines are none.
fn mark(line: &str) -> Option<Mark> {
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
        at_m: None,
    })
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mode_changes_and_failsafes_are_marks_the_rest_is_not() {
        let log = "0 mode disarmed start\n1000000 in gcs arm | ok\n2000000 beat gcs\n\
                   2500000 mode armed command arm\n9000000 failsafe link-loss land\n\
                   9500000 reached 1 goto\n";
        let m: Vec<Mark> = log.lines().filter_map(mark).collect();
        let labels: Vec<&str> = m.iter().map(|m| m.label.as_str()).collect();
        assert_eq!(labels, ["disarmed", "armed", "failsafe link-loss"]);
        assert_eq!(m[2].t_s, 9.0);
        assert!(m[2].failsafe && !m[1].failsafe);
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
