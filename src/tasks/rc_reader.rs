//! RC receiver reader: the pilot's radio from a UART (SBUS or CRSF).
//!
//! In: the receiver's bytes (tokio-serial; a pty in tests). Out: the operator inputs its frames
//! make (`core::rc::link`) into the flight's operator queue, and — before anything else — a
//! halt named `kill` to the ESC writer's mailbox for every frame with the kill switch on: the
//! pilot's kill reaches the motors without waiting for a control step. Counters, the radio as
//! a watcher sees it, and each kill timed from its frame to the confirmed stop, in
//! [`RcStats`]. Rate: as the receiver sends (SBUS every 7 or 14 ms, CRSF up to 500 Hz).
//! Ends: on cancel, or when the device fails (logged; the commander's `rc-loss` failsafe then
//! acts on the silence).

use crate::core::commander::OperatorInput;
use crate::core::esc::StopReason;
use crate::core::rc::link::RcLink;
use crate::core::rc::{Decoder, RcCounts, RcEvent};
use crate::tasks::esc_writer::EscMailbox;
use crate::tasks::heartbeats::Heartbeats;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// What the reader has seen, readable from any thread.
#[derive(Debug, Default)]
pub struct RcStats {
    pub frames: AtomicU64,
    pub discarded_bytes: AtomicU64,
    pub rejected_frames: AtomicU64,
    /// Inputs the flight's queue had no room for: reports dropped (they are sent again), and
    /// commands beyond the few kept for the next read.
    pub dropped_inputs: AtomicU64,
    /// The radio as a watcher sees it. The reader only tries the lock (a watcher holding it
    /// delays nothing: the next frame publishes); a watcher waits at most for a copy.
    status: std::sync::Mutex<Option<(crate::core::status::RcStatus, Instant)>>,
    /// A status older than this reads lost (a receiver fallen silent sends no failsafe flag);
    /// none: never.
    stale_after: Option<std::time::Duration>,
    /// Each kill: its frame's arrival and the ESCs' confirmed stop, µs on the run's clock
    /// (the first [`KILLS_KEPT`]).
    kills: std::sync::Mutex<Vec<KillTimes>>,
}

/// A kill switch's stop as the reader timed it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KillTimes {
    /// The read that brought the first frame with the switch on returned, µs.
    pub frame_us: i64,
    /// Every ESC acknowledged its zero and its disable, µs.
    pub confirmed_us: i64,
}

/// Kills timed per run, at most.
pub const KILLS_KEPT: usize = 1000;

impl RcStats {
    /// The radio as the reader last published it: lost once it is older than
    /// [`RcStats::stale_after`].
    pub fn status(&self) -> Option<crate::core::status::RcStatus> {
        let newest = match self.status.lock() {
            Ok(s) => *s,
            Err(poisoned) => *poisoned.into_inner(),
        };
        let (mut status, at) = newest?;
        status.lost |= self.stale_after.is_some_and(|limit| at.elapsed() > limit);
        Some(status)
    }

    fn publish(&self, status: Option<crate::core::status::RcStatus>, at: Instant) {
        if let Ok(mut s) = self.status.try_lock() {
            *s = status.map(|st| (st, at));
        }
    }

    /// Stats whose status reads lost once older than `limit` (`failsafe.rc_timeout_s`).
    pub fn stale_after(limit: std::time::Duration) -> Self {
        RcStats {
            stale_after: Some(limit),
            ..RcStats::default()
        }
    }

    /// The kills timed so far.
    pub fn kills(&self) -> Vec<KillTimes> {
        match self.kills.lock() {
            Ok(k) => k.clone(),
            Err(poisoned) => poisoned.into_inner().clone(),
        }
    }

    /// The counts, for the run's summary.
    pub fn counts(&self) -> RcCounts {
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        RcCounts {
            frames: load(&self.frames),
            discarded_bytes: load(&self.discarded_bytes),
            rejected_frames: load(&self.rejected_frames),
            dropped_inputs: load(&self.dropped_inputs),
        }
    }
}

/// The radio's commands (arm, disarm, the mode switch's) waiting for room in the flight's
/// queue, at most this many: a switch's move is sent once, so it is kept, not dropped, while
/// the queue is full (a report is sent again anyway).
const PENDING_MAX: usize = 16;

/// The reader's parts.
pub struct RcReader {
    pub decoder: Decoder,
    pub link: RcLink,
    pub mailbox: Arc<EscMailbox>,
    pub operator: mpsc::Sender<OperatorInput>,
    pub beats: Arc<Heartbeats>,
    pub stats: Arc<RcStats>,
    /// The ESC writer's status: a kill's stop is timed when it is confirmed.
    pub esc: Arc<crate::tasks::esc_writer::EscStatus>,
    /// A kill switch on since this frame (µs), its stop not yet confirmed; or on and timed.
    pub kill: KillWatch,
    /// When the newest frame of channels was read.
    pub frame_at: Option<Instant>,
}

/// The kill switch as the reader times it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum KillWatch {
    #[default]
    Off,
    /// On since a frame at this time, the stop not yet confirmed.
    Waiting(i64),
    /// On, its stop timed.
    Timed,
}

impl RcReader {
    /// Reads `port` until cancel or a read error.
    pub async fn run(mut self, mut port: impl AsyncRead + Unpin, cancel: CancellationToken) {
        let mut buf = [0u8; 256];
        let (mut events, mut inputs) = (Vec::new(), Vec::new());
        let mut pending = std::collections::VecDeque::new();
        loop {
            let n = tokio::select! {
                _ = cancel.cancelled() => return,
                r = port.read(&mut buf) => r,
            };
            let n = match n {
                Ok(0) => return self.ended("the device closed"),
                Ok(n) => n,
                Err(e) => return self.ended(&e.to_string()),
            };
            let at = Instant::now();
            events.clear();
            self.decoder.feed(&buf[..n], &mut events);
            self.take(&events, at, &mut inputs);
            self.send(&mut inputs, &mut pending);
        }
    }

    /// The inputs to the flight's queue, the commands kept before them first; what finds no
    /// room is counted (a command kept for the next frame, up to [`PENDING_MAX`]).
    fn send(
        &self,
        inputs: &mut Vec<OperatorInput>,
        pending: &mut std::collections::VecDeque<OperatorInput>,
    ) {
        pending.extend(inputs.drain(..));
        while let Some(input) = pending.pop_front() {
            let command = matches!(input, OperatorInput::Command(..));
            match self.operator.try_send(input) {
                Ok(()) => {}
                Err(mpsc::error::TrySendError::Full(input)) if command => {
                    pending.push_front(input);
                    break;
                }
                Err(_) => {
                    self.stats.dropped_inputs.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        // Reports behind a kept command are sent again anyway: only commands wait.
        pending.retain(|i| matches!(i, OperatorInput::Command(..)));
        while pending.len() > PENDING_MAX {
            pending.pop_front();
            self.stats.dropped_inputs.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// The kill switch read `on` in a frame at `t_us`: a new kill starts its timing; a kill
    /// waiting for its stop stays timed however short the switch's flick.
    fn watch_kill(&mut self, on: bool, t_us: i64) {
        self.kill = match (on, self.kill) {
            (false, KillWatch::Waiting(frame_us)) => KillWatch::Waiting(frame_us),
            (false, _) => KillWatch::Off,
            (true, KillWatch::Off) => KillWatch::Waiting(t_us),
            (true, k) => k,
        };
    }

    /// A kill waiting for its stop: timed once the ESC writer says every ESC acknowledged
    /// a stop named `kill` settled after the frame (then off, or on and timed).
    fn time_kill(&mut self, on: bool) {
        let KillWatch::Waiting(frame_us) = self.kill else {
            return;
        };
        let Some(o) = self.esc.stop_outcome() else {
            return;
        };
        let killed = self.esc.stop_reason() == Some(StopReason::KillSwitch);
        if !(killed && o.settled_us >= frame_us) {
            return;
        }
        // Settled: timed if every ESC acknowledged it (an unconfirmed stop is the writer's
        // to report); the next kill is timed afresh either way.
        self.kill = if on { KillWatch::Timed } else { KillWatch::Off };
        if !o.confirmed() {
            return;
        }
        if let Ok(mut k) = self.stats.kills.lock()
            && k.len() < KILLS_KEPT
        {
            k.push(KillTimes {
                frame_us,
                confirmed_us: o.settled_us,
            });
        }
    }

    /// The device failed: said once with the reader's counts; the commander's rc-loss acts
    /// on the silence.
    fn ended(&self, why: &str) {
        let s = &self.stats;
        tracing::error!(
            frames = s.frames.load(Ordering::Relaxed),
            discarded_bytes = s.discarded_bytes.load(Ordering::Relaxed),
            rejected_frames = s.rejected_frames.load(Ordering::Relaxed),
            dropped_inputs = s.dropped_inputs.load(Ordering::Relaxed),
            "RC receiver: {why}; rc-loss follows"
        );
    }

    /// The frames read at `at`: the kill switch to the ESCs at once, the rest as inputs.
    fn take(&mut self, events: &[RcEvent], at: Instant, inputs: &mut Vec<OperatorInput>) {
        let t_us = self.beats.us(at);
        // A watcher's radio is as fresh as its newest frame of channels (not a link
        // statistic, nor noise).
        if events.iter().any(|e| matches!(e, RcEvent::Channels(_))) {
            self.frame_at = Some(at);
        }
        for e in events {
            match e {
                RcEvent::Channels(f) => {
                    let kill = self.link.frame(f, t_us, inputs);
                    if kill {
                        self.mailbox.halt(StopReason::KillSwitch);
                    }
                    self.watch_kill(kill, t_us);
                    self.time_kill(kill);
                }
                RcEvent::Link(s) => self.link.link(s, inputs),
            }
        }
        if let Some(frame_at) = self.frame_at {
            self.stats.publish(self.link.status(), frame_at);
        }
        let d = self.decoder.stats();
        self.stats.frames.store(d.frames, Ordering::Relaxed);
        self.stats
            .discarded_bytes
            .store(d.discarded_bytes, Ordering::Relaxed);
        self.stats
            .rejected_frames
            .store(d.rejected_frames, Ordering::Relaxed);
    }
}
