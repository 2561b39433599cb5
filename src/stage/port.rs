//! The serial line: opened by path, owned by one process, every read bounded in time.

use super::error::{Result, StageError};
use serialport::{ClearBuffer, SerialPort, TTYPort};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How the line is opened, beyond its path.
#[derive(Debug, Clone, Default)]
pub struct LinkOptions {
    /// Record every byte both ways as JSON Lines (`--wire-log`).
    pub wire_log: Option<PathBuf>,
    /// Set by the operator's Ctrl-C: the next read returns [`StageError::Cancelled`] (once),
    /// so whatever was waiting gives up and the driver stops the stages.
    pub cancel: Option<Arc<AtomicBool>>,
    /// Told every position the controller reports, also while a motion runs (the service's
    /// position events); it must be quick and never block.
    pub position: Option<PositionSink>,
}

/// A listener to the positions the controller reports.
#[derive(Clone)]
pub struct PositionSink(pub Arc<dyn Fn(crate::coords::CarriageUm) + Send + Sync>);

impl std::fmt::Debug for PositionSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PositionSink")
    }
}

pub struct Port {
    port: TTYPort,
    pub path: PathBuf,
    /// JSON Lines record of every byte sent and received (`--wire-log`).
    wire_log: Option<std::fs::File>,
    opened: Instant,
    cancel: Option<Arc<AtomicBool>>,
    position: Option<PositionSink>,
}

/// How long a busy port is waited for before it is reported busy ([`Port::open`]).
pub const BUSY_GRACE: Duration = Duration::from_millis(250);

/// Read slices are short so deadlines are kept to within this.
const READ_SLICE: Duration = Duration::from_millis(20);

impl Port {
    /// Opens `path` at `baud`, exclusively: serialport takes `TIOCEXCL` and an exclusive
    /// `flock`, and reports either refusal as `NoDevice`, which is a busy port. A port busy
    /// for less than [`BUSY_GRACE`] is waited for: one closed a moment ago can still be held
    /// by a process that is ending, or by a child forked (by another thread) before the close
    /// and not yet past its `exec`, which closes the copy.
    pub fn open(path: &Path, baud: u32, link: &LinkOptions) -> Result<Port> {
        let start = Instant::now();
        let port = loop {
            match serialport::new(path.to_string_lossy(), baud)
                .timeout(READ_SLICE)
                .open_native()
            {
                Ok(p) => break p,
                Err(e) if e.kind() == serialport::ErrorKind::NoDevice => {
                    if start.elapsed() >= BUSY_GRACE {
                        return Err(StageError::PortBusy {
                            path: path.to_path_buf(),
                        });
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
                Err(e) => {
                    return Err(StageError::Open {
                        path: path.to_path_buf(),
                        source: e.into(),
                    })
                }
            }
        };
        let wire_log = match &link.wire_log {
            Some(l) => Some(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(l)
                    .map_err(|e| StageError::Open {
                        path: l.to_path_buf(),
                        source: e,
                    })?,
            ),
            None => None,
        };
        let mut p = Port {
            port,
            path: path.to_path_buf(),
            wire_log,
            opened: Instant::now(),
            cancel: link.cancel.clone(),
            position: link.position.clone(),
        };
        p.purge()?;
        Ok(p)
    }

    /// Passes a position the controller reported to the listener, if any.
    pub fn observe(&self, p: crate::coords::CarriageUm) {
        if let Some(s) = &self.position {
            (s.0)(p);
        }
    }

    /// Discards whatever is in the buffers both ways (after garbage, before a resync).
    pub fn purge(&mut self) -> Result<()> {
        self.port
            .clear(ClearBuffer::All)
            .map_err(|e| self.lost(e.to_string()))
    }

    fn lost(&self, why: String) -> StageError {
        StageError::Disconnected(format!("{}: {why}", self.path.display()))
    }

    fn log(&mut self, dir: &str, bytes: &[u8]) {
        if let Some(f) = &mut self.wire_log {
            let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
            let _ = writeln!(
                f,
                "{{\"t\":{:.6},\"dir\":\"{dir}\",\"hex\":\"{hex}\"}}",
                self.opened.elapsed().as_secs_f64()
            );
        }
    }

    pub fn write_all(&mut self, bytes: &[u8]) -> Result<()> {
        self.log("tx", bytes);
        self.port
            .write_all(bytes)
            .map_err(|e| self.lost(e.to_string()))?;
        self.port.flush().map_err(|e| self.lost(e.to_string()))
    }

    /// Reads what arrives before `deadline` (at least one slice). Returns an empty vector on a
    /// quiet line; a dead line is an error.
    pub fn read_until(&mut self, deadline: Instant, buf: &mut Vec<u8>) -> Result<usize> {
        let mut tmp = [0u8; 256];
        loop {
            if self
                .cancel
                .as_ref()
                .is_some_and(|c| c.swap(false, Ordering::SeqCst))
            {
                return Err(StageError::Cancelled);
            }
            match self.port.read(&mut tmp) {
                Ok(0) => return Err(self.lost("end of file".into())),
                Ok(n) => {
                    self.log("rx", &tmp[..n]);
                    buf.extend_from_slice(&tmp[..n]);
                    return Ok(n);
                }
                Err(e)
                    if e.kind() == std::io::ErrorKind::TimedOut
                        || e.kind() == std::io::ErrorKind::WouldBlock =>
                {
                    if Instant::now() >= deadline {
                        return Ok(0);
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(self.lost(e.to_string())),
            }
        }
    }
}
