//! A run saved mid-way ([`AorCheckpoint`]): the spec, the whole engine world and the run loop's
//! state, as bytes the caller keeps wherever it likes (this crate does no I/O). A run resumed
//! from a checkpoint ([`super::run_aor_with_checkpoints`]) continues bit for bit as if it had
//! never stopped (tested): the world's serde form is its complete state and MessagePack keeps
//! every f64's bits.
//!
//! Bytes: the magic line [`MAGIC`], the format number (u32, little endian), then the
//! MessagePack of the build that wrote it, the spec, the loop state and the world. A checkpoint
//! is read only by a build of the same code: the release and a fingerprint of the engine's and
//! this crate's sources (`build.rs`), since other code would continue another trajectory.

use repose_engine::world::World;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::rest::RestDecision;
use super::run::SettleCheck;
use super::spec::AorSpec;

/// The first bytes of every checkpoint.
pub const MAGIC: &[u8] = b"repose aor checkpoint\n";
/// The layout after [`MAGIC`]; bumped when the loop state or the world's serde form changes.
pub const FORMAT: u32 = 1;
/// The release and the fingerprint of the code that decides a trajectory, e.g.
/// `0.1.0+3f0c…`.
const RELEASE: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    "+",
    env!("REPOSE_TRAJECTORY_CODE")
);

/// Why bytes are not a checkpoint this run can continue from.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CheckpointError {
    #[error(
        "not an angle-of-repose checkpoint (the file does not start with the checkpoint header)"
    )]
    NotACheckpoint,
    #[error("checkpoint format {found}; this build reads format {expected}")]
    Format { found: u32, expected: u32 },
    #[error("checkpoint written by build {found}; this build is {expected} (other engine or experiment code) and would continue another trajectory")]
    Release { found: String, expected: String },
    #[error("the checkpoint is damaged: {0}")]
    Corrupt(String),
    /// The checkpoint belongs to another experiment: `path` is the first spec field that differs.
    #[error(
        "the checkpoint was written for another spec: `{path}` is {saved} there and {given} here"
    )]
    OtherSpec {
        path: String,
        saved: String,
        given: String,
    },
}

/// The run loop's state between two steps: everything besides the world that decides what
/// the loop does next.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct LoopState {
    pub heap_top: f64,
    pub ready_after: f64,
    pub insertion_end: Option<f64>,
    pub checks: Vec<SettleCheck>,
    pub decision: RestDecision,
    pub next_check: f64,
    pub deadline: f64,
    /// Wall-clock seconds spent by the run before this point (all earlier segments).
    pub wall_time_s: f64,
    // Fields added after format 1 go below, each with a default: MessagePack keeps a struct as
    // an array, so a checkpoint written before the field existed reads with the default only
    // if the field is last (tested).
    /// Funnel runs: (time, mass below the outlet in kg) every check interval, which tells a
    /// jammed funnel from one still draining when a cap ends the run.
    #[serde(default)]
    pub below_outlet: Vec<(f64, f64)>,
}

#[derive(Serialize)]
struct Written<'a> {
    release: &'a str,
    spec: &'a AorSpec,
    state: &'a LoopState,
    world: &'a World,
}

#[derive(Deserialize)]
struct Read {
    release: String,
    spec: AorSpec,
    state: LoopState,
    world: World,
}

pub(super) fn encode(spec: &AorSpec, state: &LoopState, world: &World) -> Vec<u8> {
    let mut bytes = MAGIC.to_vec();
    bytes.extend_from_slice(&FORMAT.to_le_bytes());
    let body = Written {
        release: RELEASE,
        spec,
        state,
        world,
    };
    rmp_serde::encode::write(&mut bytes, &body).expect("a run's state serialises");
    bytes
}

/// The name a store keeps the checkpoints of runs of `spec` under:
/// `aor-v{FORMAT}-{16 hex digits}`, a 64-bit FNV-1a hash of the spec's JSON (seed included) and
/// of the release. Runs of equal specs follow one trajectory, so any of them may continue from it.
pub fn checkpoint_key(spec: &AorSpec) -> String {
    let json = serde_json::to_string(&(RELEASE, spec)).expect("specs serialise");
    format!("aor-v{FORMAT}-{:016x}", crate::fnv1a(json.as_bytes()))
}

/// A run saved between two steps.
#[derive(Debug, Clone)]
pub struct AorCheckpoint {
    pub(super) spec: AorSpec,
    pub(super) state: LoopState,
    pub(super) world: World,
}

impl AorCheckpoint {
    /// Reads the bytes a run handed to its checkpoint callback.
    pub fn from_bytes(bytes: &[u8]) -> Result<AorCheckpoint, CheckpointError> {
        let rest = bytes
            .strip_prefix(MAGIC)
            .ok_or(CheckpointError::NotACheckpoint)?;
        let (format, body) = rest
            .split_first_chunk::<4>()
            .ok_or_else(|| CheckpointError::Corrupt("it ends inside its header".into()))?;
        let found = u32::from_le_bytes(*format);
        if found != FORMAT {
            return Err(CheckpointError::Format {
                found,
                expected: FORMAT,
            });
        }
        let read: Read =
            rmp_serde::from_slice(body).map_err(|e| CheckpointError::Corrupt(e.to_string()))?;
        if read.release != RELEASE {
            return Err(CheckpointError::Release {
                found: read.release,
                expected: RELEASE.into(),
            });
        }
        Ok(AorCheckpoint {
            spec: read.spec,
            state: read.state,
            world: read.world,
        })
    }

    /// The spec the run was started with.
    pub fn spec(&self) -> &AorSpec {
        &self.spec
    }

    /// Simulated time at the save, s.
    pub fn simulated_time(&self) -> f64 {
        self.world.time()
    }

    /// Steps done at the save.
    pub fn steps(&self) -> u64 {
        self.world.steps()
    }

    /// Grains in the world at the save.
    pub fn particles(&self) -> usize {
        self.world.particles().len()
    }

    /// Wall-clock seconds the run had spent when it was saved.
    pub fn wall_time_s(&self) -> f64 {
        self.state.wall_time_s
    }

    /// Ok if this checkpoint continues a run of `spec`; else the first field that differs.
    pub fn check_spec(&self, spec: &AorSpec) -> Result<(), CheckpointError> {
        if &self.spec == spec {
            return Ok(());
        }
        let saved = serde_json::to_value(&self.spec).expect("specs serialise");
        let given = serde_json::to_value(spec).expect("specs serialise");
        let (path, saved, given) = first_difference(&saved, &given, String::new())
            .unwrap_or_else(|| ("(spec)".into(), "one value".into(), "another".into()));
        Err(CheckpointError::OtherSpec { path, saved, given })
    }
}

/// The first dotted path where `a` and `b` differ, with both values as JSON text.
fn first_difference(a: &Value, b: &Value, path: String) -> Option<(String, String, String)> {
    let join = |key: &str| {
        if path.is_empty() {
            key.to_owned()
        } else {
            format!("{path}.{key}")
        }
    };
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| match (x.get(k), y.get(k)) {
                (Some(u), Some(v)) => first_difference(u, v, join(k)),
                (u, v) => Some((join(k), show(u), show(v))),
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (u, v))| first_difference(u, v, join(&i.to_string()))),
        _ if a == b => None,
        _ => Some((
            if path.is_empty() {
                "(spec)".into()
            } else {
                path
            },
            a.to_string(),
            b.to_string(),
        )),
    }
}

fn show(v: Option<&Value>) -> String {
    v.map_or_else(|| "absent".into(), Value::to_string)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_differing_field_is_named_with_both_values() {
        let a = serde_json::json!({"seed": 1, "funnel": {"outlet_diameter": 0.017}, "x": [1, 2]});
        let b = serde_json::json!({"seed": 1, "funnel": {"outlet_diameter": 0.02}, "x": [1, 2]});
        assert_eq!(
            first_difference(&a, &b, String::new()),
            Some((
                "funnel.outlet_diameter".into(),
                "0.017".into(),
                "0.02".into()
            ))
        );
        let c = serde_json::json!({"seed": 1, "funnel": {"outlet_diameter": 0.017}, "x": [1, 3]});
        assert_eq!(
            first_difference(&a, &c, String::new()),
            Some(("x.1".into(), "2".into(), "3".into()))
        );
        assert_eq!(first_difference(&a, &a, String::new()), None);
    }

    #[test]
    fn a_loop_state_written_before_its_newest_field_reads_with_the_default() {
        // The layout of format 1 as the first builds wrote it (2026-11-25, 6ca2e4f).
        #[derive(Serialize)]
        struct LoopStateAsFirstWritten {
            heap_top: f64,
            ready_after: f64,
            insertion_end: Option<f64>,
            checks: Vec<SettleCheck>,
            decision: RestDecision,
            next_check: f64,
            deadline: f64,
            wall_time_s: f64,
        }
        let old = LoopStateAsFirstWritten {
            heap_top: 0.1,
            ready_after: 0.2,
            insertion_end: Some(2.0),
            checks: Vec::new(),
            decision: RestDecision::AtRest,
            next_check: 2.1,
            deadline: 6.0,
            wall_time_s: 1430.8,
        };
        let bytes = rmp_serde::to_vec(&old).unwrap();
        let read: LoopState = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!(read.wall_time_s, 1430.8);
        assert_eq!(read.deadline, 6.0);
        assert!(read.below_outlet.is_empty());
    }

    #[test]
    fn a_checkpoint_of_other_code_is_refused() {
        let spec = AorSpec::fast();
        let world = World::new(
            spec.material_set().build().unwrap(),
            repose_engine::world::WorldConfig::new(
                1e-5,
                repose_engine::neighbor::Domain::closed(
                    repose_engine::math::Vec3::zeros(),
                    repose_engine::math::Vec3::repeat(1.0),
                ),
            ),
        )
        .unwrap();
        let state = LoopState {
            heap_top: 0.1,
            ready_after: 0.2,
            insertion_end: None,
            checks: Vec::new(),
            decision: RestDecision::AtRest,
            next_check: 0.3,
            deadline: 1.0,
            wall_time_s: 0.0,
            below_outlet: Vec::new(),
        };
        let ours = encode(&spec, &state, &world);
        assert!(AorCheckpoint::from_bytes(&ours).is_ok());
        let mut other = MAGIC.to_vec();
        other.extend_from_slice(&FORMAT.to_le_bytes());
        let body = Written {
            release: "0.1.0+0000000000000000",
            spec: &spec,
            state: &state,
            world: &world,
        };
        rmp_serde::encode::write(&mut other, &body).unwrap();
        let err = AorCheckpoint::from_bytes(&other).unwrap_err();
        assert!(
            matches!(&err, CheckpointError::Release { found, .. } if found == "0.1.0+0000000000000000"),
            "{err}"
        );
        assert!(RELEASE.starts_with(concat!(env!("CARGO_PKG_VERSION"), "+")));
        assert_eq!(RELEASE.len(), env!("CARGO_PKG_VERSION").len() + 17);
    }

    #[test]
    fn bytes_that_are_not_a_checkpoint_say_so() {
        assert_eq!(
            AorCheckpoint::from_bytes(b"{\"status\":\"ok\"}").unwrap_err(),
            CheckpointError::NotACheckpoint
        );
        let mut other_format = MAGIC.to_vec();
        other_format.extend_from_slice(&(FORMAT + 1).to_le_bytes());
        assert_eq!(
            AorCheckpoint::from_bytes(&other_format).unwrap_err(),
            CheckpointError::Format {
                found: FORMAT + 1,
                expected: FORMAT
            }
        );
        let mut truncated = MAGIC.to_vec();
        truncated.extend_from_slice(&FORMAT.to_le_bytes());
        truncated.extend_from_slice(&[0x93, 0x01]);
        assert!(matches!(
            AorCheckpoint::from_bytes(&truncated),
            Err(CheckpointError::Corrupt(_))
        ));
    }
}
