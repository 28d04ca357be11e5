//! Checkpoints of long runs on disk (`<dir>/<key>.checkpoint`), shared by every slot of a worker
//! (and by workers on one machine given the same directory): a run whose worker was killed or
//! stopped goes on from its last checkpoint when its job comes back to a worker using `dir`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use repose_experiments::catalog::CheckpointStore;

/// A directory of run checkpoints. A write goes to a temporary file in the directory, is synced
/// and renamed over the old one, so a crash or a full disk leaves the previous checkpoint whole.
#[derive(Debug, Clone)]
pub struct FileCheckpointStore {
    dir: PathBuf,
    every: Duration,
}

impl FileCheckpointStore {
    /// A store in `dir` (created on the first write), a checkpoint every `every` of wall time.
    pub fn new(dir: impl Into<PathBuf>, every: Duration) -> FileCheckpointStore {
        FileCheckpointStore {
            dir: dir.into(),
            every,
        }
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.checkpoint"))
    }

    /// Replaces the checkpoint under `key`; the error says what could not be written.
    pub fn write(&self, key: &str, bytes: &[u8]) -> std::io::Result<()> {
        write_atomically(&self.path(key), bytes)
    }
}

/// Replaces `file` by `bytes` so that a reader (or a crash, or a full disk) sees the old file
/// or the new one, never half of one: a temporary file beside it, synced, renamed over it. The
/// directory is created if missing.
pub fn write_atomically(file: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir)?;
    let mut temp = tempfile::NamedTempFile::new_in(dir)?;
    temp.write_all(bytes)?;
    temp.as_file().sync_all()?;
    temp.persist(file).map_err(|e| e.error)?;
    Ok(())
}

impl CheckpointStore for FileCheckpointStore {
    fn get(&mut self, key: &str) -> Option<Vec<u8>> {
        let bytes = std::fs::read(self.path(key)).ok()?;
        tracing::info!(key, bytes = bytes.len(), "found a checkpoint of this run");
        Some(bytes)
    }

    fn put(&mut self, key: &str, bytes: &[u8]) {
        match self.write(key, bytes) {
            Ok(()) => tracing::debug!(key, bytes = bytes.len(), "checkpoint kept"),
            Err(e) => {
                tracing::warn!(dir = %self.dir.display(), error = %e, "cannot keep the checkpoint")
            }
        }
    }

    fn remove(&mut self, key: &str) {
        if let Err(e) = std::fs::remove_file(self.path(key)) {
            if e.kind() != std::io::ErrorKind::NotFound {
                tracing::warn!(key, error = %e, "cannot delete the finished run's checkpoint");
            }
        }
    }

    fn reject(&mut self, key: &str, reason: &str) {
        let aside = self.dir.join(format!("{key}.unreadable"));
        match std::fs::rename(self.path(key), &aside) {
            Ok(()) => tracing::warn!(key, reason, kept = %aside.display(),
                "cannot continue from the checkpoint; the run starts over and the checkpoint is kept aside"),
            Err(e) => tracing::warn!(key, reason, error = %e,
                "cannot continue from the checkpoint, nor move it aside; the run starts over"),
        }
    }

    fn every(&self) -> Duration {
        self.every
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_checkpoint_is_replaced_whole_read_back_and_removed() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileCheckpointStore::new(dir.path().join("c"), Duration::from_secs(60));
        assert_eq!(store.get("k"), None);
        store.put("k", b"first");
        store.put("k", b"second, longer");
        assert_eq!(store.get("k").as_deref(), Some(&b"second, longer"[..]));
        assert_eq!(store.get("other"), None);
        // Only the checkpoint is left in the directory (no temporary files).
        assert_eq!(std::fs::read_dir(store.dir()).unwrap().count(), 1);
        store.remove("k");
        store.remove("k");
        assert_eq!(store.get("k"), None);
        assert_eq!(store.every(), Duration::from_secs(60));
    }

    #[test]
    fn a_rejected_checkpoint_is_kept_aside_not_overwritten() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileCheckpointStore::new(dir.path(), Duration::from_secs(60));
        store.put("k", b"written by another build");
        store.reject("k", "checkpoint format 7; this build reads format 1");
        assert_eq!(store.get("k"), None);
        store.put("k", b"the new run's");
        assert_eq!(
            std::fs::read(dir.path().join("k.unreadable")).unwrap(),
            b"written by another build"
        );
        assert_eq!(store.get("k").as_deref(), Some(&b"the new run's"[..]));
    }

    #[test]
    fn a_store_that_cannot_write_keeps_nothing_and_does_not_panic() {
        let dir = tempfile::tempdir().unwrap();
        let blocker = dir.path().join("file");
        std::fs::write(&blocker, b"not a directory").unwrap();
        let mut store = FileCheckpointStore::new(blocker.join("c"), Duration::from_secs(1));
        store.put("k", b"bytes");
        assert!(store.write("k", b"bytes").is_err());
        assert_eq!(store.get("k"), None);
    }
}
