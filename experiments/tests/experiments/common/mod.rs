//! Shared by the drilling tests, and by the GPU tests of the soil experiments.

use repose_experiments::drill::DrillSpec;

/// The fast preset's auger as an STL model (binary), tip at the origin, axis +z.
pub fn fast_auger_stl() -> Vec<u8> {
    use repose_engine::mesh::generators::{auger, AugerSpec};
    let a = DrillSpec::fast().auger;
    auger(&AugerSpec {
        shaft_diameter: a.shaft_diameter,
        flight_outer_diameter: a.outer_diameter,
        pitch: a.pitch,
        flight_length: 0.08,
        flight_thickness: a.flight_thickness,
        shaft_length: 0.12,
        tip_length: a.tip_length,
        segments_per_turn: a.segments_per_turn,
        right_handed: true,
    })
    .unwrap()
    .to_stl_binary()
}

/// A GPU run on a bed settled on the GPU against a CPU run of the same spec: the GPU's bed key
/// is the CPU's with `-gpu` after it, and each result names its engine (the GPU's adapter).
pub fn assert_each_names_its_engine(
    gpu: &repose_experiments::backend::Gpu,
    (gpu_bed, gpu_version): (&str, Option<&str>),
    (cpu_bed, cpu_version): (&str, Option<&str>),
) {
    assert_eq!(gpu_bed, format!("{cpu_bed}-gpu"));
    let version = gpu_version.unwrap();
    assert!(
        version.contains(&format!("+gpu:{}", gpu.name())),
        "{version}"
    );
    assert_eq!(cpu_version, Some(repose_engine::VERSION));
}
