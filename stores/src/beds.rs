//! Settled beds on disk (`<dir>/<bed key>.json`), shared by every run of a worker and by
//! `repose drill --bed-cache` and `repose shear --bed-cache`: a bed is built once per set of
//! bed inputs and reused.

use std::path::{Path, PathBuf};

use repose_experiments::soil::{BedStore, SettledBed};

/// A directory of settled beds. Reads that fail (missing, unreadable, another key) are
/// misses; writes go to a temporary name and are renamed, so a concurrent reader — another
/// slot or another worker sharing the directory — never sees half a bed.
#[derive(Debug, Clone)]
pub struct FileBedStore {
    dir: PathBuf,
}

impl FileBedStore {
    /// A store in `dir` (created on the first write).
    pub fn new(dir: impl Into<PathBuf>) -> FileBedStore {
        FileBedStore { dir: dir.into() }
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.json"))
    }

    /// Writes `bed`; the error says which file could not be written.
    pub fn write(&self, bed: &SettledBed) -> std::io::Result<()> {
        let json = serde_json::to_vec(bed).map_err(std::io::Error::other)?;
        crate::checkpoints::write_atomically(&self.path(&bed.key), &json)
    }
}

impl BedStore for FileBedStore {
    fn get(&mut self, key: &str) -> Option<SettledBed> {
        let text = std::fs::read(self.path(key)).ok()?;
        let bed: SettledBed = serde_json::from_slice(&text).ok()?;
        (bed.key == key).then_some(bed)
    }

    fn put(&mut self, bed: &SettledBed) {
        if let Err(e) = self.write(bed) {
            tracing::warn!(dir = %self.dir.display(), error = %e, "cannot keep the settled bed");
        }
    }
}

#[cfg(test)]
mod tests {
    use repose_experiments::soil::SettledBy;

    use super::*;

    fn bed(key: &str) -> SettledBed {
        SettledBed {
            key: key.to_owned(),
            positions: vec![[0.1, -0.0, 1.0 / 3.0]],
            velocities: vec![[0.0; 3]],
            angular_velocities: vec![[1e-300, 0.0, 0.0]],
            radii: vec![0.003],
            surface_z: 0.1,
            settled: true,
            settled_by: SettledBy::KineticEnergy,
            kinetic_energy_ratio: 1e-5,
            simulated_time_s: 0.5,
            steps: 1000,
            wall_time_s: 2.0,
            escaped: 0,
        }
    }

    #[test]
    fn a_written_bed_reads_back_bit_for_bit_under_its_key_only() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileBedStore::new(dir.path().join("beds"));
        store.put(&bed("bed-v2-aaaa"));
        assert_eq!(store.get("bed-v2-aaaa"), Some(bed("bed-v2-aaaa")));
        assert!(store.get("bed-v2-bbbb").is_none());
        // A file under one key holding another key's bed is not trusted.
        std::fs::copy(store.path("bed-v2-aaaa"), store.path("bed-v2-cccc")).unwrap();
        assert!(store.get("bed-v2-cccc").is_none());
        // No temporary files are left behind.
        let names: Vec<_> = std::fs::read_dir(store.dir()).unwrap().collect();
        assert_eq!(names.len(), 2);
    }

    #[test]
    fn a_missing_or_foreign_bed_is_a_miss() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileBedStore::new(dir.path().join("beds"));
        assert!(store.get("bed-v2-0000").is_none(), "missing");
        std::fs::create_dir_all(store.dir()).unwrap();
        std::fs::write(store.path("bed-v2-0000"), "not json").unwrap();
        assert!(store.get("bed-v2-0000").is_none(), "unreadable");
    }
}
