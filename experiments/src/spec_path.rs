//! What every experiment spec shares: the error type and the dotted-path `--set` that works on
//! the spec's JSON form, so every field is addressable without a hand-kept list.

use std::fmt::Write as _;

use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::Value;

/// Why a spec (or a `--set`) is not usable. The message names the path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// `path` does not exist; `valid` lists the keys at the level where the walk stopped.
    #[error("unknown spec path {path:?}: no key {key:?} here (valid keys: {valid})")]
    UnknownPath {
        path: String,
        key: String,
        valid: String,
    },
    /// The path exists but the new value does not fit its type.
    #[error("cannot set {path:?} to {value}: {reason}")]
    BadValue {
        path: String,
        value: String,
        reason: String,
    },
    /// An assignment was not `key=value`.
    #[error("expected key=value, got {0:?}")]
    NotAnAssignment(String),
    /// A field has an impossible value.
    #[error("{path}: {reason}")]
    Invalid { path: String, reason: String },
    /// Not a valid spec document (the message names the spec type).
    #[error("{0}")]
    Parse(String),
}

/// A [`SpecError::Invalid`] for `path`.
pub(crate) fn invalid(path: &str, reason: impl std::fmt::Display) -> SpecError {
    SpecError::Invalid {
        path: path.to_owned(),
        reason: reason.to_string(),
    }
}

/// Parses a spec document; the error names the spec type.
pub(crate) fn parse<T: DeserializeOwned>(text: &str, type_name: &str) -> Result<T, SpecError> {
    serde_json::from_str(text)
        .map_err(|e| SpecError::Parse(format!("spec is not valid JSON for {type_name}: {e}")))
}

/// `spec` with the field at the dotted `path` set to `value` (JSON if it parses as JSON, else
/// a string). The spec is serialised, the value replaced and the result deserialised back,
/// which type-checks the new value. Unknown paths name the valid keys where the walk stopped.
pub(crate) fn set_path<T: Serialize + DeserializeOwned>(
    spec: &T,
    path: &str,
    value: &str,
) -> Result<T, SpecError> {
    let parsed: Value =
        serde_json::from_str(value).unwrap_or_else(|_| Value::String(value.to_owned()));
    let mut doc = serde_json::to_value(spec).expect("specs always serialise");
    let mut node = &mut doc;
    for key in path.split('.') {
        let Value::Object(map) = node else {
            return Err(SpecError::UnknownPath {
                path: path.to_owned(),
                key: key.to_owned(),
                valid: "(none: the parent is not an object)".into(),
            });
        };
        if !map.contains_key(key) {
            let mut valid = String::new();
            for (i, k) in map.keys().enumerate() {
                let _ = write!(valid, "{}{k}", if i > 0 { ", " } else { "" });
            }
            return Err(SpecError::UnknownPath {
                path: path.to_owned(),
                key: key.to_owned(),
                valid,
            });
        }
        node = map.get_mut(key).expect("checked");
    }
    *node = parsed;
    serde_json::from_value(doc).map_err(|e| SpecError::BadValue {
        path: path.to_owned(),
        value: value.to_owned(),
        reason: e.to_string(),
    })
}

/// `spec` with `key=value` assignments applied in order; an error leaves nothing applied.
pub(crate) fn apply_assignments<'a, T: Serialize + DeserializeOwned + Clone>(
    spec: &T,
    assignments: impl IntoIterator<Item = &'a str>,
) -> Result<T, SpecError> {
    let mut current = spec.clone();
    for a in assignments {
        let (key, value) = a
            .split_once('=')
            .ok_or_else(|| SpecError::NotAnAssignment(a.to_owned()))?;
        current = set_path(&current, key.trim(), value.trim())?;
    }
    Ok(current)
}
