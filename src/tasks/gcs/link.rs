//! The link's bytes: a UDP socket or a serial telemetry radio. Receiving is awaited by the
//! link task; sending never waits — a datagram the socket cannot take now, or a frame the
//! radio's bounded queue cannot, is dropped and counted.

use crate::config::GcsConfig;
use crate::gcs::wire::Decoder;
use anyhow::Context;
use std::net::SocketAddr;
use tokio::io::{AsyncReadExt, AsyncWriteExt, ReadHalf};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;
use tokio_serial::{SerialPortBuilderExt, SerialStream};

/// Frames queued for the radio: about a second of telemetry at 57600 baud.
const SERIAL_QUEUE: usize = 64;
/// The radio's writer makes up this much of a late wake-up (a few ms of bytes, which a
/// radio's buffer holds).
const WAKE_SLACK: std::time::Duration = std::time::Duration::from_millis(5);

/// A download keeps at most this many frames queued for the radio (about 0.1 s at 57600
/// baud).
const RADIO_DOWNLOAD_QUEUED: usize = 6;

pub enum Link {
    Udp {
        socket: UdpSocket,
        remote: SocketAddr,
        /// The last address a ground station wrote from (answered too).
        peer: Option<SocketAddr>,
    },
    Serial {
        reader: ReadHalf<SerialStream>,
        writer: mpsc::Sender<Vec<u8>>,
    },
}

/// Why a frame was not sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SendFail {
    /// The socket or the radio's queue is full: try again later.
    Full,
    /// The link is gone or refused the frame.
    Error,
}

impl Link {
    /// The link `cfg` describes: the serial radio when `gcs.serial` is set, else UDP.
    pub async fn open(cfg: &GcsConfig) -> anyhow::Result<Link> {
        if !cfg.serial.as_os_str().is_empty() {
            return open_serial(cfg);
        }
        let local: SocketAddr = cfg
            .udp_local
            .parse()
            .with_context(|| format!("gcs.udp_local {:?}", cfg.udp_local))?;
        let remote: SocketAddr = cfg
            .udp_remote
            .parse()
            .with_context(|| format!("gcs.udp_remote {:?}", cfg.udp_remote))?;
        let socket = UdpSocket::bind(local)
            .await
            .with_context(|| format!("cannot bind gcs.udp_local {local}"))?;
        Ok(Link::Udp {
            socket,
            remote,
            peer: None,
        })
    }

    /// What the link is, for the run's log.
    pub fn describe(&self) -> String {
        match self {
            Link::Udp { socket, remote, .. } => match socket.local_addr() {
                Ok(l) => format!("UDP {l} -> {remote}"),
                Err(_) => format!("UDP -> {remote}"),
            },
            Link::Serial { .. } => "serial radio".into(),
        }
    }

    /// The decoder for this link's bytes: a datagram at a time, or a stream.
    pub fn decoder(&self) -> Decoder {
        match self {
            Link::Udp { .. } => Decoder::for_datagrams(),
            Link::Serial { .. } => Decoder::for_stream(),
        }
    }

    /// The next bytes heard, and from where (UDP). A radio that reads 0 bytes is gone: an
    /// error.
    pub async fn recv(&mut self, buf: &mut [u8]) -> std::io::Result<(usize, Option<SocketAddr>)> {
        match self {
            Link::Udp { socket, .. } => {
                let (n, from) = socket.recv_from(buf).await?;
                Ok((n, Some(from)))
            }
            Link::Serial { reader, .. } => match reader.read(buf).await? {
                0 => Err(std::io::ErrorKind::UnexpectedEof.into()),
                n => Ok((n, None)),
            },
        }
    }

    /// A ground station wrote from `from` (frames that passed their checksum): it is
    /// answered there too. Noise from elsewhere never redirects the telemetry.
    pub fn heard_from(&mut self, from: SocketAddr) {
        if let Link::Udp { peer, .. } = self {
            *peer = Some(from);
        }
    }

    pub fn is_serial(&self) -> bool {
        matches!(self, Link::Serial { .. })
    }

    /// PARAM_VALUEs per 20 ms tick while a list streams: 500 a second over UDP; over a
    /// 57600-baud radio 50 (1.9 kB/s), which leave room for the telemetry in its queue.
    pub fn params_per_tick(&self) -> usize {
        match self {
            Link::Udp { .. } => 10,
            Link::Serial { .. } => 1,
        }
    }

    /// Log-download packets the link can take now: over UDP 50 per 20 ms tick (about
    /// 225 kB/s, far below what loopback or a LAN carries beside the telemetry); over a radio
    /// what keeps at most [`RADIO_DOWNLOAD_QUEUED`] frames queued, so the telemetry's frames
    /// wait at most that long behind them and the download takes the rest of the line.
    pub fn download_room(&self) -> usize {
        match self {
            Link::Udp { .. } => 50,
            Link::Serial { writer, .. } => {
                let queued = SERIAL_QUEUE.saturating_sub(writer.capacity());
                RADIO_DOWNLOAD_QUEUED.saturating_sub(queued)
            }
        }
    }

    /// Sends `bytes` (whole frames) without waiting.
    pub fn send(&mut self, bytes: &[u8]) -> Result<(), SendFail> {
        match self {
            Link::Udp {
                socket,
                remote,
                peer,
            } => {
                let mut result = send_to(socket, bytes, *remote);
                if let Some(p) = *peer
                    && p != *remote
                {
                    result = result.and(send_to(socket, bytes, p));
                }
                result
            }
            Link::Serial { writer, .. } => writer.try_send(bytes.to_vec()).map_err(|e| match e {
                mpsc::error::TrySendError::Full(_) => SendFail::Full,
                mpsc::error::TrySendError::Closed(_) => SendFail::Error,
            }),
        }
    }
}

fn send_to(socket: &UdpSocket, bytes: &[u8], to: SocketAddr) -> Result<(), SendFail> {
    match socket.try_send_to(bytes, to) {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Err(SendFail::Full),
        Err(_) => Err(SendFail::Error),
    }
}

/// The radio: 8N1 at `gcs.baud`; its writes go through a queue to a task of their own, so a
/// slow radio never holds the link task. The task paces them to the line's byte rate (ten
/// bits a byte): a radio drops what overruns its air rate, and a device that takes bytes
/// faster (a pty, a USB adapter's buffer) must not hide that.
fn open_serial(cfg: &GcsConfig) -> anyhow::Result<Link> {
    let name = cfg.serial.to_string_lossy();
    let port = tokio_serial::new(name.as_ref(), cfg.baud)
        .open_native_async()
        .with_context(|| format!("cannot open gcs.serial {}", cfg.serial.display()))?;
    let (reader, mut write_half) = tokio::io::split(port);
    let (writer, mut frames) = mpsc::channel::<Vec<u8>>(SERIAL_QUEUE);
    let byte_time = std::time::Duration::from_secs_f64(10.0 / f64::from(cfg.baud.max(1)));
    tokio::spawn(async move {
        let mut free_at = tokio::time::Instant::now();
        while let Some(f) = frames.recv().await {
            tokio::time::sleep_until(free_at).await;
            if write_half.write_all(&f).await.is_err() {
                return;
            }
            // A wake-up a little late is made up (a radio buffers a few ms of bytes); an idle
            // line saves nothing up.
            let idle_from = tokio::time::Instant::now() - WAKE_SLACK;
            free_at = free_at.max(idle_from) + byte_time * f.len() as u32;
        }
    });
    Ok(Link::Serial { reader, writer })
}
