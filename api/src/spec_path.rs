//! Writing factor values into an experiment spec at dotted paths.
//!
//! Lives in the wire crate because the server validates paths at submission and a worker (or a
//! person debugging one run) may want to reproduce exactly what the server sent.

use serde_json::Value;

/// Why a dotted path cannot receive a factor value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SpecPathError {
    /// The path is empty or has an empty segment (`a..b`).
    #[error("path `{path}` is empty or has an empty segment")]
    Malformed {
        /// The path as given.
        path: String,
    },
    /// A segment names a key or index the spec does not have.
    #[error("path `{path}` does not exist in the spec (no `{segment}` under `{parent}`)")]
    Missing {
        /// The path as given.
        path: String,
        /// The first segment that was not found.
        segment: String,
        /// The part of the path that did exist (`<root>` at the top).
        parent: String,
    },
    /// The path ends at something other than a number (an object, a string, …).
    #[error("path `{path}` points at {found}, not a number")]
    NotANumber {
        /// The path as given.
        path: String,
        /// JSON type found there.
        found: &'static str,
    },
}

/// Returns a copy of `spec` with each `(path, value)` written at its dotted path.
///
/// Segments select object keys, or array elements when the segment is a decimal index
/// (`particles.0.radius`). The target must already exist and hold a number, so a typo in a
/// path is an error rather than a silently ignored new key the simulation never reads.
pub fn apply_factor_values<'a>(
    spec: &Value,
    assignments: impl IntoIterator<Item = (&'a str, f64)>,
) -> Result<Value, SpecPathError> {
    let mut out = spec.clone();
    for (path, value) in assignments {
        let slot = locate_mut(&mut out, path)?;
        if !slot.is_number() {
            return Err(SpecPathError::NotANumber {
                path: path.to_owned(),
                found: json_type(slot),
            });
        }
        *slot = serde_json::Number::from_f64(value)
            .map(Value::Number)
            .unwrap_or(Value::Null);
    }
    Ok(out)
}

fn locate_mut<'v>(root: &'v mut Value, path: &str) -> Result<&'v mut Value, SpecPathError> {
    if path.is_empty() || path.split('.').any(str::is_empty) {
        return Err(SpecPathError::Malformed {
            path: path.to_owned(),
        });
    }
    let mut current = root;
    let mut walked: Vec<&str> = Vec::new();
    for segment in path.split('.') {
        let next = match current {
            Value::Object(map) => map.get_mut(segment),
            Value::Array(items) => segment
                .parse::<usize>()
                .ok()
                .and_then(move |index| items.get_mut(index)),
            _ => None,
        };
        current = next.ok_or_else(|| SpecPathError::Missing {
            path: path.to_owned(),
            segment: segment.to_owned(),
            parent: if walked.is_empty() {
                "<root>".to_owned()
            } else {
                walked.join(".")
            },
        })?;
        walked.push(segment);
    }
    Ok(current)
}

fn json_type(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn writes_nested_keys_and_array_elements() {
        let spec = json!({"material": {"mu": 0.1}, "particles": [{"r": 1.0}, {"r": 2.0}]});
        let out =
            apply_factor_values(&spec, [("material.mu", 0.5), ("particles.1.r", 3.0)]).unwrap();
        assert_eq!(
            out,
            json!({"material": {"mu": 0.5}, "particles": [{"r": 1.0}, {"r": 3.0}]})
        );
    }

    #[test]
    fn missing_path_names_the_segment() {
        let spec = json!({"material": {"mu": 0.1}});
        let err = apply_factor_values(&spec, [("material.nu", 0.5)]).unwrap_err();
        assert!(
            matches!(&err, SpecPathError::Missing { segment, parent, .. } if segment == "nu" && parent == "material"),
            "{err}"
        );
    }

    #[test]
    fn non_numeric_target_and_malformed_paths_are_rejected() {
        let spec = json!({"material": {"mu": 0.1}});
        assert!(matches!(
            apply_factor_values(&spec, [("material", 0.5)]),
            Err(SpecPathError::NotANumber { .. })
        ));
        assert!(matches!(
            apply_factor_values(&spec, [("material..mu", 0.5)]),
            Err(SpecPathError::Malformed { .. })
        ));
    }
}
