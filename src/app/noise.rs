//! `uquad noise`: each sensor's noise from a still segment of a run's raw IMU log — the Allan
//! deviation's terms for the gyros and accelerometers (`core::allan`), the standard deviation
//! of the barometer's altitude and of the angles the IMU derives (roll and pitch from the
//! accelerometer, yaw from the magnetometer) — and the filter noise they imply.
//!
//! The frames are converted with the run's calibration (or `--calib`) as the estimator
//! converts them, without the gyro's null (a constant: the Allan deviation ignores it).

use crate::config::bounded::{FileKind, read_text};
use crate::core::allan::{self, NoiseTerms};
use crate::core::imu::calib::{Calibration, NullReference, P0_DEFAULT_PA};
use crate::logs::ImuRawRecord;
use anyhow::{Context, bail};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// What to read.
#[derive(Debug, Clone)]
pub struct NoiseOptions {
    pub run_dir: PathBuf,
    /// The segment, s of the log's first column (t_main); the whole log without them.
    pub from_s: Option<f64>,
    pub to_s: Option<f64>,
    /// The calibration; default RUN_DIR/imu_calib.txt.
    pub calib: Option<PathBuf>,
}

/// Fewer frames say nothing about the noise.
pub const MIN_FRAMES: usize = 100;
/// At most this many frames are analysed (about 2.8 hours at 100 Hz; 90 MB in memory).
pub const MAX_FRAMES: usize = 1_000_000;

/// One axis of a gyro or accelerometer.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisNoise {
    pub mean: f64,
    /// The samples' standard deviation (white noise and everything slower).
    pub sd: f64,
    /// The fitted terms (`core::allan`); null when nothing could be fitted.
    pub white_sd: Option<f64>,
    pub white_density: Option<f64>,
    pub bias_instability: Option<f64>,
    pub random_walk: Option<f64>,
    /// The Allan deviation the terms were fitted to: [τ (s), deviation], about ten points a
    /// decade (for a reader who plots it).
    pub allan: Vec<[f64; 2]>,
}

/// A derived signal's spread.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    pub mean: f64,
    pub sd: f64,
}

/// The command's report (`--report`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseReport {
    pub run_dir: PathBuf,
    pub frames: usize,
    pub from_s: f64,
    pub to_s: f64,
    /// The frame period, s (the median of the firmware's periods).
    pub tau0_s: f64,
    /// m/s², rad/s; x, y, z.
    pub acc: [AxisNoise; 3],
    pub gyro: [AxisNoise; 3],
    /// The barometer's altitude, m, and pressure, Pa.
    pub baro_alt_m: Spread,
    pub baro_pa: Spread,
    /// The IMU's angles ψ (roll), φ (pitch), θ (yaw), rad.
    pub euler_rad: [Spread; 3],
    /// The filter noise implied: the IMU rows' R (ψ φ θ, ax ay az, ωx ωy ωz, altitude) and
    /// the process noise per step of the accelerometer biases (bax bay baz).
    pub r_imu: [f64; 10],
    pub q_acc_bias: [f64; 3],
    /// What the reader should know (a short or moving segment).
    pub warnings: Vec<String>,
}

/// The converted samples of the segment, one vector per signal.
#[derive(Default)]
struct Series {
    acc: [Vec<f64>; 3],
    gyro: [Vec<f64>; 3],
    alt_m: Vec<f64>,
    pres_pa: Vec<f64>,
    euler: [Vec<f64>; 3],
    periods_us: Vec<u32>,
    /// Frames whose barometer gave no altitude (a failed reading): left out of its spread.
    baro_missing: usize,
    first_s: f64,
    last_s: f64,
}

pub fn run(opts: &NoiseOptions) -> anyhow::Result<NoiseReport> {
    let calib_path = calib_path(opts);
    let text = read_text(&calib_path, FileKind::Calibration).map_err(|e| {
        anyhow::anyhow!(
            "{}: {e} (the frames are converted with the run's calibration; give one with --calib)",
            calib_path.display()
        )
    })?;
    let calib = Calibration::parse(&text)
        .with_context(|| format!("{}: not a calibration", calib_path.display()))?;
    let series = read_segment(opts, &calib)?;
    Ok(analyse(opts, series))
}

fn read_segment(opts: &NoiseOptions, calib: &Calibration) -> anyhow::Result<Series> {
    let path = opts.run_dir.join("imu_raw.log");
    let Some(mut lines) = crate::app::log_lines::LogLines::open(&path)? else {
        bail!(
            "{}: no such file (a run folder has imu_raw.log)",
            path.display()
        );
    };
    let null = NullReference {
        gyro_null_rad_s: [0.0; 3],
        p0_pa: P0_DEFAULT_PA,
    };
    let (from, to) = (
        opts.from_s.unwrap_or(f64::MIN),
        opts.to_s.unwrap_or(f64::MAX),
    );
    let mut s = Series::default();
    let mut yaw_prev: Option<f64> = None;
    while let Some(r) = lines.next(ImuRawRecord::parse_fields)? {
        let t_s = r.t_main_us as f64 / 1e6;
        if t_s > to {
            // A run's frames are in time order (replay refuses a log whose times go back).
            break;
        }
        if t_s < from {
            continue;
        }
        if s.periods_us.len() >= MAX_FRAMES {
            bail!(
                "{}: the segment holds more than {MAX_FRAMES} frames; narrow it with --from and --to",
                path.display()
            );
        }
        if s.periods_us.is_empty() {
            s.first_s = t_s;
        }
        s.last_s = t_s;
        let x = calib.convert(&r.frame, &null);
        for i in 0..3 {
            s.acc[i].push(x.acc_m_s2[i]);
            s.gyro[i].push(x.gyro_rad_s[i]);
        }
        s.euler[0].push(x.euler_rad[0]);
        s.euler[1].push(x.euler_rad[1]);
        // Yaw unwrapped against the previous sample: a heading near ±π must not read as 2π.
        let yaw = crate::core::imu::calib::unwrap_theta(x.euler_rad[2], yaw_prev.unwrap_or(0.0));
        yaw_prev = Some(yaw);
        s.euler[2].push(yaw);
        if x.alt_m.is_finite() {
            s.alt_m.push(x.alt_m);
            s.pres_pa.push(f64::from(r.frame.pres_pa));
        } else {
            s.baro_missing += 1;
        }
        s.periods_us.push(r.frame.t_us);
    }
    if let Some(w) = lines.warning() {
        eprintln!("{w}");
    }
    if s.periods_us.len() < MIN_FRAMES {
        bail!(
            "{}: {} frames between {} and {} s; at least {MIN_FRAMES} are needed",
            path.display(),
            s.periods_us.len(),
            fmt_bound(opts.from_s),
            fmt_bound(opts.to_s)
        );
    }
    Ok(s)
}

fn fmt_bound(v: Option<f64>) -> String {
    v.map_or_else(|| "the log's end".to_string(), |v| format!("{v}"))
}

/// The median firmware period, s (10 ms when the log has none).
fn frame_period_s(periods_us: &mut [u32]) -> f64 {
    periods_us.sort_unstable();
    match periods_us.get(periods_us.len() / 2) {
        Some(&p) if p > 0 => f64::from(p) / 1e6,
        _ => 0.01,
    }
}

fn axis(samples: &[f64], tau0_s: f64) -> AxisNoise {
    let (mean, sd) = allan::mean_sd(samples).unwrap_or((f64::NAN, f64::NAN));
    let curve = allan::allan_deviation(samples, tau0_s);
    let terms: Option<NoiseTerms> = allan::fit(&curve, tau0_s);
    AxisNoise {
        mean,
        sd,
        white_sd: terms.map(|t| t.white_sd),
        white_density: terms.map(|t| t.white_density),
        bias_instability: terms.map(|t| t.bias_instability),
        random_walk: terms.map(|t| t.random_walk),
        allan: curve.iter().map(|p| [p.tau_s, p.adev]).collect(),
    }
}

fn spread(samples: &[f64]) -> Spread {
    let (mean, sd) = allan::mean_sd(samples).unwrap_or((f64::NAN, f64::NAN));
    Spread { mean, sd }
}

fn analyse(opts: &NoiseOptions, mut s: Series) -> NoiseReport {
    let tau0_s = frame_period_s(&mut s.periods_us);
    let acc = std::array::from_fn(|i| axis(&s.acc[i], tau0_s));
    let gyro: [AxisNoise; 3] = std::array::from_fn(|i| axis(&s.gyro[i], tau0_s));
    let euler_rad = std::array::from_fn(|i| spread(&s.euler[i]));
    let baro_alt_m = spread(&s.alt_m);
    let white = |a: &AxisNoise| a.white_sd.unwrap_or(a.sd);
    let mut r_imu = [0.0; 10];
    for i in 0..3 {
        r_imu[i] = euler_rad[i].sd.powi(2);
        r_imu[3 + i] = white(&acc[i]).powi(2);
        r_imu[6 + i] = white(&gyro[i]).powi(2);
    }
    r_imu[9] = baro_alt_m.sd.powi(2);
    let q_acc_bias = std::array::from_fn(|i| acc[i].random_walk.unwrap_or(0.0).powi(2) * tau0_s);
    let mut report = NoiseReport {
        run_dir: opts.run_dir.clone(),
        frames: s.periods_us.len(),
        from_s: s.first_s,
        to_s: s.last_s,
        tau0_s,
        acc,
        gyro,
        baro_alt_m,
        baro_pa: spread(&s.pres_pa),
        euler_rad,
        r_imu,
        q_acc_bias,
        warnings: Vec::new(),
    };
    report.warnings = warnings(&report);
    if s.baro_missing > 0 {
        report.warnings.push(format!(
            "{} frames gave no barometer altitude (a failed reading): left out of its spread",
            s.baro_missing
        ));
    }
    report
}

/// A segment too short for the slow terms, or one that moved.
fn warnings(r: &NoiseReport) -> Vec<String> {
    let mut w = Vec::new();
    let span_s = r.to_s - r.from_s;
    if span_s < 100.0 {
        w.push(format!(
            "the segment lasts {span_s:.1} s: the bias instability and random walk need minutes \
             of stillness (their figures here are bounds at best)"
        ));
    }
    let g_m_s2 = r.acc.iter().map(|a| a.mean * a.mean).sum::<f64>().sqrt();
    let turning = r.gyro.iter().any(|g| g.sd > 0.05);
    if (g_m_s2 - crate::core::model::GRAVITY_M_S2).abs() > 0.5 || turning {
        w.push(format!(
            "the segment moved or vibrated (mean acceleration {g_m_s2:.2} m/s², gyro spread \
             up to {:.3} rad/s): the figures include motion",
            r.gyro.iter().map(|g| g.sd).fold(0.0, f64::max)
        ));
    }
    w
}

impl NoiseReport {
    /// The printed table.
    pub fn text(&self) -> String {
        let mut out = format!(
            "{}: {} frames from {:.2} to {:.2} s, one every {:.4} s\n",
            self.run_dir.display(),
            self.frames,
            self.from_s,
            self.to_s,
            self.tau0_s
        );
        out.push_str(
            "sensor   axis   mean        sd          white/frame  density (·√s)  bias instab.  random walk (/√s)\n",
        );
        let opt = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.3e}"));
        for (name, unit, axes) in [("acc", "m/s²", &self.acc), ("gyro", "rad/s", &self.gyro)] {
            for (a, xyz) in axes.iter().zip(["x", "y", "z"]) {
                out.push_str(&format!(
                    "{name:<8} {xyz:<6} {:<11.4e} {:<11.4e} {:<12} {:<14} {:<13} {}   [{unit}]\n",
                    a.mean,
                    a.sd,
                    opt(a.white_sd),
                    opt(a.white_density),
                    opt(a.bias_instability),
                    opt(a.random_walk)
                ));
            }
        }
        let e = &self.euler_rad;
        out.push_str(&format!(
            "baro     alt    sd {:.4} m ({:.3} Pa)\nangles   sd     roll {:.4e}, pitch {:.4e}, yaw {:.4e} rad\n",
            self.baro_alt_m.sd, self.baro_pa.sd, e[0].sd, e[1].sd, e[2].sd
        ));
        let list = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:.3e}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        out.push_str(&format!(
            "implied ekf.r_imu (psi phi theta, ax ay az, wx wy wz, baro): [{}]\n",
            list(&self.r_imu)
        ));
        out.push_str(
            "  (the sensors' own noise at rest: a floor, on their own scale; the profiles' values \
             are the 2012 flights', on another — do not paste one into the other)\n",
        );
        out.push_str(&format!(
            "implied ekf.q for bax bay baz (random walk² × frame period): [{}]\n",
            list(&self.q_acc_bias)
        ));
        for w in &self.warnings {
            out.push_str(&format!("warning: {w}\n"));
        }
        out
    }
}

/// The path a run's calibration is read from.
pub fn calib_path(opts: &NoiseOptions) -> PathBuf {
    opts.calib
        .clone()
        .unwrap_or_else(|| Path::new(&opts.run_dir).join("imu_calib.txt"))
}
