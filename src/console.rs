//! The console: a Unix socket served by `fly` and `sim` that `uquad console` (run by a user who
//! ssh-ed into the board) attaches to. It streams the live tracing events (filtered per client),
//! a statistics line once a second, and takes the manual-mode commands of spec 5.2.
//!
//! A console never slows the control path: events go through a bounded broadcast queue, each
//! client reads it at its own pace, and what a slow client misses is counted and told to it.

use crate::core::commander::{LinkSource, OperatorInput};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{broadcast, mpsc};
use tokio_util::sync::CancellationToken;

/// Events queued for the consoles (each client has its own read position).
const EVENT_QUEUE: usize = 1024;

/// The live events, level first: "INFO target: message key=value".
fn events() -> &'static broadcast::Sender<Arc<str>> {
    static EVENTS: OnceLock<broadcast::Sender<Arc<str>>> = OnceLock::new();
    EVENTS.get_or_init(|| broadcast::channel(EVENT_QUEUE).0)
}

/// A tracing layer feeding the consoles. It formats only when a console is attached.
pub struct ConsoleLayer;

struct Fields(String);

impl tracing::field::Visit for Fields {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.0, " {value:?}");
        } else {
            let _ = write!(self.0, " {}={value:?}", field.name());
        }
    }
}

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for ConsoleLayer {
    fn on_event(
        &self,
        event: &tracing::Event<'_>,
        _ctx: tracing_subscriber::layer::Context<'_, S>,
    ) {
        let tx = events();
        if tx.receiver_count() == 0 {
            return;
        }
        let meta = event.metadata();
        let mut f = Fields(format!("{} {}:", meta.level(), meta.target()));
        event.record(&mut f);
        let _ = tx.send(f.0.into());
    }
}

/// A client's filter: a minimum level and an optional target/text part ("warn", "debug,esc").
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Filter {
    min: tracing::Level,
    contains: Option<String>,
}

impl Filter {
    pub fn parse(s: &str) -> Filter {
        let mut min = tracing::Level::INFO;
        let mut contains = None;
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            match part.parse::<tracing::Level>() {
                Ok(l) => min = l,
                Err(_) => contains = Some(part.to_string()),
            }
        }
        Filter { min, contains }
    }

    pub fn accepts(&self, line: &str) -> bool {
        let level = line
            .split_whitespace()
            .next()
            .and_then(|l| l.parse::<tracing::Level>().ok())
            .unwrap_or(tracing::Level::INFO);
        // tracing orders levels by verbosity: ERROR < WARN < INFO < DEBUG < TRACE.
        level <= self.min
            && self
                .contains
                .as_ref()
                .is_none_or(|c| line.contains(c.as_str()))
    }
}

/// Lines the stderr writer dropped because stderr could not keep up (a stalled terminal);
/// set once by the binary that installs the writer.
static STDERR_DROPS: OnceLock<tracing_appender::non_blocking::ErrorCounter> = OnceLock::new();

/// Counts the stderr writer's drops from now on (see [`stderr_drops`]).
pub fn count_stderr_drops(counter: tracing_appender::non_blocking::ErrorCounter) {
    let _ = STDERR_DROPS.set(counter);
}

/// Log lines stderr could not take so far.
pub fn stderr_drops() -> u64 {
    STDERR_DROPS.get().map_or(0, |c| c.dropped_lines() as u64)
}

/// The once-a-second statistics line, made by the run that serves the console.
pub type StatsFn = Arc<dyn Fn() -> String + Send + Sync>;

/// Longest line a console client may send, bytes: a longer one is refused and the client is
/// told why and disconnected (an endless line must not grow this process's locked memory).
pub const MAX_LINE_BYTES: usize = 1024;
/// Consoles attached at once; more are told so and closed.
pub const MAX_CLIENTS: usize = 8;
/// Commands a console may send per second; the rest are refused, each with a reply.
pub const MAX_COMMANDS_PER_S: u32 = 20;

/// Serves the console socket at `path` until `cancel`. The socket is created readable and
/// writable by its owner and group only, at a private name first and then renamed into
/// place, so it is never open to others, and never follows a symlink. A socket that another
/// run still answers on is left alone: this run then serves no console, and says why.
pub async fn serve(
    path: PathBuf,
    stats: StatsFn,
    operator: mpsc::Sender<OperatorInput>,
    dropped: Arc<AtomicU64>,
    cancel: CancellationToken,
) -> std::io::Result<()> {
    let listener = bind(&path).await?;
    tracing::info!(socket = %path.display(), "console socket ready");
    let clients = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    loop {
        let conn = tokio::select! {
            _ = cancel.cancelled() => break,
            c = listener.accept() => c,
        };
        match conn {
            Ok((mut stream, _)) => {
                if clients.fetch_add(1, Ordering::SeqCst) >= MAX_CLIENTS {
                    clients.fetch_sub(1, Ordering::SeqCst);
                    let msg = format!("console: {MAX_CLIENTS} consoles already attached\n");
                    let _ = stream.write_all(msg.as_bytes()).await;
                    continue;
                }
                let (stats, manual, dropped, cancel, clients) = (
                    stats.clone(),
                    operator.clone(),
                    dropped.clone(),
                    cancel.clone(),
                    clients.clone(),
                );
                tokio::spawn(async move {
                    client(stream, stats, manual, dropped, cancel).await;
                    clients.fetch_sub(1, Ordering::SeqCst);
                });
            }
            Err(e) => tracing::warn!("console accept: {e}"),
        }
    }
    let _ = std::fs::remove_file(&path);
    Ok(())
}

/// Binds the console socket at `path` (see [`serve`]).
async fn bind(path: &Path) -> std::io::Result<UnixListener> {
    use std::os::unix::fs::{FileTypeExt, PermissionsExt};
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        // A socket left by a run that died is replaced; a live one, or anything else at that
        // path, is not ours to delete.
        if !meta.file_type().is_socket() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                format!("{} exists and is not a socket", path.display()),
            ));
        }
        if UnixStream::connect(path).await.is_ok() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AddrInUse,
                format!(
                    "{} is the console of another running uquad; this run serves no console",
                    path.display()
                ),
            ));
        }
    }
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    if let Some(dir) = dir {
        std::fs::create_dir_all(dir)?;
    }
    let private = path.with_extension(format!("{}.new", std::process::id()));
    let _ = std::fs::remove_file(&private);
    let listener = UnixListener::bind(&private)?;
    std::fs::set_permissions(&private, std::fs::Permissions::from_mode(0o660))?;
    // rename replaces a stale socket (or a symlink put there meanwhile) without following it.
    std::fs::rename(&private, path)?;
    Ok(listener)
}

async fn client(
    stream: UnixStream,
    stats: StatsFn,
    operator: mpsc::Sender<OperatorInput>,
    dropped: Arc<AtomicU64>,
    cancel: CancellationToken,
) {
    let (read, mut write) = stream.into_split();
    let mut lines = tokio_util::codec::FramedRead::new(
        read,
        tokio_util::codec::LinesCodec::new_with_max_length(MAX_LINE_BYTES),
    );
    let mut rate = RateLimit::default();
    let mut rx = events().subscribe();
    let mut filter = Filter::parse("info");
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    let _ = write
        .write_all(b"uquad console: arm, takeoff [ALT_M], hold [X Y Z], land, disarm, kill; keys j/g roll, y/h pitch, q/w yaw, e/d altitude, i/k mass, 0 reset mass, quit; 'filter LEVEL[,TEXT]'\n")
        .await;
    loop {
        let out: Option<String> = tokio::select! {
            _ = cancel.cancelled() => None,
            line = futures_util::StreamExt::next(&mut lines) => match line {
                Some(Ok(l)) if rate.allows(Instant::now()) => Some(command(&l, &mut filter, &operator)),
                Some(Ok(_)) => Some(format!(
                    "console: more than {MAX_COMMANDS_PER_S} commands a second; refused\n"
                )),
                Some(Err(tokio_util::codec::LinesCodecError::MaxLineLengthExceeded)) => {
                    let msg = format!("console: line longer than {MAX_LINE_BYTES} bytes; disconnecting\n");
                    let _ = write.write_all(msg.as_bytes()).await;
                    None
                }
                _ => None,
            },
            ev = rx.recv() => match ev {
                Ok(e) if filter.accepts(&e) => Some(format!("{e}\n")),
                Ok(_) => Some(String::new()),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    dropped.fetch_add(n, Ordering::Relaxed);
                    Some(format!("console: {n} events dropped (this console read too slowly)\n"))
                }
                Err(broadcast::error::RecvError::Closed) => None,
            },
            _ = tick.tick() => {
                // An attached console keeps the operator link alive (failsafe.link_sources).
                let _ = operator.try_send(OperatorInput::Beat(LinkSource::Console));
                Some(format!("{}\n", stats()))
            }
        };
        let Some(out) = out else { break };
        if !out.is_empty() && write.write_all(out.as_bytes()).await.is_err() {
            break;
        }
    }
}

/// At most [`MAX_COMMANDS_PER_S`] commands in any one-second window.
#[derive(Debug, Default)]
pub struct RateLimit {
    window_start: Option<Instant>,
    count: u32,
}

impl RateLimit {
    /// Whether a command arriving `now` is taken.
    pub fn allows(&mut self, now: Instant) -> bool {
        match self.window_start {
            Some(start) if now.duration_since(start) < Duration::from_secs(1) => {}
            _ => {
                self.window_start = Some(now);
                self.count = 0;
            }
        }
        self.count += 1;
        self.count <= MAX_COMMANDS_PER_S
    }
}

/// One line from a client: a filter change, a commander command (arm, takeoff [ALT_M],
/// hold [X Y Z], land, disarm, kill) or manual-mode keys; returns the reply. The command's
/// outcome (done or refused, and why) arrives as a log event. Public for the fuzz tests
/// (`tests/fuzz.rs`), which feed it generated lines.
pub fn command(line: &str, filter: &mut Filter, operator: &mpsc::Sender<OperatorInput>) -> String {
    let line = line.trim();
    if let Some(f) = line.strip_prefix("filter") {
        *filter = Filter::parse(f);
        return format!("console: filter {filter:?}\n");
    }
    let inputs = match OperatorInput::parse_line(line, LinkSource::Console) {
        Ok(i) => i,
        Err(e) => return format!("console: {e}\n"),
    };
    let mut reply = String::new();
    for input in inputs {
        let what = match &input {
            OperatorInput::Key(k) => format!("{k:?}"),
            other => other.what(),
        };
        reply += &match operator.try_send(input) {
            Ok(()) => format!("console: sent {what}\n"),
            Err(_) => "console: the flight is not taking commands now\n".to_string(),
        };
    }
    reply
}

/// `uquad console`: attaches to `path`, prints what arrives, sends stdin's lines.
pub async fn attach(path: &Path, filter: Option<&str>) -> anyhow::Result<()> {
    use anyhow::Context;
    let stream = UnixStream::connect(path)
        .await
        .with_context(|| format!("cannot attach to the console at {}", path.display()))?;
    let (read, mut write) = stream.into_split();
    if let Some(f) = filter {
        write.write_all(format!("filter {f}\n").as_bytes()).await?;
    }
    let to_socket = tokio::spawn(async move {
        let mut stdin = BufReader::new(tokio::io::stdin()).lines();
        while let Ok(Some(l)) = stdin.next_line().await {
            if write.write_all(format!("{l}\n").as_bytes()).await.is_err() {
                break;
            }
        }
    });
    let mut lines = BufReader::new(read).lines();
    let mut out = tokio::io::stdout();
    while let Some(l) = lines.next_line().await? {
        out.write_all(format!("{l}\n").as_bytes()).await?;
        out.flush().await?;
    }
    to_socket.abort();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filters() {
        let f = Filter::parse("warn");
        assert!(f.accepts("ERROR uquad: x"));
        assert!(f.accepts("WARN uquad: x"));
        assert!(!f.accepts("INFO uquad: x"));
        let f = Filter::parse("debug,esc");
        assert!(f.accepts("DEBUG uquad::tasks::esc_writer: y"));
        assert!(!f.accepts("DEBUG uquad::tasks::estimator: y"));
        assert!(!f.accepts("TRACE uquad::tasks::esc_writer: y"));
    }
}
