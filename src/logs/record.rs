//! The log streams of a run and how each record is written: the flight's records (spec 1.6 and
//! 8.6 layouts) plus the run's own lines, one enum of streams instead of positions.

use super::format::{self, ImuRawRecord, InnovRecord, KalmanInRecord};
use crate::core::flight::FlightRecord;
use crate::core::watchdog::Halt;
use serde::Serialize;
use std::ops::{Index, IndexMut};

/// The streams of a run, one `<name>.log` file each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stream {
    ImuRaw,
    KalmanIn,
    XHat,
    Innov,
    W,
    Int,
    Gps,
    Err,
    Mode,
    Setpoint,
}

impl Stream {
    /// How many streams there are.
    pub const COUNT: usize = 10;

    pub const ALL: [Stream; Stream::COUNT] = [
        Stream::ImuRaw,
        Stream::KalmanIn,
        Stream::XHat,
        Stream::Innov,
        Stream::W,
        Stream::Int,
        Stream::Gps,
        Stream::Err,
        Stream::Mode,
        Stream::Setpoint,
    ];

    /// The file's name without `.log`, and the name reports use.
    pub fn name(self) -> &'static str {
        match self {
            Stream::ImuRaw => "imu_raw",
            Stream::KalmanIn => "kalman_in",
            Stream::XHat => "x_hat",
            Stream::Innov => "innov",
            Stream::W => "w",
            Stream::Int => "int",
            Stream::Gps => "gps",
            Stream::Err => "err",
            Stream::Mode => "mode",
            Stream::Setpoint => "setpoint",
        }
    }

    pub fn from_name(name: &str) -> Option<Stream> {
        Stream::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// One value per stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PerStream<T>(pub [T; Stream::COUNT]);

impl<T> Index<Stream> for PerStream<T> {
    type Output = T;
    fn index(&self, s: Stream) -> &T {
        &self.0[s as usize]
    }
}

impl<T> IndexMut<Stream> for PerStream<T> {
    fn index_mut(&mut self, s: Stream) -> &mut T {
        &mut self.0[s as usize]
    }
}

impl<T: Copy> PerStream<T> {
    /// (stream, value) pairs in stream order.
    pub fn iter(&self) -> impl Iterator<Item = (Stream, T)> + '_ {
        Stream::ALL.into_iter().map(|s| (s, self[s]))
    }
}

impl PerStream<u64> {
    pub fn total(&self) -> u64 {
        self.0.iter().sum()
    }
}

/// Reports name each stream: `{"imu_raw": 0, ...}`.
impl<T: Serialize + Copy> Serialize for PerStream<T> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.iter().map(|(k, v)| (k.name(), v)))
    }
}

/// One record of one stream.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    Flight(FlightRecord),
    /// The header of a gps.log holding gpsd fixes, naming its run.
    GpsHeader(String),
    /// mode.log's first line: the run's id (also in its config.toml and gps.log headers), so
    /// that a replay refuses another run's mode.log.
    RunId(String),
}

impl Record {
    /// A line of free text (err.log).
    pub fn note(line: impl Into<String>) -> Record {
        Record::Flight(FlightRecord::Note(line.into()))
    }

    /// The record's stream.
    pub fn stream(&self) -> Stream {
        match self {
            Record::GpsHeader(_) => Stream::Gps,
            Record::RunId(_) => Stream::Mode,
            Record::Flight(r) => match r {
                FlightRecord::Frame { .. } => Stream::ImuRaw,
                FlightRecord::KalmanIn { .. } => Stream::KalmanIn,
                FlightRecord::XHat(_) => Stream::XHat,
                FlightRecord::Innov { .. } => Stream::Innov,
                FlightRecord::Command { .. } => Stream::W,
                FlightRecord::Setpoint { .. } => Stream::Setpoint,
                FlightRecord::Int { .. } => Stream::Int,
                FlightRecord::FakeGps(_) | FlightRecord::GpsFix { .. } => Stream::Gps,
                FlightRecord::Halt(_) | FlightRecord::Note(_) => Stream::Err,
                FlightRecord::Commander(_) | FlightRecord::Operator { .. } => Stream::Mode,
            },
        }
    }

    /// Appends the record in its stream's format.
    pub fn write(&self, out: &mut String) {
        let r = match self {
            Record::GpsHeader(run) => {
                out.push_str(format::UQUAD_GPS_HEADER);
                out.push_str("; run ");
                out.push_str(run);
                out.push('\n');
                return;
            }
            Record::RunId(run) => return crate::logs::mode_log::write_run(out, run),
            Record::Flight(r) => r,
        };
        match r {
            FlightRecord::Frame { times, frame } => ImuRawRecord {
                t_main_us: times.t_main_us,
                t_frame_us: times.t_frame_us,
                frame: *frame,
            }
            .write(out),
            FlightRecord::KalmanIn {
                t_us,
                dt_us,
                sample,
            } => KalmanInRecord::from_sample(*t_us, *dt_us, sample).write(out),
            FlightRecord::XHat(x) => format::write_values_row(out, None, x),
            FlightRecord::Innov {
                t_us,
                ratios,
                gated,
            } => InnovRecord {
                t_us: *t_us,
                ratios: *ratios,
                gated: *gated,
            }
            .write(out),
            FlightRecord::Command { t_us, w_rad_s } => {
                format::write_values_row(out, Some(*t_us), w_rad_s)
            }
            FlightRecord::Int { t_us, x_int, n_int } => {
                format::write_values_row(out, Some(*t_us), &x_int[..*n_int])
            }
            FlightRecord::Setpoint { t_us, sp } => format::write_values_row(out, Some(*t_us), sp),
            FlightRecord::FakeGps(t_us) => {
                out.push_str(&format::fmt_time_us(*t_us));
                out.push_str("\t\n");
            }
            FlightRecord::GpsFix { t_us, fix } => format::write_gps_fix(
                out,
                *t_us,
                fix.stamp_us,
                fix.fix.mode,
                fix.sample.pos_m(),
                fix.sample.vel_m_s,
                fix.fix.lat_deg,
                fix.fix.lon_deg,
            ),
            FlightRecord::Halt(h) => {
                out.push_str(&halt_line(h));
                out.push('\n');
            }
            FlightRecord::Note(s) => {
                out.push_str(s);
                out.push('\n');
            }
            FlightRecord::Commander(e) => super::mode_log::write_event(out, e),
            FlightRecord::Operator {
                t_us,
                input,
                verdict,
            } => super::mode_log::write_input(out, *t_us, input, verdict.as_ref()),
        }
    }
}

/// The err.log line of a watchdog halt: the same words in every mode.
pub fn halt_line(h: &Halt) -> String {
    let stop = if h.confirmed() {
        "stop confirmed by every ESC".to_string()
    } else {
        let addrs: Vec<String> = h
            .unconfirmed_addresses()
            .map(|a| format!("0x{a:02x}"))
            .collect();
        format!("stop NOT confirmed by {}", addrs.join(", "))
    };
    format!(
        "watchdog: halt, reason {}; event at {} s, halt at {} s ({:.3} ms later); {stop}",
        h.trip.reason.name(),
        format::fmt_time_us(h.trip.event_us),
        format::fmt_time_us(h.halt_us),
        h.latency_ms()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_index_and_name_in_file_order() {
        let mut n = PerStream::<u64>::default();
        n[Stream::XHat] = 3;
        n[Stream::Err] = 1;
        n[Stream::Innov] = 2;
        assert_eq!(n.0, [0, 0, 3, 2, 0, 0, 0, 1, 0, 0]);
        assert_eq!(n.total(), 6);
        for s in Stream::ALL {
            assert_eq!(Stream::from_name(s.name()), Some(s));
        }
        let json = serde_json::to_string(&n).unwrap();
        assert_eq!(
            json,
            r#"{"imu_raw":0,"kalman_in":0,"x_hat":3,"innov":2,"w":0,"int":0,"gps":0,"err":1,"mode":0,"setpoint":0}"#
        );
    }
}
