//! Which worker versions a server accepts.
//!
//! The rule: a worker is accepted when its release has the same `MAJOR.MINOR` as the server's
//! (`0.1.0` and `0.1.7` work together; `0.1.x` and `0.2.x` do not, in either direction).
//! Patch releases never change the worker protocol or the meaning of a result; anything that
//! does bumps the minor version. The server checks at registration and again at a worker's
//! first claim after the server started (so workers that outlive a server upgrade are refused
//! too); the refusal names both versions, and the worker exits instead of retrying.

use std::fmt;
use std::str::FromStr;

/// This build's release (the workspace version, shared by server, worker and command line).
pub const RELEASE: &str = env!("CARGO_PKG_VERSION");

/// A release version `MAJOR.MINOR.PATCH`, optionally with a `-pre` or `+build` suffix (ignored
/// by the compatibility rule).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct ReleaseVersion {
    /// Incompatible changes of everything.
    pub major: u64,
    /// Changes of the worker protocol or of results.
    pub minor: u64,
    /// Fixes that change neither.
    pub patch: u64,
}

/// A version string that is not `MAJOR.MINOR.PATCH`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("`{0}` is not a release version (expected MAJOR.MINOR.PATCH, e.g. {RELEASE})")]
pub struct BadRelease(pub String);

impl FromStr for ReleaseVersion {
    type Err = BadRelease;

    fn from_str(text: &str) -> Result<Self, BadRelease> {
        let core = text.split(['-', '+']).next().unwrap_or_default();
        let mut parts = core.split('.').map(|part| {
            (!part.is_empty() && part.bytes().all(|b| b.is_ascii_digit()))
                .then(|| part.parse::<u64>().ok())
                .flatten()
        });
        match (parts.next(), parts.next(), parts.next(), parts.next()) {
            (Some(Some(major)), Some(Some(minor)), Some(Some(patch)), None) => Ok(ReleaseVersion {
                major,
                minor,
                patch,
            }),
            _ => Err(BadRelease(text.to_owned())),
        }
    }
}

impl fmt::Display for ReleaseVersion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

impl ReleaseVersion {
    /// This build's release.
    pub fn current() -> ReleaseVersion {
        RELEASE.parse().unwrap_or(ReleaseVersion {
            major: 0,
            minor: 0,
            patch: 0,
        })
    }

    /// Whether a worker of release `worker` may work for a server of this release.
    pub fn accepts_worker(self, worker: ReleaseVersion) -> bool {
        self.major == worker.major && self.minor == worker.minor
    }
}

/// Why a server refuses a worker's version; its text names both versions.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum VersionRefusal {
    /// The worker sent something that is not a version.
    #[error("worker version {0}; this server runs repose {server}", server = RELEASE)]
    Unreadable(BadRelease),
    /// Another `MAJOR.MINOR`.
    #[error(
        "worker version {worker} is not compatible with server version {server}: workers must \
         run the server's release {major}.{minor}.x; {advice}"
    )]
    Incompatible {
        /// The worker's release as sent.
        worker: String,
        /// The server's release.
        server: ReleaseVersion,
        /// The server's major version.
        major: u64,
        /// The server's minor version.
        minor: u64,
        /// Which side to upgrade.
        advice: &'static str,
    },
}

/// The server's check of a worker's version string against the server release `server`.
pub fn check_worker_version(server: ReleaseVersion, worker: &str) -> Result<(), VersionRefusal> {
    let release: ReleaseVersion = worker.parse().map_err(VersionRefusal::Unreadable)?;
    if server.accepts_worker(release) {
        return Ok(());
    }
    Err(VersionRefusal::Incompatible {
        worker: worker.to_owned(),
        server,
        major: server.major,
        minor: server.minor,
        advice: if release < server {
            "upgrade the worker"
        } else {
            "upgrade the server, or run a worker of the server's release"
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn release(text: &str) -> ReleaseVersion {
        text.parse().unwrap()
    }

    #[test]
    fn versions_parse_once_and_bad_ones_are_named() {
        assert_eq!(
            release("1.22.3-rc.1+abc"),
            ReleaseVersion {
                major: 1,
                minor: 22,
                patch: 3
            }
        );
        for bad in [
            "", "1", "1.2", "1.2.3.4", "v1.2.3", "1..3", "1.2.x", "test", "+1.2.3",
        ] {
            let err = bad.parse::<ReleaseVersion>().unwrap_err();
            assert_eq!(err.0, bad);
        }
        assert!(ReleaseVersion::current() > release("0.0.0") || RELEASE == "0.0.0");
        assert_eq!(
            ReleaseVersion::current().to_string(),
            RELEASE.split('-').next().unwrap()
        );
    }

    #[test]
    fn same_major_minor_is_compatible_in_both_directions_and_nothing_else() {
        let server = release("0.4.2");
        assert!(check_worker_version(server, "0.4.0").is_ok());
        assert!(check_worker_version(server, "0.4.9-dev").is_ok());
        let older = check_worker_version(server, "0.3.7")
            .unwrap_err()
            .to_string();
        assert!(
            older.contains("0.3.7") && older.contains("0.4.2"),
            "{older}"
        );
        assert!(older.contains("upgrade the worker"), "{older}");
        let newer = check_worker_version(server, "0.5.0")
            .unwrap_err()
            .to_string();
        assert!(
            newer.contains("0.5.0") && newer.contains("0.4.2"),
            "{newer}"
        );
        assert!(newer.contains("upgrade the server"), "{newer}");
        assert!(check_worker_version(server, "1.4.2").is_err());
        let garbage = check_worker_version(server, "t").unwrap_err().to_string();
        assert!(
            garbage.contains("`t`") && garbage.contains(RELEASE),
            "{garbage}"
        );
    }
}
