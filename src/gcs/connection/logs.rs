//! Log download, the way ground stations fetch a vehicle's logs (QGroundControl's Log
//! Download, MAVProxy's `log`): LOG_REQUEST_LIST is answered with a LOG_ENTRY per log,
//! LOG_REQUEST_DATA with LOG_DATA packets of 90 bytes from the offset asked, LOG_REQUEST_END
//! stops. The logs are the run folders' ULog exports (`uquad export --format ulog`), the
//! newest last; listing and reading them is the owner's file work ([`Effect::ListLogs`],
//! [`Effect::OpenLog`]), off the link's task. A log being sent is held in memory and sent a
//! budget of packets at a time ([`Connection::poll_download`]): the owner gives the room its
//! link has (a UDP socket a fixed share, a radio what its paced queue can take beside the
//! telemetry), so telemetry and commands keep flowing during a download.

use super::{Connection, Effect};
use mavlink::dialects::common::*;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Bytes of one LOG_DATA packet.
pub const CHUNK: usize = 90;

/// A download's packets go out at most this often (and the timer wakes for them).
pub const TICK: Duration = Duration::from_millis(20);

/// A download stops once no ground station's heartbeat was heard for this long.
pub const QUIET: Duration = Duration::from_secs(5);

/// One log as the owner lists it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogEntry {
    /// 1-based, oldest first.
    pub id: u16,
    pub size: u32,
    /// When its run began, s since 1970 (0: unknown).
    pub time_utc: u32,
}

/// The log download's state.
#[derive(Debug, Default)]
pub(super) struct Downloads {
    /// As last listed.
    entries: Vec<LogEntry>,
    /// A list asked for (its first and last id), waiting for the owner.
    listing: Option<(u16, u16)>,
    /// A read asked for (id, offset, bytes) while its log is being opened, and the log the
    /// owner is opening (one at a time).
    opening: Option<(u16, u32, u32)>,
    open_asked: Option<u16>,
    /// The log being sent, whole, and what is left of the read: next offset, end.
    open: Option<(u16, Arc<[u8]>)>,
    sending: Option<(u32, u32)>,
    next_due: Option<Instant>,
    /// Log bytes sent in this run.
    pub sent_bytes: u64,
}

impl Downloads {
    /// When the next packets are due, while a read is being sent.
    pub(super) fn next_due(&self) -> Option<Instant> {
        self.sending.and(self.next_due)
    }
}

impl Connection {
    /// LOG_REQUEST_LIST: the owner lists the logs afresh (the running one grows); one list
    /// at a time (a repeat while one is made is answered by it). Disarmed only: the exports
    /// are file work, and a download's packets take the link.
    pub(super) fn on_log_list(&mut self, start: u16, end: u16) {
        if !self.disarmed() {
            let text = "logs: downloaded only while disarmed";
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, text);
        }
        if self.downloads.listing.replace((start, end)).is_none() {
            self.effects.push_back(Effect::ListLogs);
        }
    }

    /// Whether a read is being sent or waited for.
    pub(super) fn downloading(&self) -> bool {
        self.downloads.sending.is_some() || self.downloads.opening.is_some()
    }

    /// The owner's list (from [`Effect::ListLogs`]): a LOG_ENTRY for each log asked for; none
    /// at all is told as one entry with no logs.
    pub fn handle_log_list(&mut self, now: Instant, listed: Result<Vec<LogEntry>, String>) {
        self.tell_time(now);
        let Some((start, end)) = self.downloads.listing.take() else {
            return;
        };
        let entries = match listed {
            Ok(e) => e,
            Err(why) => {
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &format!("logs: {why}"));
                Vec::new()
            }
        };
        let last = entries.last().map_or(0, |e| e.id);
        let n = entries.len() as u16;
        let asked: Vec<LogEntry> = entries
            .iter()
            .filter(|e| e.id >= start && e.id <= end)
            .copied()
            .collect();
        if asked.is_empty() {
            self.send(&entry_message(None, n, last));
        }
        for e in &asked {
            self.send(&entry_message(Some(e), n, last));
        }
        self.downloads.entries = entries;
        // A new list may number the logs anew: what was open is let go.
        self.on_log_end();
    }

    /// LOG_REQUEST_DATA: `count` bytes of log `id` from `ofs` (the rest of it, when more).
    pub(super) fn on_log_data_request(&mut self, now: Instant, id: u16, ofs: u32, count: u32) {
        if !self.disarmed() {
            let text = "logs: downloaded only while disarmed";
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, text);
        }
        if !self.downloads.entries.iter().any(|e| e.id == id) {
            let text = format!("logs: no log {id} (ask for the list first)");
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, &text);
        }
        match &self.downloads.open {
            Some((open, _)) if *open == id => self.start_sending(now, ofs, count),
            _ => {
                // One log opened at a time: a newer request waits for it.
                self.downloads.opening = Some((id, ofs, count));
                self.ask_open(id);
            }
        }
    }

    fn ask_open(&mut self, id: u16) {
        if self.downloads.open_asked.is_none() {
            self.downloads.open_asked = Some(id);
            self.effects.push_back(Effect::OpenLog { id });
        }
    }

    /// The owner's bytes of log `id` (from [`Effect::OpenLog`]), or why it could not read it.
    pub fn handle_log_opened(&mut self, now: Instant, id: u16, bytes: Result<Arc<[u8]>, String>) {
        self.tell_time(now);
        if self.downloads.open_asked != Some(id) {
            return;
        }
        self.downloads.open_asked = None;
        let Some((asked, ofs, count)) = self.downloads.opening else {
            return;
        };
        if asked != id {
            // A newer request, for another log: that one is opened now.
            return self.ask_open(asked);
        }
        self.downloads.opening = None;
        match bytes {
            Ok(b) => {
                self.downloads.open = Some((id, b));
                self.start_sending(now, ofs, count);
            }
            Err(why) => {
                let text = format!("logs: log {id}: {why}");
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &text);
            }
        }
    }

    /// LOG_REQUEST_END: the read stops and the log's bytes are let go.
    pub(super) fn on_log_end(&mut self) {
        self.downloads.sending = None;
        self.downloads.open = None;
        self.downloads.opening = None;
    }

    /// Armed: a download stops (the link is the flight's).
    pub(super) fn stop_download_when_armed(&mut self) {
        if self.downloading() && !self.disarmed() {
            self.on_log_end();
            let text = "logs: download stopped, armed";
            self.text(MavSeverity::MAV_SEVERITY_WARNING, text);
        }
    }

    fn start_sending(&mut self, now: Instant, ofs: u32, count: u32) {
        let size = self
            .downloads
            .open
            .as_ref()
            .map_or(0, |(_, b)| b.len() as u32);
        let end = ofs.saturating_add(count).min(size);
        self.downloads.sending = Some((ofs.min(size), end));
        self.downloads.next_due = Some(now);
        // A read past the end is answered with one empty packet at that offset.
        if ofs >= size {
            self.downloads.sending = Some((ofs, ofs));
        }
    }

    /// Up to `room` LOG_DATA packets of the read being sent, when they are due: the owner's
    /// room on its link (UDP: a fixed share; a radio: its queue's spare beyond the
    /// telemetry's). Call it after [`Connection::handle_timeout`].
    pub fn poll_download(&mut self, now: Instant, room: usize) {
        if self.downloads.next_due().is_none_or(|due| now < due) || room == 0 {
            return;
        }
        // Nobody is listening any more: the download stops, its bytes let go.
        let heard = self
            .last_beat
            .is_some_and(|t| now.saturating_duration_since(t) < QUIET);
        if !heard {
            self.on_log_end();
            let text = "logs: download stopped, the ground station is silent";
            return self.text(MavSeverity::MAV_SEVERITY_WARNING, text);
        }
        self.downloads.next_due = Some(now + TICK);
        for _ in 0..room {
            let Some((next, end)) = self.downloads.sending else {
                return;
            };
            let Some((id, bytes)) = self.downloads.open.clone() else {
                return;
            };
            let n = (end - next).min(CHUNK as u32) as usize;
            let mut data = [0u8; CHUNK];
            let from = next as usize;
            if let Some(src) = bytes.get(from..from + n) {
                data[..n].copy_from_slice(src);
            }
            self.send(&MavMessage::LOG_DATA(LOG_DATA_DATA {
                ofs: next,
                id,
                count: n as u8,
                data,
            }));
            self.downloads.sent_bytes += n as u64;
            let next = next + n as u32;
            // The read ends after its last packet (an empty one when nothing was left).
            self.downloads.sending = (next < end).then_some((next, end));
        }
    }
}

fn entry_message(e: Option<&LogEntry>, num_logs: u16, last_log_num: u16) -> MavMessage {
    MavMessage::LOG_ENTRY(LOG_ENTRY_DATA {
        time_utc: e.map_or(0, |e| e.time_utc),
        size: e.map_or(0, |e| e.size),
        id: e.map_or(0, |e| e.id),
        num_logs,
        last_log_num,
    })
}
