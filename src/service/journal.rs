//! The service's memory across crashes: an append-only file of records, each synced to the
//! disk before the request that made it is answered.
//!
//! A record is `length (u32 LE) · CRC-32 of the payload (u32 LE) · payload`. A kill or a power
//! cut can leave only the last record torn (the file is appended to and synced in order), so
//! reading stops at the first record whose length runs past the end or whose CRC disagrees:
//! everything before it is read, nothing after it is guessed at. The bytes from there on are
//! kept beside the journal (`NAME.torn`) for inspection and cut off, so the next append starts
//! on a record boundary. At start the service rewrites the journal as one snapshot
//! ([`Journal::compact`], atomically), so the file stays as long as the state, not the history.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// The first bytes of a journal, so that a file of another kind is refused, never read as one.
pub const MAGIC: &[u8; 8] = b"RIGJRNL\n";
/// The largest payload taken: a longer length field is damage, not a record.
pub const MAX_RECORD: usize = 64 << 20;
const HEADER: usize = 8;

#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not a rig service journal (it does not begin with the journal's mark); move it away or name another --data directory")]
    NotAJournal { path: PathBuf },
    #[error("{path}: a record of {len} bytes is over the limit of {MAX_RECORD} bytes")]
    TooLarge { path: PathBuf, len: usize },
}

/// What opening found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Recovery {
    /// Records read whole.
    pub records: usize,
    /// Bytes after the last whole record (a torn or damaged tail), moved to `NAME.torn`.
    pub dropped_bytes: u64,
}

pub struct Journal {
    file: File,
    path: PathBuf,
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> JournalError + '_ {
    move |source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The records of `bytes` (a whole journal after its mark) up to the first one that is not
/// whole, and where that one begins.
fn split(bytes: &[u8]) -> (Vec<Vec<u8>>, usize) {
    let mut out = Vec::new();
    let mut at = 0;
    while bytes.len() - at >= HEADER {
        let len = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        let crc = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().unwrap());
        if len > MAX_RECORD || bytes.len() - at - HEADER < len {
            break;
        }
        let payload = &bytes[at + HEADER..at + HEADER + len];
        if crc32fast::hash(payload) != crc {
            break;
        }
        out.push(payload.to_vec());
        at += HEADER + len;
    }
    (out, at)
}

fn encode(payload: &[u8], out: &mut Vec<u8>) {
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out.extend_from_slice(payload);
}

fn sync_dir(path: &Path) {
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if let Ok(d) = File::open(d) {
            let _ = d.sync_all();
        }
    }
}

impl Journal {
    /// Opens (or creates) the journal at `path` and reads its whole records. A torn tail is
    /// moved to `NAME.torn` and cut off.
    pub fn open(path: &Path) -> Result<(Journal, Vec<Vec<u8>>, Recovery), JournalError> {
        let e = io(path);
        let mut file = OpenOptions::new()
            .read(true)
            .append(true)
            .create(true)
            .open(path)
            .map_err(&e)?;
        let mut bytes = Vec::new();
        file.read_to_end(&mut bytes).map_err(&e)?;
        if bytes.is_empty() {
            file.write_all(MAGIC).map_err(&e)?;
            file.sync_data().map_err(&e)?;
            sync_dir(path);
            bytes.extend_from_slice(MAGIC);
        }
        // A file cut inside its mark was being created: it holds nothing yet.
        if bytes.len() < MAGIC.len() && MAGIC.starts_with(&bytes) {
            file.set_len(0).map_err(&e)?;
            file.write_all(MAGIC).map_err(&e)?;
            file.sync_data().map_err(&e)?;
            bytes = MAGIC.to_vec();
        }
        if !bytes.starts_with(MAGIC) {
            return Err(JournalError::NotAJournal {
                path: path.to_path_buf(),
            });
        }
        let (records, used) = split(&bytes[MAGIC.len()..]);
        let end = MAGIC.len() + used;
        let dropped = (bytes.len() - end) as u64;
        if dropped > 0 {
            let torn = path.with_extension("torn");
            std::fs::write(&torn, &bytes[end..]).map_err(io(&torn))?;
            file.set_len(end as u64).map_err(&e)?;
            file.sync_data().map_err(&e)?;
            tracing::warn!(
                journal = %path.display(), bytes = dropped, kept = %torn.display(),
                "the journal's last record was torn (a crash while writing it); it was set aside"
            );
        }
        file.seek(SeekFrom::End(0)).map_err(&e)?;
        let rec = Recovery {
            records: records.len(),
            dropped_bytes: dropped,
        };
        Ok((
            Journal {
                file,
                path: path.to_path_buf(),
            },
            records,
            rec,
        ))
    }

    /// Appends one record and waits until it is on the disk.
    pub fn append(&mut self, payload: &[u8]) -> Result<(), JournalError> {
        if payload.len() > MAX_RECORD {
            return Err(JournalError::TooLarge {
                path: self.path.clone(),
                len: payload.len(),
            });
        }
        let mut buf = Vec::with_capacity(HEADER + payload.len());
        encode(payload, &mut buf);
        let e = io(&self.path);
        self.file.write_all(&buf).map_err(&e)?;
        self.file.sync_data().map_err(&e)
    }

    /// Replaces the whole journal by `records` (atomically: the old file or the new one, never
    /// half), and appends after them from then on.
    pub fn compact(&mut self, records: &[Vec<u8>]) -> Result<(), JournalError> {
        let mut buf = MAGIC.to_vec();
        for r in records {
            if r.len() > MAX_RECORD {
                return Err(JournalError::TooLarge {
                    path: self.path.clone(),
                    len: r.len(),
                });
            }
            encode(r, &mut buf);
        }
        let e = io(&self.path);
        crate::atomic::write_with(&self.path, |w| w.write_all(&buf)).map_err(&e)?;
        self.file = OpenOptions::new()
            .append(true)
            .open(&self.path)
            .map_err(&e)?;
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn records() -> Vec<Vec<u8>> {
        vec![
            b"{\"op\":\"add\"}".to_vec(),
            Vec::new(),
            vec![0u8; 300],
            b"the last one".to_vec(),
        ]
    }

    fn written(dir: &Path) -> (PathBuf, Vec<u8>) {
        let p = dir.join("j");
        let (mut j, got, rec) = Journal::open(&p).unwrap();
        assert!(got.is_empty());
        assert_eq!(rec, Recovery::default());
        for r in records() {
            j.append(&r).unwrap();
        }
        drop(j);
        let bytes = std::fs::read(&p).unwrap();
        (p, bytes)
    }

    /// Cut after every byte, the journal gives exactly the records written whole before the
    /// cut, never a torn one or a garbled one, and takes appends after them again.
    #[test]
    fn a_cut_at_every_byte_keeps_exactly_the_whole_records() {
        let t = tempfile::tempdir().unwrap();
        let (_, full) = written(t.path());
        let all = records();
        // Where each record ends in the file.
        let mut ends = vec![];
        let mut at = MAGIC.len();
        for r in &all {
            at += HEADER + r.len();
            ends.push(at);
        }
        assert_eq!(at, full.len());
        for cut in 0..=full.len() {
            let p = t.path().join(format!("cut{cut}"));
            std::fs::write(&p, &full[..cut]).unwrap();
            let (mut j, got, rec) = Journal::open(&p).unwrap();
            let whole = ends.iter().filter(|&&e| e <= cut).count();
            assert_eq!(got, all[..whole], "cut at {cut}");
            let end = if whole == 0 {
                MAGIC.len()
            } else {
                ends[whole - 1]
            };
            let expect_dropped = cut.saturating_sub(end.max(MAGIC.len())) as u64;
            assert_eq!(rec.dropped_bytes, expect_dropped, "cut at {cut}");
            j.append(b"after").unwrap();
            drop(j);
            let (_, again, rec) = Journal::open(&p).unwrap();
            assert_eq!(rec.dropped_bytes, 0);
            assert_eq!(again.len(), whole + 1);
            assert_eq!(again.last().unwrap(), b"after");
        }
    }

    /// A flipped bit anywhere in a record ends the journal at that record: the damaged
    /// record and what follows are set aside, never read.
    #[test]
    fn a_flipped_bit_is_never_read_as_a_record() {
        let t = tempfile::tempdir().unwrap();
        let (p, full) = written(t.path());
        let first_end = MAGIC.len() + HEADER + records()[0].len();
        for byte in MAGIC.len()..first_end {
            for bit in 0..8 {
                let mut b = full.clone();
                b[byte] ^= 1 << bit;
                std::fs::write(&p, &b).unwrap();
                let (_, got, rec) = Journal::open(&p).unwrap();
                assert!(got.is_empty(), "byte {byte} bit {bit}: {got:?}");
                assert!(rec.dropped_bytes > 0);
                let torn = std::fs::read(p.with_extension("torn")).unwrap();
                assert_eq!(torn, b[MAGIC.len()..]);
            }
        }
    }

    #[test]
    fn another_file_is_refused_and_compaction_replaces_the_records() {
        let t = tempfile::tempdir().unwrap();
        let p = t.path().join("other");
        std::fs::write(&p, b"{\"not\": \"a journal\"}").unwrap();
        assert!(matches!(
            Journal::open(&p),
            Err(JournalError::NotAJournal { .. })
        ));
        let (p, _) = written(t.path());
        let (mut j, got, _) = Journal::open(&p).unwrap();
        assert_eq!(got.len(), 4);
        j.compact(&[b"snapshot".to_vec()]).unwrap();
        j.append(b"next").unwrap();
        drop(j);
        let (_, got, _) = Journal::open(&p).unwrap();
        assert_eq!(got, vec![b"snapshot".to_vec(), b"next".to_vec()]);
    }
}
