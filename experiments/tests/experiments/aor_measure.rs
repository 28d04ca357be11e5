//! Angle-of-repose measurement on synthetic piles of known geometry.
//!
//! The piles are cones filled with spheres (random sequential addition, i.e. a random loose
//! packing, or a jittered lattice), each sphere entirely inside the cone. The surface of such a
//! pile is the cone shifted inwards by about one grain, so the flank slope, which is what is
//! measured, is exactly the cone's.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use repose_experiments::aor::{
    measure_angle_of_repose, side_view_svg, AngleOfRepose, MeasureError, MeasureSettings,
    PictureOptions, ProjectionPlane,
};
use std::collections::HashMap;

const MM: f64 = 1e-3;

#[derive(Debug, Clone, Default)]
struct Pile {
    positions: Vec<[f64; 3]>,
    radii: Vec<f64>,
}

/// A cone with its apex above `centre`, standing on `base_z`, possibly with a different slope on
/// the x < centre side (left) and the x >= centre side (right).
#[derive(Debug, Clone, Copy)]
struct Cone {
    centre: [f64; 2],
    base_z: f64,
    base_radius: f64,
    left_deg: f64,
    right_deg: f64,
}

impl Cone {
    fn symmetric(angle_deg: f64, base_radius: f64) -> Self {
        Self {
            centre: [0.0, 0.0],
            base_z: 0.0,
            base_radius,
            left_deg: angle_deg,
            right_deg: angle_deg,
        }
    }

    /// Apex height: `base_radius` is the base radius on the steeper side.
    fn height(&self) -> f64 {
        self.base_radius * self.left_deg.max(self.right_deg).to_radians().tan()
    }

    /// Base radius on the shallower side (the horizontal extent of the pile).
    fn extent(&self) -> f64 {
        self.height() / self.left_deg.min(self.right_deg).to_radians().tan()
    }

    fn slope_at(&self, x: f64) -> f64 {
        let deg = if x < self.centre[0] {
            self.left_deg
        } else {
            self.right_deg
        };
        deg.to_radians()
    }

    /// Whether a sphere fits entirely inside the cone (above the base, below the flank).
    fn holds(&self, p: [f64; 3], radius: f64) -> bool {
        let alpha = self.slope_at(p[0]);
        let r = (p[0] - self.centre[0]).hypot(p[1] - self.centre[1]);
        let surface = self.base_z + self.height() - r * alpha.tan();
        p[2] >= self.base_z + radius && p[2] <= surface - radius / alpha.cos()
    }
}

/// Random loose packing: random sequential addition of spheres with radii uniform in
/// `[r_min, r_max]`, rejecting overlaps, `attempts` tries.
fn random_loose_pile(cone: &Cone, r_min: f64, r_max: f64, attempts: usize, seed: u64) -> Pile {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let cell = 2.0 * r_max;
    let mut grid: HashMap<(i64, i64, i64), Vec<usize>> = HashMap::new();
    let key = |p: [f64; 3]| {
        (
            (p[0] / cell).floor() as i64,
            (p[1] / cell).floor() as i64,
            (p[2] / cell).floor() as i64,
        )
    };
    let mut pile = Pile::default();
    let h = cone.height();
    let extent = cone.extent();
    for _ in 0..attempts {
        let radius = if r_max > r_min {
            rng.gen_range(r_min..r_max)
        } else {
            r_min
        };
        let p = [
            cone.centre[0] + rng.gen_range(-extent..extent),
            cone.centre[1] + rng.gen_range(-extent..extent),
            cone.base_z + rng.gen_range(0.0..h),
        ];
        if !cone.holds(p, radius) {
            continue;
        }
        let (i, j, k) = key(p);
        let mut free = true;
        'search: for di in -1..=1 {
            for dj in -1..=1 {
                for dk in -1..=1 {
                    if let Some(list) = grid.get(&(i + di, j + dj, k + dk)) {
                        for &n in list {
                            let q = pile.positions[n];
                            let d2 = (p[0] - q[0]).powi(2)
                                + (p[1] - q[1]).powi(2)
                                + (p[2] - q[2]).powi(2);
                            let min = radius + pile.radii[n];
                            if d2 < min * min {
                                free = false;
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        if free {
            grid.entry((i, j, k))
                .or_default()
                .push(pile.positions.len());
            pile.positions.push(p);
            pile.radii.push(radius);
        }
    }
    pile
}

/// Simple cubic lattice of touching spheres (with a small random jitter) clipped to the cone.
fn lattice_pile(cone: &Cone, radius: f64, seed: u64) -> Pile {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let spacing = 2.0 * radius * 1.05;
    let jitter = 0.04 * radius;
    let n = (cone.extent() / spacing).ceil() as i64 + 1;
    let layers = (cone.height() / spacing).ceil() as i64 + 1;
    let mut pile = Pile::default();
    for i in -n..=n {
        for j in -n..=n {
            for k in 0..layers {
                let p = [
                    cone.centre[0] + i as f64 * spacing + rng.gen_range(-jitter..jitter),
                    cone.centre[1] + j as f64 * spacing + rng.gen_range(-jitter..jitter),
                    cone.base_z + radius + k as f64 * spacing + rng.gen_range(0.0..jitter),
                ];
                if cone.holds(p, radius) {
                    pile.positions.push(p);
                    pile.radii.push(radius);
                }
            }
        }
    }
    pile
}

/// Grains that are not part of the heap: some that bounced far away onto the base, one still in
/// flight above the apex, one that fell off the plate, one numerically blown up.
fn add_strays(pile: &mut Pile, cone: &Cone, radius: f64) {
    let [cx, cy] = cone.centre;
    let far = 3.0 * cone.base_radius;
    for (x, y) in [(far, 0.0), (-far, 0.3 * far), (0.2 * far, -far), (0.0, far)] {
        pile.positions.push([cx + x, cy + y, cone.base_z + radius]);
        pile.radii.push(radius);
    }
    pile.positions
        .push([cx, cy, cone.base_z + cone.height() + 15.0 * MM]);
    pile.radii.push(radius);
    pile.positions.push([cx + far, cy, cone.base_z - 0.2]);
    pile.radii.push(radius);
    pile.positions.push([f64::NAN, 0.0, 0.0]);
    pile.radii.push(radius);
}

/// Equal up to the last bits that a decimal JSON round trip may change.
fn assert_same_json(a: &AngleOfRepose, b: &AngleOfRepose) {
    fn same(x: &serde_json::Value, y: &serde_json::Value) -> bool {
        use serde_json::Value;
        match (x, y) {
            (Value::Number(p), Value::Number(q)) => {
                let (p, q) = (p.as_f64().unwrap(), q.as_f64().unwrap());
                (p - q).abs() <= 1e-12 * p.abs().max(q.abs()).max(1e-300)
            }
            (Value::Array(p), Value::Array(q)) => {
                p.len() == q.len() && p.iter().zip(q).all(|(p, q)| same(p, q))
            }
            (Value::Object(p), Value::Object(q)) => {
                p.len() == q.len() && p.iter().all(|(k, v)| q.get(k).is_some_and(|w| same(v, w)))
            }
            _ => x == y,
        }
    }
    let x = serde_json::to_value(a).unwrap();
    let y = serde_json::to_value(b).unwrap();
    assert!(same(&x, &y), "JSON round trip changed the result");
}

fn measure(pile: &Pile, settings: &MeasureSettings) -> AngleOfRepose {
    measure_angle_of_repose(&pile.positions, &pile.radii, settings)
        .unwrap_or_else(|e| panic!("measurement failed: {e}"))
}

fn report(label: &str, truth: (f64, f64), pile: &Pile, m: &AngleOfRepose) {
    eprintln!(
        "{label}: n={} considered={} true L/R {:.1}/{:.1}° | half-planes {:.2}° (sd {:.2}, {:.2}..{:.2}) | x-z left {:.2}° right {:.2}° | y-z {:.2}/{:.2}° | H {:.2} mm D {:.2} mm | r2 min {:.3}",
        pile.positions.len(),
        m.particles_considered,
        truth.0,
        truth.1,
        m.angle_deg,
        m.std_dev_deg,
        m.min_deg,
        m.max_deg,
        m.left_deg,
        m.right_deg,
        m.projection_yz.left_deg,
        m.projection_yz.right_deg,
        m.pile_height_m / MM,
        m.base_diameter_m / MM,
        m.directions
            .iter()
            .map(|d| d.fit.r_squared)
            .fold(1.0, f64::min),
    );
}

/// The accuracy targets of the issue, checked on one symmetric cone.
fn check_symmetric(label: &str, cone: &Cone, pile: &Pile, grain_diameter: f64) -> AngleOfRepose {
    let m = measure(
        pile,
        &MeasureSettings {
            base_z_m: cone.base_z,
            ..MeasureSettings::default()
        },
    );
    report(label, (cone.left_deg, cone.right_deg), pile, &m);
    let truth = cone.left_deg;
    assert!(
        (m.angle_deg - truth).abs() <= 1.0,
        "{label}: mean angle {:.2}° vs {truth}°",
        m.angle_deg
    );
    assert!(
        m.std_dev_deg <= 1.5,
        "{label}: spread {:.2}°",
        m.std_dev_deg
    );
    for (i, a) in m.per_direction_deg.iter().enumerate() {
        assert!((a - truth).abs() <= 3.0, "{label}: direction {i}: {a:.2}°");
    }
    for (side, a) in [
        ("x-z left", m.left_deg),
        ("x-z right", m.right_deg),
        ("y-z left", m.projection_yz.left_deg),
        ("y-z right", m.projection_yz.right_deg),
    ] {
        assert!(
            (a - truth).abs() <= 1.5,
            "{label}: {side} {a:.2}° vs {truth}°"
        );
    }
    let height_error = m.pile_height_m - cone.height();
    assert!(
        height_error.abs() <= 2.0 * grain_diameter,
        "{label}: height {:.2} mm vs {:.2} mm",
        m.pile_height_m / MM,
        cone.height() / MM
    );
    // The toe is where the fitted flank meets the base. The grains' tops lie up to about one
    // grain below the cone (they are inscribed in it), which on a 25° flank moves the toe inwards
    // by up to 1 mm / tan 25° ≈ 2 mm per side: hence three grain diameters.
    let diameter_error = m.base_diameter_m - 2.0 * cone.base_radius;
    assert!(
        diameter_error.abs() <= 3.0 * grain_diameter,
        "{label}: base diameter {:.2} mm vs {:.2} mm",
        m.base_diameter_m / MM,
        2.0 * cone.base_radius / MM
    );
    assert!(
        (m.apex[0] - cone.centre[0]).hypot(m.apex[1] - cone.centre[1]) <= 3.0 * grain_diameter,
        "{label}: apex {:?}",
        m.apex
    );
    assert!(
        (m.axis_xy_m[0] - cone.centre[0]).hypot(m.axis_xy_m[1] - cone.centre[1]) <= grain_diameter,
        "{label}: axis {:?}",
        m.axis_xy_m
    );
    m
}

#[test]
fn random_loose_cones_of_known_angle() {
    for (angle, seed) in [(25.0, 1), (35.0, 2), (45.0, 3)] {
        let cone = Cone::symmetric(angle, 40.0 * MM);
        let mut pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 400_000, seed);
        add_strays(&mut pile, &cone, 1.0 * MM);
        let m = check_symmetric(&format!("loose {angle}°"), &cone, &pile, 2.0 * MM);
        assert_eq!(m.particles_total, pile.positions.len());
        assert!(m.particles_considered <= pile.positions.len() - 7);
    }
}

#[test]
fn lattice_cones_of_known_angle() {
    for (angle, seed) in [(25.0, 11), (35.0, 12), (45.0, 13)] {
        let cone = Cone::symmetric(angle, 40.0 * MM);
        let mut pile = lattice_pile(&cone, 1.0 * MM, seed);
        add_strays(&mut pile, &cone, 1.0 * MM);
        check_symmetric(&format!("lattice {angle}°"), &cone, &pile, 2.0 * MM);
    }
}

#[test]
fn polydisperse_pile_off_origin_on_raised_base() {
    let cone = Cone {
        centre: [0.12, -0.07],
        base_z: 0.015,
        base_radius: 40.0 * MM,
        left_deg: 34.85,
        right_deg: 34.85,
    };
    let mut pile = random_loose_pile(&cone, 0.5 * MM, 1.5 * MM, 400_000, 21);
    add_strays(&mut pile, &cone, 1.0 * MM);
    check_symmetric("polydisperse 34.85°", &cone, &pile, 2.0 * MM);
}

#[test]
fn given_funnel_axis_is_used() {
    let cone = Cone::symmetric(35.0, 30.0 * MM);
    let pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 200_000, 5);
    let settings = MeasureSettings {
        axis_xy_m: Some([0.0, 0.0]),
        ..MeasureSettings::default()
    };
    let m = measure(&pile, &settings);
    assert_eq!(m.axis_xy_m, [0.0, 0.0]);
    assert!((m.angle_deg - 35.0).abs() <= 1.0, "{}", m.angle_deg);
}

#[test]
fn asymmetric_pile_gives_different_left_and_right_angles() {
    let cone = Cone {
        centre: [0.0, 0.0],
        base_z: 0.0,
        base_radius: 40.0 * MM,
        left_deg: 28.0,
        right_deg: 42.0,
    };
    let pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 900_000, 31);
    let m = measure(&pile, &MeasureSettings::default());
    report("asymmetric 28/42°", (28.0, 42.0), &pile, &m);
    assert!((m.left_deg - 28.0).abs() <= 1.5, "left {}", m.left_deg);
    assert!((m.right_deg - 42.0).abs() <= 1.5, "right {}", m.right_deg);
    assert!(m.right_deg - m.left_deg > 10.0);
    // The default axis is the footprint centre, which for this lopsided heap lies well on the
    // shallow side of the apex; with the funnel axis (under the apex) given, the half-planes see
    // each side's slope, and their spread shows the asymmetry.
    let with_axis = measure(
        &pile,
        &MeasureSettings {
            axis_xy_m: Some([0.0, 0.0]),
            ..MeasureSettings::default()
        },
    );
    let towards_plus_x = with_axis.per_direction_deg[0];
    let towards_minus_x = with_axis.per_direction_deg[4];
    assert!((towards_plus_x - 42.0).abs() <= 2.0, "{towards_plus_x}");
    assert!((towards_minus_x - 28.0).abs() <= 2.0, "{towards_minus_x}");
    assert!(with_axis.max_deg - with_axis.min_deg > 10.0);
    assert!(with_axis.std_dev_deg > 4.0);
    // Looking along x, both flanks of the y-z view mix the two halves: roughly symmetric.
    let yz = &m.projection_yz;
    assert!((yz.left_deg - yz.right_deg).abs() < 3.0, "{yz:?}");
}

#[test]
fn result_round_trips_through_json() {
    let cone = Cone::symmetric(35.0, 25.0 * MM);
    let pile = lattice_pile(&cone, 1.0 * MM, 7);
    let m = measure(&pile, &MeasureSettings::default());
    let json = serde_json::to_string(&m).unwrap();
    let back: AngleOfRepose = serde_json::from_str(&json).unwrap();
    assert_same_json(&m, &back);
    assert_eq!(m.per_direction_deg.len(), 8);
    assert_eq!(m.directions.len(), 8);
    assert!((m.projection_mean_deg - 0.5 * (m.left_deg + m.right_deg)).abs() < 1e-12);
}

#[test]
fn custom_direction_count_and_band() {
    let cone = Cone::symmetric(35.0, 30.0 * MM);
    let pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 250_000, 8);
    let settings = MeasureSettings {
        directions: 12,
        band_low_fraction: 0.3,
        band_high_fraction: 0.7,
        ..MeasureSettings::default()
    };
    let m = measure(&pile, &settings);
    assert_eq!(m.per_direction_deg.len(), 12);
    assert_eq!(m.band_fractions, [0.3, 0.7]);
    assert!((m.angle_deg - 35.0).abs() <= 1.5, "{}", m.angle_deg);
}

// ---- "no pile" cases -------------------------------------------------------------------------

#[test]
fn empty_input_is_no_pile() {
    let err = measure_angle_of_repose(&[], &[], &MeasureSettings::default()).unwrap_err();
    assert_eq!(
        err,
        MeasureError::TooFewParticles {
            found: 0,
            required: 20
        }
    );
}

#[test]
fn mismatched_lengths_are_rejected() {
    let err = measure_angle_of_repose(&[[0.0; 3]; 3], &[1e-3; 2], &MeasureSettings::default())
        .unwrap_err();
    assert_eq!(
        err,
        MeasureError::LengthMismatch {
            positions: 3,
            radii: 2
        }
    );
}

#[test]
fn flat_layer_is_too_flat() {
    // One layer of grains (tops at 1 d): no slope, too flat.
    let mut layer = Pile::default();
    for i in 0..40 {
        for j in 0..40 {
            layer
                .positions
                .push([i as f64 * 2.0 * MM, j as f64 * 2.0 * MM, MM]);
            layer.radii.push(MM);
        }
    }
    let err = measure_angle_of_repose(&layer.positions, &layer.radii, &MeasureSettings::default())
        .unwrap_err();
    assert!(matches!(err, MeasureError::PileTooFlat { .. }), "{err}");
    assert!(err.to_string().contains("no pile"));
    // Two flat layers (1.75 d) stand above the minimum height (issue 37: a second layer begun is
    // a heap) but have no flank: nothing of the surface lies in the fit band, so still no pile.
    let mut pile = Pile::default();
    for i in 0..40 {
        for j in 0..40 {
            for layer in 0..2 {
                pile.positions.push([
                    i as f64 * 2.0 * MM + layer as f64 * MM,
                    j as f64 * 2.0 * MM + layer as f64 * MM,
                    MM + layer as f64 * 1.5 * MM,
                ]);
                pile.radii.push(MM);
            }
        }
    }
    let err = measure_angle_of_repose(&pile.positions, &pile.radii, &MeasureSettings::default())
        .unwrap_err();
    assert!(
        matches!(err, MeasureError::TooFewFitPoints { found: 0, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("no pile"));
    // The old rule (3 d) called them too flat; it still can, as a setting.
    let three = MeasureSettings {
        min_height_diameters: 3.0,
        ..MeasureSettings::default()
    };
    let err = measure_angle_of_repose(&pile.positions, &pile.radii, &three).unwrap_err();
    assert!(matches!(err, MeasureError::PileTooFlat { .. }), "{err}");
}

/// A low heap is a low angle (issue 37): cones 2-3 grains high, below the old 3-grain minimum,
/// are measured, at about their angle.
#[test]
fn low_heap_gives_its_low_angle() {
    for (angle, seed) in [(6.0, 21), (8.0, 22)] {
        let cone = Cone::symmetric(angle, 45.0 * MM);
        let pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 200_000, seed);
        let m = measure(&pile, &MeasureSettings::default());
        report(&format!("low {angle}°"), (angle, angle), &pile, &m);
        assert!(
            m.pile_height_m < 3.0 * 2.0 * MM,
            "{angle}°: {} m",
            m.pile_height_m
        );
        assert!(
            (m.angle_deg - angle).abs() <= 2.5,
            "{angle}°: measured {:.2}°",
            m.angle_deg
        );
        let old = MeasureSettings {
            min_height_diameters: 3.0,
            ..MeasureSettings::default()
        };
        assert!(matches!(
            measure_angle_of_repose(&pile.positions, &pile.radii, &old),
            Err(MeasureError::PileTooFlat { .. })
        ));
    }
}

#[test]
fn scattered_grains_are_not_a_pile() {
    // Grains that escaped: spread over a square metre of plate, nowhere touching.
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let positions: Vec<[f64; 3]> = (0..500)
        .map(|_| [rng.gen_range(-0.5..0.5), rng.gen_range(-0.5..0.5), MM])
        .collect();
    let radii = vec![MM; positions.len()];
    let err = measure_angle_of_repose(&positions, &radii, &MeasureSettings::default()).unwrap_err();
    assert!(matches!(err, MeasureError::TooFewParticles { .. }), "{err}");
}

#[test]
fn grains_below_the_base_are_not_a_pile() {
    let cone = Cone::symmetric(35.0, 20.0 * MM);
    let mut pile = lattice_pile(&cone, MM, 3);
    for p in &mut pile.positions {
        p[2] -= 0.5; // all fell off the plate
    }
    let err = measure_angle_of_repose(&pile.positions, &pile.radii, &MeasureSettings::default())
        .unwrap_err();
    assert_eq!(
        err,
        MeasureError::TooFewParticles {
            found: 0,
            required: 20
        }
    );
}

#[test]
fn single_column_has_no_flank() {
    // A tower one grain wide: tall, but no flank to fit a line to.
    let positions: Vec<[f64; 3]> = (0..40)
        .map(|k| [0.0, 0.0, MM + k as f64 * 2.0 * MM])
        .collect();
    let radii = vec![MM; positions.len()];
    let err = measure_angle_of_repose(&positions, &radii, &MeasureSettings::default()).unwrap_err();
    assert!(matches!(err, MeasureError::TooFewFitPoints { .. }), "{err}");
}

#[test]
fn invalid_settings_are_reported() {
    let settings = MeasureSettings {
        directions: 0,
        ..MeasureSettings::default()
    };
    let err = measure_angle_of_repose(&[], &[], &settings).unwrap_err();
    assert!(matches!(err, MeasureError::InvalidSettings(_)));
}

#[test]
fn pathological_values_do_not_panic() {
    let positions = vec![
        [f64::NAN, 0.0, 0.0],
        [f64::INFINITY, 0.0, 1.0],
        [1e300, -1e300, 1e300],
        [0.0, 0.0, 0.001],
        [1e-300, 0.0, 0.001],
    ];
    let radii = vec![1e-3, f64::NAN, 1e300, -1.0, 0.0];
    let settings = MeasureSettings {
        min_particles: 1,
        min_height_diameters: 0.0,
        ..MeasureSettings::default()
    };
    let _ = measure_angle_of_repose(&positions, &radii, &settings);
    let huge = vec![1e250; positions.len()];
    let _ = measure_angle_of_repose(&positions, &huge, &settings);
}

// ---- picture ---------------------------------------------------------------------------------

#[test]
fn side_view_svg_is_well_formed_and_annotated() {
    let cone = Cone::symmetric(34.85, 40.0 * MM);
    let mut pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 400_000, 2);
    add_strays(&mut pile, &cone, 1.0 * MM);
    let m = measure(&pile, &MeasureSettings::default());
    let svg = side_view_svg(&m, &pile.positions, &pile.radii, &PictureOptions::default());

    let doc = roxmltree::Document::parse(&svg).expect("SVG must be well-formed XML");
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "svg");
    assert!(root.attribute("viewBox").is_some());
    assert!(
        !svg.contains("href") && !svg.contains("http://www.w3.org/1999/xlink"),
        "no external resources"
    );
    let texts: Vec<String> = doc
        .descendants()
        .filter(|n| n.has_tag_name("text"))
        .filter_map(|n| n.text().map(str::to_owned))
        .collect();
    let left = format!("{:.1}°", m.left_deg);
    let right = format!("{:.1}°", m.right_deg);
    assert!(texts.contains(&left), "left angle label {left}");
    assert!(texts.contains(&right), "right angle label {right}");
    assert!(texts
        .iter()
        .any(|t| t.contains(&format!("mean {:.1}°", m.projection_mean_deg))));
    assert!(texts.iter().any(|t| t == "x (mm)"));
    let circles = doc
        .descendants()
        .filter(|n| n.has_tag_name("circle"))
        .count();
    assert!(circles > 1000, "grains drawn: {circles}");
    assert_eq!(
        doc.descendants()
            .filter(|n| n.has_tag_name("polygon"))
            .count(),
        1,
        "one silhouette"
    );

    // Silhouette only, y-z view.
    let options = PictureOptions {
        plane: ProjectionPlane::Yz,
        draw_particles: false,
        ..PictureOptions::default()
    };
    let yz = side_view_svg(&m, &[], &[], &options);
    let doc = roxmltree::Document::parse(&yz).expect("well-formed");
    assert!(doc.descendants().any(|n| n.text() == Some("y (mm)")));

    // A sample for people to look at.
    let path = std::env::temp_dir().join("aor_sample.svg");
    std::fs::write(&path, &svg).expect("write sample SVG");
    eprintln!("sample picture written to {}", path.display());
}

// ---- robustness ------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Random clouds (heaps or not) never panic, and any result they give is finite and sane.
    #[test]
    fn random_clouds_never_panic(
        grains in prop::collection::vec(
            (-0.03f64..0.03, -0.03f64..0.03, -0.005f64..0.04, 1e-4f64..3e-3),
            0..400,
        ),
        directions in 1usize..16,
        low in 0.0f64..0.5,
        width in 0.05f64..0.5,
        min_particles in 1usize..30,
    ) {
        let positions: Vec<[f64; 3]> = grains.iter().map(|g| [g.0, g.1, g.2]).collect();
        let radii: Vec<f64> = grains.iter().map(|g| g.3).collect();
        let settings = MeasureSettings {
            directions,
            band_low_fraction: low,
            band_high_fraction: (low + width).min(1.0),
            min_particles,
            min_height_diameters: 1.0,
            ..MeasureSettings::default()
        };
        if let Ok(m) = measure_angle_of_repose(&positions, &radii, &settings) {
            prop_assert!(m.angle_deg.is_finite() && (0.0..=90.0).contains(&m.angle_deg));
            prop_assert_eq!(m.per_direction_deg.len(), directions);
            prop_assert!(m.left_deg.is_finite() && m.right_deg.is_finite());
            prop_assert!(m.pile_height_m > 0.0 && m.base_diameter_m.is_finite());
            let json = serde_json::to_string(&m).unwrap();
            let back: AngleOfRepose = serde_json::from_str(&json).unwrap();
            assert_same_json(&m, &back);
            let svg = side_view_svg(&m, &positions, &radii, &PictureOptions::default());
            prop_assert!(roxmltree::Document::parse(&svg).is_ok());
        }
    }
}

#[test]
fn grains_in_flight_are_not_a_pile() {
    // A run stopped before the grains settled: a cloud above the plate, none touching the base.
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let positions: Vec<[f64; 3]> = (0..800)
        .map(|_| {
            [
                rng.gen_range(-0.02..0.02),
                rng.gen_range(-0.02..0.02),
                rng.gen_range(0.05..0.09),
            ]
        })
        .collect();
    let radii = vec![MM; positions.len()];
    let err = measure_angle_of_repose(&positions, &radii, &MeasureSettings::default()).unwrap_err();
    assert!(matches!(err, MeasureError::TooFewParticles { .. }), "{err}");
}

/// Accuracy over 20 smaller random loose piles (base radius 17.5 grain diameters, 25°-45°).
/// Measured when written: mean half-plane angle within 1.03° of the cone for every pile (typical
/// bias -0.3°: the loose synthetic surface is slightly rounder near the apex), each side-projection
/// angle within 1.46°. The bounds below leave a little room above those. Prints the table (run with
/// `--nocapture` to see it).
#[test]
fn accuracy_over_seeds() {
    let mut worst_mean: f64 = 0.0;
    let mut worst_side: f64 = 0.0;
    for angle in [25.0, 30.0, 35.0, 40.0, 45.0] {
        for seed in 100..104 {
            let cone = Cone::symmetric(angle, 35.0 * MM);
            let pile = random_loose_pile(&cone, 1.0 * MM, 1.0 * MM, 300_000, seed);
            let m = measure(&pile, &MeasureSettings::default());
            let side = [m.left_deg, m.right_deg]
                .iter()
                .map(|a| (a - angle).abs())
                .fold(0.0, f64::max);
            eprintln!(
                "accuracy: true {angle:.1}° seed {seed}: half-planes {:.2}° (sd {:.2}), x-z {:.2}/{:.2}°",
                m.angle_deg, m.std_dev_deg, m.left_deg, m.right_deg
            );
            worst_mean = worst_mean.max((m.angle_deg - angle).abs());
            worst_side = worst_side.max(side);
        }
    }
    eprintln!(
        "accuracy: worst |mean - true| {worst_mean:.2}°, worst |side - true| {worst_side:.2}°"
    );
    assert!(worst_mean <= 1.25, "worst mean error {worst_mean:.2}°");
    assert!(worst_side <= 1.75, "worst side error {worst_side:.2}°");
}
