//! Writing factor values into an experiment spec at dotted paths.
//!
//! Lives in the wire crate because the server validates paths at submission and a worker (or a
//! person debugging one run) may want to reproduce exactly what the server sent.

use serde_json::Value;

/// Why a dotted path cannot be walked or cannot receive a factor value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SpecPathError {
    /// The path is empty or has an empty segment (`a..b`).
    #[error("path `{path}` is empty or has an empty segment")]
    Malformed {
        /// The path as given.
        path: String,
    },
    /// A segment names a key or index the spec does not have.
    #[error("path `{path}` does not exist in the spec (no `{segment}` under `{parent}`; {valid})")]
    Missing {
        /// The path as given.
        path: String,
        /// The first segment that was not found.
        segment: String,
        /// The part of the path that did exist (`<root>` at the top).
        parent: String,
        /// What the parent does offer: its keys, its index range, or that it is neither an
        /// object nor an array.
        valid: String,
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

/// What a walk does where the path names an object key the document lacks. Array elements
/// are never created: an index must exist in either mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathMode {
    /// Every segment must exist (a factor's path, a `--set`): a typo is an error naming the
    /// valid keys, never a new key the simulation would not read.
    Existing,
    /// Missing object keys are created on the way (as objects) and at the end (as `null`): a
    /// campaign's spec override need not hold the key yet; merged over a preset it lands where
    /// the path points.
    CreateObjects,
}

/// The one dotted-path walker of the workspace (factor values here, `--set` in
/// `repose-experiments`, a campaign's spec overrides in `repose-campaign`).
///
/// Segments select object keys, or array elements when the segment is a decimal index
/// (`particles.0.radius`). Returns the value at `path`.
pub fn locate_mut<'v>(
    root: &'v mut Value,
    path: &str,
    mode: PathMode,
) -> Result<&'v mut Value, SpecPathError> {
    if path.is_empty() || path.split('.').any(str::is_empty) {
        return Err(SpecPathError::Malformed {
            path: path.to_owned(),
        });
    }
    let segments: Vec<&str> = path.split('.').collect();
    let mut current = root;
    for (k, &segment) in segments.iter().enumerate() {
        let missing = |valid: String| SpecPathError::Missing {
            path: path.to_owned(),
            segment: segment.to_owned(),
            parent: if k == 0 {
                "<root>".to_owned()
            } else {
                segments[..k].join(".")
            },
            valid,
        };
        current = match current {
            Value::Object(map) => {
                if !map.contains_key(segment) {
                    match mode {
                        PathMode::Existing => {
                            let keys: Vec<&str> = map.keys().map(String::as_str).collect();
                            return Err(missing(format!("valid keys: {}", keys.join(", "))));
                        }
                        PathMode::CreateObjects => {
                            let last = k + 1 == segments.len();
                            map.insert(
                                segment.to_owned(),
                                if last {
                                    Value::Null
                                } else {
                                    Value::Object(serde_json::Map::new())
                                },
                            );
                        }
                    }
                }
                map.get_mut(segment).expect("present or just inserted")
            }
            Value::Array(items) => {
                let len = items.len();
                match segment.parse::<usize>() {
                    Ok(index) if index < len => &mut items[index],
                    _ => return Err(missing(format!("valid indices: 0..{len}"))),
                }
            }
            other => {
                return Err(missing(format!(
                    "`{}` is {}, neither an object nor an array",
                    if k == 0 {
                        "<root>".to_owned()
                    } else {
                        segments[..k].join(".")
                    },
                    json_type(other)
                )))
            }
        };
    }
    Ok(current)
}

/// Returns a copy of `spec` with each `(path, value)` written at its dotted path
/// ([`PathMode::Existing`]: the target must already exist and hold a number, so a typo in a
/// path is an error rather than a silently ignored new key the simulation never reads).
pub fn apply_factor_values<'a>(
    spec: &Value,
    assignments: impl IntoIterator<Item = (&'a str, f64)>,
) -> Result<Value, SpecPathError> {
    let mut out = spec.clone();
    for (path, value) in assignments {
        let slot = locate_mut(&mut out, path, PathMode::Existing)?;
        if !slot.is_number() {
            return Err(SpecPathError::NotANumber {
                path: path.to_owned(),
                found: json_type(slot),
            });
        }
        *slot = number(value);
    }
    Ok(out)
}

/// A factor value as JSON (`null` for a non-finite one, which validation then rejects).
pub fn number(value: f64) -> Value {
    serde_json::Number::from_f64(value)
        .map(Value::Number)
        .unwrap_or(Value::Null)
}

/// The JSON type of `value`, as an error message names it.
pub fn json_type(value: &Value) -> &'static str {
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
    fn the_walker_creates_object_keys_only_when_asked_and_never_array_elements() {
        let mut spec = json!({"a": {"b": 1.0}, "list": [1.0]});
        let err = locate_mut(&mut spec, "a.c", PathMode::Existing).unwrap_err();
        assert!(err.to_string().contains("valid keys: b"), "{err}");
        *locate_mut(&mut spec, "a.c.d", PathMode::CreateObjects).unwrap() = json!(2.0);
        assert_eq!(spec["a"], json!({"b": 1.0, "c": {"d": 2.0}}));
        for mode in [PathMode::Existing, PathMode::CreateObjects] {
            let err = locate_mut(&mut spec, "list.1", mode).unwrap_err();
            assert!(err.to_string().contains("valid indices: 0..1"), "{err}");
            let err = locate_mut(&mut spec, "a.b.x", mode).unwrap_err();
            assert!(
                err.to_string().contains("neither an object nor an array"),
                "{err}"
            );
        }
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
