//! Opening the test GPU: any Vulkan/Metal/DX12 adapter (Mesa's lavapipe in CI).

use std::sync::OnceLock;

use repose_engine_gpu::{Gpu, GpuError};

/// The GPU, or `None` with a message on stderr where no adapter can be created at all (the
/// test then checks nothing and says so). `REPOSE_REQUIRE_GPU=1` (set by `.ci/run`, which
/// installs lavapipe) turns that into a failure. Opened once per test process and shared, as a
/// worker shares its GPU: NVIDIA's Vulkan driver (580.159.04, H200) refused a 30th device in
/// one process.
pub fn gpu() -> Option<&'static Gpu> {
    static GPU: OnceLock<Option<Gpu>> = OnceLock::new();
    GPU.get_or_init(|| match Gpu::open() {
        Ok(gpu) => {
            eprintln!("GPU: {}", gpu.describe());
            Some(gpu)
        }
        Err(e @ GpuError::NoAdapter(_)) => {
            if std::env::var("REPOSE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("REPOSE_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("SKIPPED: {e}");
            None
        }
        Err(e) => panic!("{e}"),
    })
    .as_ref()
}

/// One material, "grain" (2500 kg/m³, E 1e8 Pa, ν 0.3), against itself with restitution 0.5,
/// static friction 0.5 and rolling friction `rolling`.
pub fn grain_materials(rolling: f64) -> repose_engine::material::MaterialTable {
    use repose_engine::material::{
        Cohesion, DampingLaw, Interaction, InteractionEntry, Material, MaterialSet,
    };
    MaterialSet {
        damping_law: DampingLaw::default(),
        materials: vec![Material {
            name: "grain".into(),
            density: 2500.0,
            youngs_modulus: 1.0e8,
            poisson: 0.3,
        }],
        interactions: vec![InteractionEntry {
            a: "grain".into(),
            b: "grain".into(),
            coefficients: Interaction {
                restitution: 0.5,
                static_friction: 0.5,
                rolling_friction: rolling,
                cohesion: Cohesion::None,
            },
        }],
    }
    .build()
    .unwrap()
}
