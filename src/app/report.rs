//! What a run did: the counters every mode fills ([`FlySummary`]), the closing lines of its
//! err.log, the exit summary for a person, and the JSON report (`--report FILE`) as types.

use crate::app::commander_report::{CommanderReport, CommanderSummary};
use crate::core::flight::GatedCounts;
use crate::core::watchdog::Halt;
use crate::logs::{PerStream, Record};
use crate::sim::esc::EscEnd;
use crate::sim::hover::HoverStats;
use crate::sim::safety::SafetyFigures;
use crate::sim::track::TrackStats;
use crate::sim::truth::{Consistency, EstError};
use anyhow::Context;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct FlySummary {
    pub run_dir: PathBuf,
    pub frames: u64,
    pub steps: u64,
    pub discarded_bytes: u64,
    pub rejected_frames: u64,
    pub dropped_frames: u64,
    pub late_feedback: u64,
    pub ekf_errors: u64,
    /// Kalman steps that left a measurement group out of their update (innovation gate).
    pub ekf_gated: GatedCounts,
    pub gps_updates: u64,
    /// gpsd sessions opened and lost, and fixes received.
    pub gpsd_connects: u64,
    pub gpsd_disconnects: u64,
    pub gpsd_fixes: u64,
    pub saturated_commands: u64,
    pub esc_writes: u64,
    pub esc_failed_writes: u64,
    pub esc_commands: u64,
    pub esc_stop_reason: Option<String>,
    /// Records dropped per stream (a logger could not keep up, or its write failed).
    pub log_drops: PerStream<u64>,
    /// Failed writes per stream (an I/O error, a full disk).
    pub log_io_errors: PerStream<u64>,
    /// Console events a slow console missed.
    pub console_drops: u64,
    /// Log lines stderr could not take (a stalled terminal).
    pub stderr_drops: u64,
    /// The ground-station link's counters, when it was served.
    pub gcs: Option<crate::tasks::gcs::GcsReport>,
    /// The RC receiver's counters, with a radio (`rc.protocol`).
    pub rc: Option<RcCounts>,
    /// Each kill switch's stop as the receiver's reader timed it.
    pub rc_kills: Vec<crate::tasks::rc_reader::KillTimes>,
    /// Records written per stream.
    pub log_records: PerStream<u64>,
    /// Frame arrival → ESC write and its stages, µs (all 0 in lock-step runs).
    pub latency: LatencyFigures,
    pub deadline_misses: u64,
    /// Gaps between the watchdog's checks beyond 5 ms: the host stalled every flight thread.
    pub host_stalls: u64,
    /// The longest gap between the watchdog's checks (every 0.5 ms when healthy), µs; 0 in
    /// lock-step runs.
    pub watchdog_gap_max_us: u64,
    /// The watchdog's halt, if it tripped.
    pub halt: Option<Halt>,
    /// Why the run ended with an error, if it did (motors were stopped first).
    pub error: Option<String>,
    /// Modes, failsafes, refusals, takeoff and touchdown.
    pub commander: CommanderSummary,
}

pub use crate::tasks::latency::{LatencyFigures, Percentiles, StageFigures};

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HaltReport {
    pub reason: &'static str,
    /// From the event to the settled stop (the last acknowledgement, or the retries' end).
    pub latency_ms: f64,
    /// From the event to the watchdog's decision.
    pub decision_ms: f64,
    pub event_s: f64,
    pub halt_s: f64,
    /// Every ESC acknowledged zero, then disable.
    pub confirmed: bool,
    /// The ESCs that never did, as "0x6a".
    pub unconfirmed: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EscReport {
    pub commands: u64,
    pub writes: u64,
    pub failed_writes: u64,
    pub stop_reason: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ImuReport {
    pub discarded_bytes: u64,
    pub rejected_frames: u64,
    pub dropped_frames: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GpsReport {
    pub updates: u64,
    pub gpsd_connects: u64,
    pub gpsd_disconnects: u64,
    pub gpsd_fixes: u64,
}

/// The flight report (`uquad fly --report FILE`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlyReport {
    pub frames: u64,
    pub steps: u64,
    pub latency_us: Percentiles,
    /// Where the latency goes: decode → estimate, estimate → command, command → write.
    pub latency_stages_us: StageFigures,
    pub deadline_misses: u64,
    /// Gaps over 5 ms between the watchdog's checks: stalls of the host itself (they are left
    /// out of the IMU's silence; see the watchdog in docs).
    pub host_stalls: u64,
    pub watchdog_gap_max_ms: f64,
    pub log_drops: u64,
    pub watchdog_trips: u64,
    pub halt: Option<HaltReport>,
    pub run_dir: PathBuf,
    pub log_drops_by_stream: PerStream<u64>,
    pub log_io_errors_by_stream: PerStream<u64>,
    pub console_drops: u64,
    pub stderr_drops: u64,
    /// The ground-station link (null when it was not served).
    pub gcs: Option<crate::tasks::gcs::GcsReport>,
    /// The RC receiver, with a radio.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rc: Option<RcCounts>,
    pub esc: EscReport,
    pub imu: ImuReport,
    pub gps: GpsReport,
    /// Kalman steps that left the attitude, altitude or GPS measurements out of their update:
    /// outside the innovation gate (`ekf.gate_sigma`, with `ekf.gate_fusion` on).
    pub ekf_gated: GatedCounts,
    pub error: Option<String>,
    #[serde(flatten)]
    pub commander: CommanderReport,
}

/// The simulator's report: the flight report plus the hover figures and what the simulated
/// ESCs were left with.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimReport {
    #[serde(flatten)]
    pub fly: FlyReport,
    #[serde(flatten)]
    pub hover: HoverStats,
    /// With a mission: its track and durations.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub track: Option<TrackStats>,
    /// The estimate against the simulated truth (`sim::truth`); absent before a Kalman step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub est_error: Option<EstError>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ekf_consistency: Option<Consistency>,
    pub simulated_s: f64,
    pub esc_end: Vec<EscEnd>,
    /// `sim --fast`: what the true vehicle did that the safety campaign judges.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub safety: Option<SafetyFigures>,
    /// Each stop by the pilot's kill switch (`--rc`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub kill_switch: Vec<KillFigures>,
}

/// A kill switch's stop as the simulated vehicle felt it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct KillFigures {
    /// The frame that turned the switch on arrived, s.
    pub frame_s: f64,
    /// Every ESC had acknowledged its zero and its disable, s (none: never confirmed).
    pub confirmed_s: Option<f64>,
    /// The true height then, m, and the true vertical speed as the vehicle reached the
    /// ground, m/s (up positive; none: it was on the ground, or had not come down). Both
    /// none in `--realtime`, whose kills the receiver's reader times on the run's clock.
    pub height_m: Option<f64>,
    pub impact_v_m_s: Option<f64>,
}

impl KillFigures {
    fn text(&self) -> String {
        let confirmed = self.confirmed_s.map_or("never confirmed".to_string(), |c| {
            format!(
                "zero and disable confirmed {:.0} ms later",
                (c - self.frame_s) * 1e3
            )
        });
        let fall = match (self.height_m, self.impact_v_m_s) {
            (Some(h), Some(v)) => format!(", fell from {h:.2} m to the ground at {:.2} m/s", -v),
            _ => String::new(),
        };
        format!(
            "\n  kill switch at {:.2} s: {confirmed}{fall}",
            self.frame_s
        )
    }
}

/// Writes a report as pretty JSON to `path`.
pub fn write_json(report: &impl Serialize, path: &Path) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(report)?;
    std::fs::write(path, text + "\n")
        .with_context(|| format!("cannot write the report {}", path.display()))
}

pub use crate::core::rc::RcCounts;

/// err.log's line of the RC receiver's counts.
fn rc_line(rc: &RcCounts) -> String {
    format!(
        "RC receiver: {} frames, {} bytes outside frames, {} frames refused, {} inputs dropped",
        rc.frames, rc.discarded_bytes, rc.rejected_frames, rc.dropped_inputs
    )
}

impl FlySummary {
    /// A summary with nothing counted yet.
    pub fn empty(run_dir: PathBuf) -> Self {
        FlySummary {
            run_dir,
            ..FlySummary::default()
        }
    }

    pub fn log_drops_total(&self) -> u64 {
        self.log_drops.total()
    }

    /// Latency percentiles (p50, p99, max), µs.
    pub fn latency_percentiles(&self) -> Percentiles {
        self.latency.total
    }

    /// The flight report (`--report FILE`).
    pub fn report(&self) -> FlyReport {
        FlyReport {
            frames: self.frames,
            steps: self.steps,
            latency_us: self.latency_percentiles(),
            latency_stages_us: self.latency.stages,
            deadline_misses: self.deadline_misses,
            host_stalls: self.host_stalls,
            watchdog_gap_max_ms: self.watchdog_gap_max_us as f64 / 1000.0,
            log_drops: self.log_drops_total(),
            watchdog_trips: u64::from(self.halt.is_some()),
            halt: self.halt.map(|h| HaltReport {
                reason: h.trip.reason.name(),
                latency_ms: h.latency_ms(),
                decision_ms: h.decision_ms(),
                event_s: h.trip.event_us as f64 / 1e6,
                halt_s: h.halt_us as f64 / 1e6,
                confirmed: h.confirmed(),
                unconfirmed: h
                    .unconfirmed_addresses()
                    .map(|a| format!("0x{a:02x}"))
                    .collect(),
            }),
            run_dir: std::fs::canonicalize(&self.run_dir).unwrap_or_else(|_| self.run_dir.clone()),
            log_drops_by_stream: self.log_drops,
            log_io_errors_by_stream: self.log_io_errors,
            console_drops: self.console_drops,
            stderr_drops: self.stderr_drops,
            gcs: self.gcs,
            rc: self.rc,
            esc: EscReport {
                commands: self.esc_commands,
                writes: self.esc_writes,
                failed_writes: self.esc_failed_writes,
                stop_reason: self.esc_stop_reason.clone(),
            },
            imu: ImuReport {
                discarded_bytes: self.discarded_bytes,
                rejected_frames: self.rejected_frames,
                dropped_frames: self.dropped_frames,
            },
            gps: GpsReport {
                updates: self.gps_updates,
                gpsd_connects: self.gpsd_connects,
                gpsd_disconnects: self.gpsd_disconnects,
                gpsd_fixes: self.gpsd_fixes,
            },
            ekf_gated: self.ekf_gated,
            error: self.error.clone(),
            commander: self.commander.report(),
        }
    }

    /// Writes the report as JSON to `path`.
    pub fn write_report(&self, path: &Path) -> anyhow::Result<()> {
        write_json(&self.report(), path)
    }

    /// The last lines of the run's err.log, the same in every mode: the error that ended it,
    /// the records each stream dropped, the counts and how the ESCs stopped.
    pub fn closing_records(&self) -> Vec<Record> {
        let mut lines = Vec::new();
        if let Some(e) = &self.error {
            lines.push(Record::note(format!("error: {e}")));
        }
        for (s, n) in self.log_drops.iter().filter(|(_, n)| *n > 0) {
            lines.push(Record::note(format!(
                "log stream {}: {n} records dropped",
                s.name()
            )));
        }
        for (s, n) in self.log_io_errors.iter().filter(|(_, n)| *n > 0) {
            lines.push(Record::note(format!(
                "log stream {}: {n} failed writes",
                s.name()
            )));
        }
        if let Some(rc) = &self.rc {
            lines.push(Record::note(rc_line(rc)));
        }
        if self.stderr_drops > 0 {
            lines.push(Record::note(format!(
                "stderr: {} log lines dropped (it could not keep up)",
                self.stderr_drops
            )));
        }
        if self.console_drops > 0 {
            lines.push(Record::note(format!(
                "console: {} events missed by slow consoles",
                self.console_drops
            )));
        }
        if let Some(g) = &self.gcs {
            lines.push(Record::note(gcs_line(g)));
        }
        lines.push(Record::note(format!(
            "run ended: {} frames, {} steps, ESCs stopped: {}",
            self.frames,
            self.steps,
            self.esc_stop_reason.as_deref().unwrap_or("never started")
        )));
        lines
    }

    /// The exit summary, a few lines for a person.
    pub fn text(&self) -> String {
        let lat = self.latency_percentiles();
        let st = &self.latency.stages;
        let stage = |p: &Percentiles| format!("{}/{}/{}", p.p50, p.p99, p.max);
        let stages = format!(
            "stages p50/p99/max: decode -> estimate {} us, estimate -> command {} us, command -> write {} us",
            stage(&st.decode_to_estimate),
            stage(&st.estimate_to_command),
            stage(&st.command_to_write)
        );
        let drops: Vec<String> = self
            .log_drops
            .iter()
            .filter(|(_, d)| *d > 0)
            .map(|(s, d)| format!("{} {d}", s.name()))
            .collect();
        let watchdog = match self.halt {
            Some(h) => format!(
                "HALT, reason {}, {:.3} ms after the event{}",
                h.trip.reason.name(),
                h.latency_ms(),
                if h.confirmed() {
                    ""
                } else {
                    " (stop NOT confirmed by every ESC)"
                }
            ),
            None => "no trip".to_string(),
        };
        let watchdog = if self.host_stalls > 0 {
            format!(
                "{watchdog}; host stalls over 5 ms: {}, the longest {:.1} ms",
                self.host_stalls,
                self.watchdog_gap_max_us as f64 / 1000.0
            )
        } else {
            watchdog
        };
        format!(
            "run {}\n  frames {} (discarded bytes {}, rejected frames {}, dropped {}), Kalman steps {}, GPS samples fused {}\n  \
             outside the innovation gate, left out: attitude {}, altitude {}, GPS {}\n  \
             ESC: {} commands, {} writes, {} failed; stopped: {}\n  \
             latency frame -> ESC write: p50 {} us, p99 {} us, max {} us; deadline misses {}\n  \
             {stages}\n  \
             watchdog: {watchdog}\n  \
             log drops: {}\n  {}{}",
            self.run_dir.display(),
            self.frames,
            self.discarded_bytes,
            self.rejected_frames,
            self.dropped_frames,
            self.steps,
            self.gps_updates,
            self.ekf_gated.attitude,
            self.ekf_gated.altitude,
            self.ekf_gated.gps,
            self.esc_commands,
            self.esc_writes,
            self.esc_failed_writes,
            self.esc_stop_reason.as_deref().unwrap_or("never started"),
            lat.p50,
            lat.p99,
            lat.max,
            self.deadline_misses,
            if drops.is_empty() {
                "none".to_string()
            } else {
                drops.join(", ")
            },
            self.commander.text(),
            self.error
                .as_ref()
                .map(|e| format!("\n  error: {e}"))
                .unwrap_or_default()
        )
    }
}

/// What a simulation did.
#[derive(Debug, Clone)]
pub struct SimSummary {
    pub fly: FlySummary,
    pub hover: HoverStats,
    pub track: Option<TrackStats>,
    /// The estimate against the truth, and the filter's consistency.
    pub truth: Option<(EstError, Consistency)>,
    pub simulated_s: f64,
    pub esc_end: Vec<EscEnd>,
    /// `sim --fast`: what the true vehicle did that the safety campaign judges.
    pub safety: Option<SafetyFigures>,
    pub kill_switch: Vec<KillFigures>,
}

impl SimSummary {
    /// The flight report plus the hover figures.
    pub fn report(&self) -> SimReport {
        SimReport {
            fly: self.fly.report(),
            hover: self.hover,
            track: self.track,
            est_error: self.truth.map(|t| t.0),
            ekf_consistency: self.truth.map(|t| t.1),
            simulated_s: self.simulated_s,
            esc_end: self.esc_end.clone(),
            safety: self.safety.clone(),
            kill_switch: self.kill_switch.clone(),
        }
    }

    pub fn text(&self) -> String {
        let h = &self.hover;
        let hover = if h.samples == 0 {
            "no hover window (it starts sim.settle_s after the flight ramp)".to_string()
        } else {
            format!(
                "hover from {:.1} s: altitude RMS {:.3} m (largest error {:.3} m, {:.3} m in 3-D), roll RMS {:.4} rad, pitch RMS {:.4} rad",
                h.window_start_s,
                h.alt_rms_m,
                h.alt_max_err_m,
                h.pos_max_err_m,
                h.roll_rms_rad,
                h.pitch_rms_rad
            )
        };
        let track = self
            .track
            .map(|t| format!("\n  {}", t.text()))
            .unwrap_or_default();
        let truth = self
            .truth
            .map(|(e, c)| format!("\n  {}", crate::sim::truth::text(&e, &c)))
            .unwrap_or_default();
        let kills: String = self.kill_switch.iter().map(KillFigures::text).collect();
        format!(
            "{}{track}{truth}{kills}\n  simulated {:.1} s; {hover}",
            self.fly.text(),
            self.simulated_s
        )
    }
}

/// err.log's line of the ground-station link's counts.
fn gcs_line(g: &crate::tasks::gcs::GcsReport) -> String {
    format!(
        "ground-station link: {} frames in, {} out ({} dropped); {} commands ({} refused); \
         {} GCS heartbeats; {} parameter sets; dropped over the rate {}; noise: {} bad CRC, {} \
         cut short, {} unknown, {} malformed, {} bytes outside frames; {} receive errors, {} \
         inputs the flight's queue refused, {} notices missed; CPU {:.1} ms ({:.3} % of a core)",
        g.counts.rx.frames,
        g.counts.tx_frames,
        g.counts.tx_drops,
        g.counts.commands,
        g.counts.commands_refused,
        g.counts.gcs_heartbeats,
        g.counts.param_sets,
        g.counts.flood_drops,
        g.counts.rx.bad_crc,
        g.counts.rx.truncated,
        g.counts.rx.unknown,
        g.counts.rx.malformed,
        g.counts.rx.garbage_bytes,
        g.counts.rx_errors,
        g.counts.input_drops,
        g.notices_missed,
        g.cpu_ms,
        g.cpu_pct
    )
}
