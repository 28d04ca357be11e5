//! What every experiment spec shares: the error type and the dotted-path `--set` that works on
//! the spec's JSON form, so every field is addressable without a hand-kept list. The walk is
//! the workspace's one dotted-path walker, `repose_api::locate_mut`, in its `Existing` mode.

use repose_api::{locate_mut, PathMode, SpecPathError};
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::Value;

use crate::experiment::InvalidField;

/// Why a spec (or a `--set`) is not usable. The message names the path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// `path` does not exist; `valid` says what the level where the walk stopped offers (its
    /// keys, or its index range).
    #[error("unknown spec path {path:?}: no key {key:?} here ({valid})")]
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

impl InvalidField for SpecError {
    fn path(&self) -> Option<&str> {
        match self {
            SpecError::Invalid { path, .. } => Some(path),
            _ => None,
        }
    }
}

/// What every experiment spec offers: its presets, JSON, the dotted-path `--set` and
/// validation. Each spec names its presets and checks its fields; the rest is shared here.
pub trait Spec: Serialize + DeserializeOwned + Clone {
    /// The spec's name in messages ("an AorSpec").
    const NAME: &'static str;
    /// The preset names [`Spec::preset`] accepts (aliases aside).
    const PRESETS: &'static [&'static str];

    /// The named preset; an unknown name is an error listing [`Spec::PRESETS`].
    fn preset(name: &str) -> Result<Self, SpecError>
    where
        Self: Sized;

    /// Every field checked; the error names the first bad field's path.
    fn validate(&self) -> Result<(), SpecError>;

    /// Parses a JSON spec document.
    fn from_json(text: &str) -> Result<Self, SpecError>
    where
        Self: Sized,
    {
        parse(text, Self::NAME)
    }

    /// Pretty JSON.
    fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("specs always serialise")
    }

    /// Sets the field at the dotted `path` to `value` (JSON if it parses as JSON, else a
    /// string). Every field is addressable (array elements by index); unknown paths are an
    /// error naming the path and what the level where the walk stopped offers. The spec is
    /// unchanged on error.
    fn set(&mut self, path: &str, value: &str) -> Result<(), SpecError>
    where
        Self: Sized,
    {
        *self = set_path(&*self, path, value)?;
        Ok(())
    }

    /// Applies `key=value` assignments in order; on error none is applied.
    fn apply_assignments<'a>(
        &mut self,
        assignments: impl IntoIterator<Item = &'a str>,
    ) -> Result<(), SpecError>
    where
        Self: Sized,
    {
        *self = apply_assignments(&*self, assignments)?;
        Ok(())
    }
}

/// The error of [`Spec::preset`] for a name it does not know.
pub(crate) fn unknown_preset<S: Spec>(name: &str) -> SpecError {
    invalid(
        "preset",
        format!(
            "unknown preset {name:?} (presets: {})",
            S::PRESETS.join(", ")
        ),
    )
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
fn set_path<T: Serialize + DeserializeOwned>(
    spec: &T,
    path: &str,
    value: &str,
) -> Result<T, SpecError> {
    let parsed: Value =
        serde_json::from_str(value).unwrap_or_else(|_| Value::String(value.to_owned()));
    let mut doc = serde_json::to_value(spec).expect("specs always serialise");
    let node = locate_mut(&mut doc, path, PathMode::Existing).map_err(|e| match e {
        SpecPathError::Missing { segment, valid, .. } => SpecError::UnknownPath {
            path: path.to_owned(),
            key: segment,
            valid,
        },
        other => SpecError::UnknownPath {
            path: path.to_owned(),
            key: path.to_owned(),
            valid: other.to_string(),
        },
    })?;
    *node = parsed;
    serde_json::from_value(doc).map_err(|e| SpecError::BadValue {
        path: path.to_owned(),
        value: value.to_owned(),
        reason: e.to_string(),
    })
}

/// `spec` with `key=value` assignments applied in order; an error leaves nothing applied.
fn apply_assignments<'a, T: Serialize + DeserializeOwned + Clone>(
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
