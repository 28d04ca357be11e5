//! The crate's integration tests as one test binary (one link, the tests of every file
//! run side by side): `cargo test -p repose-experiments --test experiments <file>::`.

mod aor_gpu;
mod aor_measure;
mod aor_paper_designs;
mod aor_presets;
mod aor_run;
mod aor_spec;
mod common;
mod drill_gpu;
mod drill_run;
mod drill_spec;
/// The engine-gpu tests' GPU opener (`gpu()`: skips, or fails under `REPOSE_REQUIRE_GPU=1`,
/// where no adapter can be opened), one file for both crates.
#[allow(dead_code)]
#[path = "../../../engine-gpu/tests/gpu/common/mod.rs"]
mod gpu_common;
mod shear_gpu;
mod shear_run;
mod shear_spec;
mod triaxial_gpu;
mod triaxial_run;
