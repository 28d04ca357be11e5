//! Shared by the drilling tests.

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
