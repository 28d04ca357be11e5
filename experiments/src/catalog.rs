//! The experiment kinds a job can name, behind one interface: the server uses
//! [`Kind::prepare`] (or [`prepare_spec`]) and [`ExperimentSpec::parse`] (or [`validate_spec`])
//! at submission (so a bad spec is a 422, not a dead job), a worker parses a job once into an
//! [`ExperimentSpec`] and [runs](ExperimentSpec::run) it to turn it into metrics.
//!
//! Specs travel as JSON because the job server stores and edits them (factor values are
//! written at dotted paths) without knowing each kind's Rust type. Each kind is an
//! [`Experiment`] in its own folder; the `registry!` call below names them, one
//! line per kind, and [`registry!`] makes of it the [`Kind`] enum, the names, the parsed-spec
//! enum and every dispatch (one line per kind each, like mini-redis's `Command`).

use serde::Serialize;
use serde_json::Value;

use crate::backend::{BackendKind, Engine};
pub use crate::experiment::{CheckpointStore, Experiment, ExperimentError, NoCheckpoints, Outcome};
use crate::progress::Control;
pub use crate::soil::{BedStore, NoBedStore};

/// Makes, from one line per kind (`Variant = Type`, the type an [`Experiment`]), the kind
/// enum [`Kind`] with its names ([`KINDS`]) and presets, the parsed-spec enum
/// [`ExperimentSpec`] and its dispatch.
macro_rules! registry {
    ($($(#[$doc:meta])* $variant:ident = $kind:ty),+ $(,)?) => {
        /// An experiment kind, parsed once from its name ([`Kind::parse`]) and dispatched by
        /// `match`.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum Kind {
            $($(#[$doc])* $variant,)+
        }

        /// Names of the kinds a job may give (`Kind::ALL`'s names).
        pub const KINDS: [&str; [$(<$kind as Experiment>::NAME),+].len()] =
            [$(<$kind as Experiment>::NAME),+];

        impl Kind {
            /// Every kind, in the order [`KINDS`] names them.
            pub const ALL: [Kind; KINDS.len()] = [$(Kind::$variant),+];

            /// The name a job gives.
            pub fn name(self) -> &'static str {
                match self {
                    $(Kind::$variant => <$kind as Experiment>::NAME,)+
                }
            }

            /// Presets the kind offers (the first is its default).
            pub fn presets(self) -> &'static [&'static str] {
                match self {
                    $(Kind::$variant => <$kind as Experiment>::PRESETS,)+
                }
            }

            /// The engines that run every spec of the kind.
            pub fn backends(self) -> &'static [BackendKind] {
                match self {
                    $(Kind::$variant => <$kind as Experiment>::BACKENDS,)+
                }
            }

            /// The complete spec: `overrides` merged over `preset` (objects key by key, see
            /// [`merge_json`]), parsed and checked. Without a preset a kind that has presets
            /// starts from its default one; a kind without presets takes the overrides as the
            /// whole spec.
            pub fn prepare(
                self,
                preset: Option<&str>,
                overrides: &Value,
            ) -> Result<ExperimentSpec, ExperimentError> {
                Ok(match self {
                    $(Kind::$variant => {
                        ExperimentSpec::$variant(prepare::<$kind>(preset, overrides)?)
                    })+
                })
            }
        }

        /// A spec parsed and checked for its kind: the typed form every entry point works on
        /// (parsed once, like mini-redis's `Command`), each method one line per kind.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(untagged)]
        pub enum ExperimentSpec {
            $($variant(<$kind as Experiment>::Spec),)+
        }

        impl ExperimentSpec {
            /// Parses and validates `spec` as a complete spec of `kind`.
            pub fn parse(kind: Kind, spec: &Value) -> Result<ExperimentSpec, ExperimentError> {
                Ok(match kind {
                    $(Kind::$variant => ExperimentSpec::$variant(<$kind>::parse(spec)?),)+
                })
            }

            pub fn kind(&self) -> Kind {
                match self {
                    $(ExperimentSpec::$variant(_) => Kind::$variant,)+
                }
            }

            /// [`ExperimentSpec::run`] on `engine`; a kind or spec the engine does not run is
            /// refused ([`ExperimentSpec::check_backend`]'s error), never run on the CPU
            /// instead. A run on the GPU keeps no checkpoint.
            pub fn run_on(
                self,
                engine: Engine<'_>,
                seed: u64,
                progress: &mut dyn FnMut(f64) -> Control,
                beds: &mut dyn BedStore,
                checkpoints: &mut dyn CheckpointStore,
            ) -> Result<Outcome, ExperimentError> {
                let (p, b, c, e) = (progress, beds, checkpoints, engine);
                match self {
                    $(ExperimentSpec::$variant(s) => <$kind>::run_on(s, seed, e, p, b, c),)+
                }
            }

            /// Ok if the `backend` engine runs this spec; else
            /// [`ExperimentError::Unsupported`], naming what it lacks. A job server asks at
            /// submission, before any worker opens a GPU.
            pub fn check_backend(&self, backend: BackendKind) -> Result<(), ExperimentError> {
                match self {
                    $(ExperimentSpec::$variant(s) => <$kind>::check_backend(s, backend),)+
                }
            }

            /// The key under which the run with `seed` keeps its checkpoint, for a kind that
            /// keeps checkpoints (angle of repose). A worker uses it to drop the checkpoint of
            /// a run nobody will continue.
            pub fn checkpoint_key(&self, seed: u64) -> Option<String> {
                match self {
                    $(ExperimentSpec::$variant(s) => <$kind>::checkpoint_key(s, seed),)+
                }
            }

            /// The key of the settled bed the run with `seed` builds or reuses, for a kind that
            /// runs on one (drilling, shear, triaxial).
            pub fn bed_key(&self, seed: u64) -> Option<String> {
                match self {
                    $(ExperimentSpec::$variant(s) => <$kind>::bed_key(s, seed),)+
                }
            }
        }
    };
}

registry! {
    /// Angle of repose (`aor`).
    Aor = crate::aor::Aor,
    /// The drilling (pore-forming) test (`drill`).
    Drill = crate::drill::Drill,
    /// The direct shear test (`shear`).
    Shear = crate::shear::Shear,
    /// The drained triaxial compression test (`triaxial`).
    Triaxial = crate::triaxial::Triaxial,
    /// The test aid that answers from a table of known results (`table_lookup`).
    TableLookup = crate::replay::TableLookup,
    /// The test aid that answers with closed forms and seeded noise (`formula`).
    Formula = crate::formula::Formula,
}

impl Kind {
    /// The kind called `name`.
    pub fn parse(name: &str) -> Result<Kind, ExperimentError> {
        Kind::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| ExperimentError::UnknownKind {
                kind: name.into(),
                known: &KINDS,
            })
    }
}

impl std::str::FromStr for Kind {
    type Err = ExperimentError;
    fn from_str(name: &str) -> Result<Kind, ExperimentError> {
        Kind::parse(name)
    }
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// [`Kind::prepare`] for the kind `E`.
fn prepare<E: Experiment>(
    preset: Option<&str>,
    overrides: &Value,
) -> Result<E::Spec, ExperimentError> {
    let unknown_preset = |valid: String| ExperimentError::UnknownPreset {
        kind: E::NAME.into(),
        preset: preset.unwrap_or_default().into(),
        valid,
    };
    let spec = match E::PRESETS.first() {
        Some(default) => {
            let base = E::preset(preset.unwrap_or(default))
                .ok_or_else(|| unknown_preset(E::PRESETS.join(", ")))?;
            let base = serde_json::to_value(base).expect("specs serialise");
            merge_json(base, overrides.clone())
        }
        None if preset.is_some() => return Err(unknown_preset("(none)".into())),
        None => overrides.clone(),
    };
    E::parse(&spec)
}

impl ExperimentSpec {
    /// A job's kind (by name) and spec, parsed once.
    pub fn parse_job(kind: &str, spec: &Value) -> Result<ExperimentSpec, ExperimentError> {
        ExperimentSpec::parse(Kind::parse(kind)?, spec)
    }

    /// The JSON form a job carries.
    pub fn to_value(&self) -> Value {
        serde_json::to_value(self).expect("specs serialise")
    }

    /// Runs the experiment with `seed` (overriding any seed in the spec). `progress` receives
    /// the fraction done (0..1) and may cancel. Heavy kinds run on the current rayon pool.
    /// Settled beds are taken from and kept in `beds` (the outcome is the same, bit for bit,
    /// whether the bed was built or reused: `details.bed.reused` says which); runs that
    /// checkpoint (angle of repose) continue from and checkpoint to `checkpoints`, under
    /// [`ExperimentSpec::checkpoint_key`].
    pub fn run(
        self,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        self.run_on(Engine::Cpu, seed, progress, beds, checkpoints)
    }

    /// [`ExperimentSpec::checkpoint_key`] of the run on `backend`: none on the GPU (a GPU run
    /// neither keeps a checkpoint nor continues a CPU run's).
    pub fn checkpoint_key_on(&self, backend: BackendKind, seed: u64) -> Option<String> {
        match backend {
            BackendKind::Cpu => self.checkpoint_key(seed),
            BackendKind::Gpu => None,
        }
    }
}

/// Presets a kind offers (the first is its default).
pub fn presets(kind: &str) -> Result<&'static [&'static str], ExperimentError> {
    Ok(Kind::parse(kind)?.presets())
}

/// The complete spec for `kind` as JSON: [`Kind::prepare`] by the kind's name.
pub fn prepare_spec(
    kind: &str,
    preset: Option<&str>,
    overrides: &Value,
) -> Result<Value, ExperimentError> {
    Ok(Kind::parse(kind)?.prepare(preset, overrides)?.to_value())
}

/// Checks a complete spec (e.g. after factor values were written into it).
pub fn validate_spec(kind: &str, spec: &Value) -> Result<(), ExperimentError> {
    ExperimentSpec::parse_job(kind, spec).map(drop)
}

/// Runs one experiment with `seed`, without stores: [`ExperimentSpec::run`] of the job's kind
/// and spec.
pub fn run_experiment(
    kind: &str,
    spec: &Value,
    seed: u64,
    progress: &mut dyn FnMut(f64) -> Control,
) -> Result<Outcome, ExperimentError> {
    run_experiment_with_stores(
        kind,
        spec,
        seed,
        progress,
        &mut NoBedStore,
        &mut NoCheckpoints,
    )
}

/// [`run_experiment`], with settled beds taken from and kept in `beds`.
pub fn run_experiment_with_beds(
    kind: &str,
    spec: &Value,
    seed: u64,
    progress: &mut dyn FnMut(f64) -> Control,
    beds: &mut dyn BedStore,
) -> Result<Outcome, ExperimentError> {
    run_experiment_with_stores(kind, spec, seed, progress, beds, &mut NoCheckpoints)
}

/// [`run_experiment_with_beds`], with angle-of-repose runs continued from and checkpointed to
/// `checkpoints` ([`ExperimentSpec::run`]).
pub fn run_experiment_with_stores(
    kind: &str,
    spec: &Value,
    seed: u64,
    progress: &mut dyn FnMut(f64) -> Control,
    beds: &mut dyn BedStore,
    checkpoints: &mut dyn CheckpointStore,
) -> Result<Outcome, ExperimentError> {
    ExperimentSpec::parse_job(kind, spec)?.run(seed, progress, beds, checkpoints)
}

/// `over` merged into `base`: objects merge key by key, so a spec may give only what differs
/// from its preset; anything else (numbers, arrays, a tagged enum such as a size distribution
/// given whole with its `kind`, or a cohesion law with its `model`) replaces the base value.
pub fn merge_json(base: Value, over: Value) -> Value {
    match (base, over) {
        (Value::Object(mut b), Value::Object(o)) => {
            for (k, v) in o {
                let merged = match b.remove(&k) {
                    Some(old) if v.get("kind").is_none() && v.get("model").is_none() => {
                        merge_json(old, v)
                    }
                    _ => v,
                };
                b.insert(k, merged);
            }
            Value::Object(b)
        }
        (_, o) => o,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aor::AorSpec;
    use serde_json::json;

    #[test]
    fn aor_overrides_merge_over_the_preset() {
        let spec = prepare_spec(
            "aor",
            Some("fast"),
            &json!({"soil_soil": {"rolling_friction": 0.3}}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["rolling_friction"], json!(0.3));
        assert_eq!(spec["soil_soil"]["static_friction"], json!(0.442));
        assert_eq!(spec["total_mass"], json!(0.03), "fast preset kept");
        validate_spec("aor", &spec).unwrap();
    }

    #[test]
    fn bad_specs_name_the_problem() {
        let err = prepare_spec(
            "aor",
            None,
            &json!({"soil_soil": {"static_friction": -1.0}}),
        )
        .unwrap_err();
        match err {
            ExperimentError::InvalidSpec { path, .. } => {
                assert_eq!(path.as_deref(), Some("soil_soil.static_friction"))
            }
            other => panic!("unexpected {other:?}"),
        }
        let err = prepare_spec("aor", None, &json!({"funnel": {"no_such": 1}})).unwrap_err();
        assert!(err.to_string().contains("no_such"), "{err}");
        assert!(matches!(
            prepare_spec("aor", Some("huge"), &json!({})),
            Err(ExperimentError::UnknownPreset { .. })
        ));
        assert!(matches!(
            prepare_spec("cook", None, &json!({})),
            Err(ExperimentError::UnknownKind { .. })
        ));
    }

    #[test]
    fn drill_specs_complete_from_their_preset_and_share_the_aor_factor_paths() {
        let spec = prepare_spec(
            "drill",
            Some("fast"),
            &json!({"soil_soil": {"static_friction": 0.5}}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["static_friction"], json!(0.5));
        validate_spec("drill", &spec).unwrap();
        let mut bad = spec.clone();
        bad["soil_soil"]["rolling_friction"] = json!(-1.0);
        assert!(validate_spec("drill", &bad).is_err());
    }

    #[test]
    fn kinds_parse_once_and_round_trip_their_names() {
        for (kind, name) in Kind::ALL.into_iter().zip(KINDS) {
            assert_eq!(kind.name(), name);
            assert_eq!(Kind::parse(name).unwrap(), kind);
            assert_eq!(name.parse::<Kind>().unwrap(), kind);
            assert_eq!(presets(name).unwrap(), kind.presets());
        }
        assert!(matches!(
            Kind::parse("Aor"),
            Err(ExperimentError::UnknownKind { .. })
        ));
        let spec = prepare_spec("drill", Some("fast"), &json!({})).unwrap();
        let parsed = ExperimentSpec::parse(Kind::Drill, &spec).unwrap();
        assert_eq!(parsed.kind(), Kind::Drill);
        assert_eq!(parsed.to_value(), spec);
        assert!(ExperimentSpec::parse(Kind::Aor, &spec).is_err());
    }

    #[test]
    fn a_cohesion_law_is_given_whole_and_replaces_the_presets_whole() {
        let linear = json!({"model": "linear", "energy_density": 3.0e5});
        let spec = prepare_spec(
            "aor",
            Some("fast"),
            &json!({"soil_soil": {"cohesion": linear}}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["cohesion"], linear);
        assert_eq!(spec["soil_steel"]["cohesion"], json!({"model": "none"}));
        // A different model over it replaces it (no leftover energy_density).
        let jkr = json!({"model": "jkr", "surface_energy": 0.1});
        let spec = prepare_spec(
            "aor",
            Some("fast"),
            &merge_json(
                json!({"soil_soil": {"cohesion": linear}}),
                json!({"soil_soil": {"cohesion": jkr}}),
            ),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["cohesion"], jkr);
        let mut bad = spec.clone();
        bad["soil_soil"]["cohesion"]["surface_energy"] = json!(-1.0);
        match validate_spec("aor", &bad) {
            Err(ExperimentError::InvalidSpec { path, .. }) => {
                assert_eq!(path.as_deref(), Some("soil_soil.cohesion.surface_energy"))
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn shear_specs_complete_from_their_preset_and_name_bad_fields() {
        let spec = prepare_spec(
            "shear",
            Some("fast"),
            &json!({"soil_soil": {"static_friction": 0.5}, "normal_stresses_kpa": [5.0, 10.0]}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["static_friction"], json!(0.5));
        assert_eq!(spec["normal_stresses_kpa"], json!([5.0, 10.0]));
        assert_eq!(spec["box"]["side"], json!(0.05), "fast preset kept");
        let parsed = ExperimentSpec::parse(Kind::Shear, &spec).unwrap();
        assert_eq!(parsed.kind(), Kind::Shear);
        assert_eq!(parsed.to_value(), spec);
        let mut bad = spec.clone();
        bad["normal_stresses_kpa"] = json!([5.0]);
        match validate_spec("shear", &bad) {
            Err(ExperimentError::InvalidSpec { path, .. }) => {
                assert_eq!(path.as_deref(), Some("normal_stresses_kpa"))
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(matches!(
            prepare_spec("shear", Some("full"), &json!({})),
            Err(ExperimentError::UnknownPreset { .. })
        ));
    }

    #[test]
    fn a_local_failure_is_not_permanent_and_a_bad_spec_is() {
        let local = ExperimentError::Local {
            message: "cannot start 4 simulation threads".into(),
        };
        assert!(!local.is_permanent());
        assert!(!ExperimentError::Cancelled.is_permanent());
        let bad = prepare_spec("aor", None, &json!({"total_mass": -1.0})).unwrap_err();
        assert!(bad.is_permanent(), "{bad:?}");
    }

    /// Every preset's prepared JSON, and the bed key of each drilling and shear preset, by
    /// hash: moving the spec types between modules must not change a field name, a default or
    /// a cached bed's key. (Recorded before the experiment layer's refactoring, issue 37.)
    #[test]
    fn presets_and_bed_keys_are_as_before() {
        use crate::Spec;
        let mut seen = Vec::new();
        for kind in Kind::ALL {
            for preset in kind.presets() {
                let spec = prepare_spec(kind.name(), Some(preset), &json!({})).unwrap();
                let text = serde_json::to_string(&spec).unwrap();
                let hash = crate::fnv1a(text.as_bytes());
                seen.push(format!("{kind}/{preset} {hash:016x}"));
            }
        }
        for preset in crate::drill::PRESETS {
            let spec = crate::drill::DrillSpec::preset(preset).unwrap();
            seen.push(format!("drill/{preset} {}", crate::drill::bed_key(&spec)));
        }
        for preset in crate::shear::PRESETS {
            let spec = crate::shear::ShearSpec::preset(preset).unwrap();
            seen.push(format!(
                "shear/{preset} {}",
                crate::shear::sample_key(&spec)
            ));
        }
        let pinned = [
            "aor/default c39391d40047b07c",
            "aor/fast 1ca7e71ba5b310c5",
            "aor/paper-scale 04208fdc4585c385",
            "aor/fine 7600fa2547a9d803",
            "aor/size-2.5mm a88c712f8f779d58",
            "aor/size-1.5mm 571ff0accde9c8be",
            "aor/mass-100g 751a52a818f9b08f",
            "aor/paper-scale-sieve afc50a5568886834",
            "drill/default 0500a8a97dc1855b",
            "drill/fast 1feba4a402b7cfd3",
            "drill/full b96e263b8828df22",
            "shear/default 4ceedad5d6ae2b0d",
            "shear/fast 85a596c68357ea10",
            // Added with the kind (issue 50), pinned from here on.
            "triaxial/default 3b73d88124db87bb",
            "triaxial/fast b7437472e53ed2f5",
            "triaxial/ci 176b1ddbb729bc10",
            "drill/default bed-v2-c799c2efba703217",
            "drill/fast bed-v2-a59bd87c59242559",
            "drill/full bed-v2-268f918f70a4d81b",
            "shear/default bed-v2-6f5f776c5d93f0b2",
            "shear/fast bed-v2-dc77c0cdb4ec1e60",
        ];
        assert_eq!(seen, pinned, "{seen:#?}");
    }

    #[test]
    fn a_parsed_spec_keys_its_bed_and_its_checkpoint_under_the_runs_seed() {
        let drill = Kind::Drill.prepare(Some("fast"), &json!({})).unwrap();
        let seeded = crate::drill::DrillSpec {
            seed: 7,
            ..crate::drill::DrillSpec::fast()
        };
        assert_eq!(drill.bed_key(7), Some(crate::drill::bed_key(&seeded)));
        assert_ne!(drill.bed_key(7), drill.bed_key(8));
        assert_eq!(drill.checkpoint_key(7), None);
        let shear = Kind::Shear.prepare(Some("fast"), &json!({})).unwrap();
        let seeded = crate::shear::ShearSpec {
            seed: 7,
            ..crate::shear::ShearSpec::fast()
        };
        assert_eq!(shear.bed_key(7), Some(crate::shear::sample_key(&seeded)));
        assert_eq!(shear.checkpoint_key(7), None);
        let aor = Kind::Aor.prepare(Some("fast"), &json!({})).unwrap();
        let seeded = AorSpec {
            seed: 7,
            ..AorSpec::fast()
        };
        assert_eq!(
            aor.checkpoint_key(7),
            Some(crate::aor::checkpoint_key(&seeded))
        );
        assert_ne!(aor.checkpoint_key(7), aor.checkpoint_key(8));
        assert_eq!(aor.bed_key(7), None);
        let formula = json!({"inputs": {"x": 1.0}, "responses": {"y": "x"}});
        let formula = Kind::Formula.prepare(None, &formula).unwrap();
        assert_eq!(
            (formula.bed_key(7), formula.checkpoint_key(7)),
            (None, None)
        );
    }

    /// `aor` (both protocols), `drill`, `shear` and `triaxial` run on the GPU with every contact law; every other
    /// kind is refused by name and permanently (no worker's GPU runs it), and a GPU run keeps no
    /// checkpoint while the CPU's key stays what it was.
    #[test]
    fn the_gpu_runs_aor_drill_and_shear_and_refuses_the_other_kinds_by_name() {
        let aor = Kind::Aor.prepare(Some("fast"), &json!({})).unwrap();
        for over in [
            json!({"protocol": "lifted_cylinder"}),
            json!({"soil_soil": {"cohesion": {"model": "linear", "energy_density": 1e4}}}),
            json!({"soil_steel": {"cohesion": {"model": "jkr", "surface_energy": 0.1}}}),
            json!({"rolling_model": "epsd"}),
        ] {
            for kind in [Kind::Aor, Kind::Drill, Kind::Shear, Kind::Triaxial] {
                if kind != Kind::Aor && over.get("protocol").is_some() {
                    continue;
                }
                let spec = kind.prepare(Some("fast"), &over).unwrap();
                spec.check_backend(BackendKind::Gpu).unwrap();
                spec.check_backend(BackendKind::Cpu).unwrap();
            }
        }
        for kind in Kind::ALL {
            let spec = match kind {
                Kind::TableLookup => json!({"values": {"a": 1.0}, "rows": [{"a": 1.0}]}),
                Kind::Formula => json!({"inputs": {"x": 1.0}, "responses": {"y": "x"}}),
                _ => json!({}),
            };
            let spec = kind.prepare(None, &spec).unwrap();
            spec.check_backend(BackendKind::Cpu).unwrap();
            if matches!(kind, Kind::Aor | Kind::Drill | Kind::Shear | Kind::Triaxial) {
                assert_eq!(kind.backends(), [BackendKind::Cpu, BackendKind::Gpu]);
                spec.check_backend(BackendKind::Gpu).unwrap();
                continue;
            }
            assert_eq!(kind.backends(), [BackendKind::Cpu]);
            let err = spec.check_backend(BackendKind::Gpu).unwrap_err();
            assert!(
                matches!(
                    err,
                    ExperimentError::Unsupported {
                        backend: BackendKind::Gpu,
                        ..
                    }
                ),
                "{kind}: {err:?}"
            );
            assert!(err.is_permanent(), "{kind}");
            assert!(err.to_string().contains(&format!("`{kind}`")), "{err}");
        }
        assert_eq!(
            aor.checkpoint_key_on(BackendKind::Cpu, 7),
            aor.checkpoint_key(7)
        );
        assert!(aor.checkpoint_key(7).is_some());
        assert_eq!(aor.checkpoint_key_on(BackendKind::Gpu, 7), None);
    }

    #[test]
    fn table_lookup_runs_and_reports_misses_as_no_result() {
        let spec = json!({
            "values": {"a": 1.0},
            "rows": [{"a": 1.0, "y": 5.0}, {"a": 2.0, "y": 7.0}]
        });
        let spec = prepare_spec("table_lookup", None, &spec).unwrap();
        let out = run_experiment("table_lookup", &spec, 3, &mut |_| Control::Continue).unwrap();
        assert_eq!(out.metrics["y"], 5.0);
        let mut missing = spec.clone();
        missing["values"]["a"] = json!(1.5);
        let err = run_experiment("table_lookup", &missing, 3, &mut |_| Control::Continue);
        assert!(matches!(err, Err(ExperimentError::NoResult { .. })));
        let err = err.unwrap_err();
        assert!(err.is_permanent() && !err.another_seed_may_help());
    }
}
