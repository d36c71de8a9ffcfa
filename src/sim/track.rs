//! A mission's track in a simulation: the true vehicle's horizontal distance from the path
//! the commander flies (the segment of its set point), one sample per IMU period in `mission`
//! mode, and the mission's flown and planned durations.

use crate::core::commander::{Guidance, MissionFigures, Mode};
use serde::Serialize;

/// The report's mission figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct TrackStats {
    pub track_samples: u64,
    /// RMS and largest horizontal distance from the planned path, m.
    pub track_rms_m: f64,
    pub track_max_m: f64,
    /// RMS horizontal distance of the estimated position from the planned path, m: what the
    /// control leaves; the rest of `track_rms_m` is the estimate's error (the receiver's).
    pub track_est_rms_m: f64,
    /// From the first to the last step in `mission` mode, s.
    pub mission_s: f64,
    /// The planned duration of the segments flown, s.
    pub mission_ideal_s: f64,
}

#[derive(Debug, Clone, Copy, Default)]
pub struct TrackTrace {
    n: u64,
    sum_sq_m2: f64,
    est_sum_sq_m2: f64,
    max_m: f64,
}

impl TrackTrace {
    /// One IMU period: the commander's guidance, the true and the estimated position.
    pub fn sample(&mut self, g: &Guidance, true_pos_m: [f64; 3], est_pos_m: [f64; 3]) {
        let (Mode::Mission, Some((_, segment, _))) = (g.mode, g.path) else {
            return;
        };
        let d = segment.distance_m(true_pos_m);
        self.n += 1;
        self.sum_sq_m2 += d * d;
        self.est_sum_sq_m2 += segment.distance_m(est_pos_m).powi(2);
        self.max_m = self.max_m.max(d);
    }

    /// The figures, once a mission flew.
    pub fn stats(&self, f: MissionFigures) -> Option<TrackStats> {
        let (start, end) = (f.started_us?, f.ended_us?);
        let rms = |sum: f64| {
            if self.n > 0 {
                (sum / self.n as f64).sqrt()
            } else {
                0.0
            }
        };
        Some(TrackStats {
            track_samples: self.n,
            track_rms_m: rms(self.sum_sq_m2),
            track_est_rms_m: rms(self.est_sum_sq_m2),
            track_max_m: self.max_m,
            mission_s: (end - start) as f64 / 1e6,
            mission_ideal_s: f.ideal_s,
        })
    }
}

impl TrackStats {
    pub fn text(&self) -> String {
        format!(
            "mission {:.1} s (planned {:.1} s); track from the planned path: RMS {:.3} m, largest {:.3} m (the estimate's: RMS {:.3} m)",
            self.mission_s,
            self.mission_ideal_s,
            self.track_rms_m,
            self.track_max_m,
            self.track_est_rms_m
        )
    }
}
