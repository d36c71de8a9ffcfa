//! The logs a replay writes: its records gathered in chunks during the loop, formatted as the
//! chunks fill (on a second thread when the replay has one, so that printing some fifty
//! thousand numbers overlaps the closed loop instead of following it), and written only once
//! the loop has succeeded (a failed loop leaves an earlier replay's logs as they were).

use crate::core::flight::{FlightRecord, Outputs};
use crate::core::watchdog::Event;
use crate::logs::{self, InnovRecord, KalmanInRecord};
use anyhow::Context;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, Sender};

/// Frames a chunk gathers before it is formatted: a handful of hand-offs a flight, each large
/// enough that the formatter is not woken for every step.
const CHUNK_FRAMES: usize = 128;

/// A chunk's room: it is handed on between frames, so one stream may hold a record more than
/// the stream it is counted by.
const CHUNK_ROOM: usize = CHUNK_FRAMES + 1;

/// The records of some consecutive frames, each stream in order.
pub struct Chunk {
    kalman_in: Vec<KalmanInRecord>,
    x_hat: Vec<[f64; 15]>,
    innov: Vec<InnovRecord>,
    w: Vec<(i64, [f64; 4])>,
    /// Time and integrators; only the first `n_int` values are meaningful.
    int: Vec<(i64, [f64; 4])>,
    n_int: usize,
    setpoint: Vec<(i64, [f64; 6])>,
    /// The mode stream, formatted as it goes (a few lines a flight).
    mode: String,
}

impl Chunk {
    /// Room for `frames` records in each stream, so that a chunk never grows once made.
    fn with_capacity(frames: usize) -> Self {
        Chunk {
            kalman_in: Vec::with_capacity(frames),
            x_hat: Vec::with_capacity(frames),
            innov: Vec::with_capacity(frames),
            w: Vec::with_capacity(frames),
            int: Vec::with_capacity(frames),
            n_int: 0,
            setpoint: Vec::with_capacity(frames),
            mode: String::new(),
        }
    }

    /// Empties the chunk, keeping its room for the next frames.
    fn clear(&mut self) {
        self.kalman_in.clear();
        self.x_hat.clear();
        self.innov.clear();
        self.w.clear();
        self.int.clear();
        self.setpoint.clear();
        self.mode.clear();
    }

    /// Whether it holds a chunk's worth of frames (every frame that steps writes kalman_in).
    fn is_full(&self) -> bool {
        self.kalman_in.len() >= CHUNK_FRAMES
    }
}

/// The text of each log, formatted chunk by chunk.
pub struct Texts {
    kalman_in: String,
    x_hat: String,
    innov: String,
    w: String,
    int: String,
    setpoint: String,
    mode: String,
}

impl Texts {
    /// Room for the text of `frames` frames (a row's usual length each), so that the strings
    /// are not copied as they grow.
    pub fn for_frames(frames: usize) -> Self {
        let room = |row_bytes: usize| String::with_capacity(frames * row_bytes);
        Texts {
            kalman_in: room(112),
            x_hat: room(192),
            innov: room(48),
            w: room(80),
            int: room(80),
            setpoint: room(112),
            mode: String::new(),
        }
    }

    /// Formats `c`'s records after the ones before.
    fn append(&mut self, c: &Chunk) {
        for r in &c.kalman_in {
            r.write(&mut self.kalman_in);
        }
        for x in &c.x_hat {
            logs::write_values_row(&mut self.x_hat, None, x);
        }
        for r in &c.innov {
            r.write(&mut self.innov);
        }
        for (t_us, w) in &c.w {
            logs::write_values_row(&mut self.w, Some(*t_us), w);
        }
        for (t_us, v) in &c.int {
            logs::write_values_row(&mut self.int, Some(*t_us), &v[..c.n_int]);
        }
        for (t_us, sp) in &c.setpoint {
            logs::write_values_row(&mut self.setpoint, Some(*t_us), sp);
        }
        self.mode.push_str(&c.mode);
    }

    /// Writes the logs into `out_dir` (which exists); the paths written, or the first
    /// failure naming its file.
    pub fn write(&self, out_dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
        [
            ("x_hat.log", &self.x_hat),
            ("w.log", &self.w),
            ("innov.log", &self.innov),
            ("mode.log", &self.mode),
            ("kalman_in.log", &self.kalman_in),
            ("int.log", &self.int),
            ("setpoint.log", &self.setpoint),
        ]
        .iter()
        .map(|(name, text)| {
            let path = out_dir.join(name);
            write_text(&path, text)
                .with_context(|| format!("cannot write {}", path.display()))
                .map(|()| path)
        })
        .collect()
    }
}

/// Writes `text` as the whole file at `path`, over what it held.
///
/// The file is not truncated first: a replay usually rewrites a log of the same size, and
/// truncating frees the file's blocks only for the write to allocate them again (a third of a
/// batch's time into an existing folder); it is cut to the text's length after.
fn write_text(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write as _;
    let mut file = std::fs::File::options()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)?;
    if let Err(e) = file.write_all(text.as_bytes()) {
        // Emptied rather than left as the new text followed by the old one's tail, which
        // could pass for a log.
        let _ = file.set_len(0);
        return Err(e);
    }
    file.set_len(text.len() as u64)
}

/// Formats the chunks `full` brings, in order, handing each back emptied through `spare`,
/// until `full` closes: the text of every log, for `frames` frames.
pub fn format_chunks(full: Receiver<Chunk>, spare: Sender<Chunk>, frames: usize) -> Texts {
    let mut texts = Texts::for_frames(frames);
    while let Some(mut chunk) = next_polling(&full) {
        texts.append(&chunk);
        chunk.clear();
        // The loop may have ended already; then the chunk is simply dropped.
        let _ = spare.send(chunk);
    }
    texts
}

/// The next message of `rx` (`None` once its sender is gone), polled for about a millisecond
/// before sleeping: a replay's two threads wait on each other some fifteen times, and waking
/// a sleeping thread costs tens of microseconds on a virtual machine, several times what the
/// wait itself usually is. Only for the replay's own two threads, each on a CPU of its own.
pub fn next_polling<T>(rx: &Receiver<T>) -> Option<T> {
    use std::sync::mpsc::TryRecvError;
    // An empty poll takes 10-20 ns.
    const POLLS: usize = 100_000;
    for _ in 0..POLLS {
        match rx.try_recv() {
            Ok(v) => return Some(v),
            Err(TryRecvError::Disconnected) => return None,
            Err(TryRecvError::Empty) => std::hint::spin_loop(),
        }
    }
    rx.recv().ok()
}

/// Where a full chunk goes: formatted here (a [`Texts`]) or to a formatter thread.
pub trait ChunkSink {
    /// Takes the records of `chunk`, leaving it empty for the next frames.
    fn take(&mut self, chunk: &mut Chunk);
}

impl ChunkSink for Texts {
    fn take(&mut self, chunk: &mut Chunk) {
        self.append(chunk);
        chunk.clear();
    }
}

/// The loop's end of a formatter thread ([`format_chunks`]): full chunks go out, emptied ones
/// come back, so that the loop reuses their memory. Dropping it ends the thread's input.
pub struct ToFormatter {
    pub full: Sender<Chunk>,
    pub spare: Receiver<Chunk>,
}

impl ChunkSink for ToFormatter {
    fn take(&mut self, chunk: &mut Chunk) {
        let next = self
            .spare
            .try_recv()
            .unwrap_or_else(|_| Chunk::with_capacity(CHUNK_ROOM));
        // A formatter that is gone has panicked; the replay reports it after the loop.
        let _ = self.full.send(std::mem::replace(chunk, next));
    }
}

/// The output records of a replay's loop (its [`Outputs`]): the current chunk and where it
/// goes when full.
pub struct Records<S> {
    chunk: Chunk,
    sink: S,
}

impl<S: ChunkSink> Records<S> {
    pub fn new(sink: S) -> Self {
        Records {
            chunk: Chunk::with_capacity(CHUNK_ROOM),
            sink,
        }
    }

    /// mode.log's first line: the run it names (before any record).
    pub fn run_line(&mut self, run_id: &str) {
        logs::mode_log::write_run(&mut self.chunk.mode, run_id);
    }

    /// Hands the chunk on once it is full (called between frames).
    pub fn hand_off_if_full(&mut self) {
        if self.chunk.is_full() {
            self.sink.take(&mut self.chunk);
        }
    }

    /// Hands on the last records; the sink, which has them all.
    pub fn finish(mut self) -> S {
        self.sink.take(&mut self.chunk);
        self.sink
    }
}

impl<S> Outputs for Records<S> {
    /// Keeps the streams a replay writes; the others (imu_raw, gps, err) are the run's.
    fn record(&mut self, r: FlightRecord) {
        let c = &mut self.chunk;
        match r {
            FlightRecord::KalmanIn {
                t_us,
                dt_us,
                sample,
            } => c
                .kalman_in
                .push(KalmanInRecord::from_sample(t_us, dt_us, &sample)),
            FlightRecord::XHat(x) => c.x_hat.push(x),
            FlightRecord::Innov {
                t_us,
                ratios,
                gated,
            } => c.innov.push(InnovRecord {
                t_us,
                ratios,
                gated,
            }),
            FlightRecord::Command { t_us, w_rad_s } => c.w.push((t_us, w_rad_s)),
            FlightRecord::Setpoint { t_us, sp } => c.setpoint.push((t_us, sp)),
            FlightRecord::Int { t_us, x_int, n_int } => {
                c.n_int = n_int;
                c.int.push((t_us, x_int));
            }
            r @ (FlightRecord::Commander(_) | FlightRecord::Operator { .. }) => {
                logs::Record::Flight(r).write(&mut c.mode)
            }
            FlightRecord::Frame { .. }
            | FlightRecord::FakeGps(_)
            | FlightRecord::GpsFix { .. }
            | FlightRecord::Halt(_)
            | FlightRecord::Note(_) => {}
        }
    }

    fn watchdog(&mut self, _: Event) {}
}
