//! Measuring the hole from particle positions, on the surface height field the soil module
//! reads ([`crate::soil::height_field`]): the opening at the original surface level, the
//! effective depth along the axis, and the backfill of the drilled cylinder.
//!
//! Frame: z up, bin floor at z = 0, drill axis through `axis` (x, y).

use serde::{Deserialize, Serialize};

use crate::soil::HeightField;

/// What the hole looks like after the auger is out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HoleMeasurement {
    /// Original surface level (before drilling), m above the floor.
    pub surface_z: f64,
    /// Cells whose surface is below this height belong to the opening, m.
    pub open_below_z: f64,
    /// Area of the connected opening around the axis at the original surface level, m².
    pub opening_area: f64,
    /// Diameter of the circle of that area, m.
    pub opening_diameter: f64,
    /// Width of the opening along x and along y through the axis, m.
    pub opening_x: f64,
    pub opening_y: f64,
    /// Surface height on the axis (the bottom of the open hole), m.
    pub bottom_z: f64,
    /// `surface_z - bottom_z`, m.
    pub effective_depth: f64,
    /// Highest point of the surface within two auger diameters of the axis, above `surface_z`
    /// (the spoil heaped around the hole), m.
    pub rim_height: f64,
}

/// Measures the opening and the depth of the hole on `hf` around `axis`. `open_depth`: how far
/// below `surface_z` a cell must be to count as open; `search_radius`: if the axis cell itself
/// is not open, the open cell nearest the axis within this radius starts the opening (none: the
/// hole is closed at the top and the opening is zero).
pub fn measure_hole(
    hf: &HeightField,
    surface_z: f64,
    axis: [f64; 2],
    open_depth: f64,
    search_radius: f64,
) -> HoleMeasurement {
    let open_below_z = surface_z - open_depth;
    let is_open = |i: usize, j: usize| hf.at(i, j) < open_below_z;
    let (ia, ja) = hf.cell_of(axis[0], axis[1]);
    let seed = if is_open(ia, ja) {
        Some((ia, ja))
    } else {
        let mut best: Option<((usize, usize), f64)> = None;
        let reach = (search_radius / hf.cell).ceil() as isize;
        for dj in -reach..=reach {
            for di in -reach..=reach {
                let (i, j) = (ia as isize + di, ja as isize + dj);
                if i < 0 || j < 0 || i >= hf.nx as isize || j >= hf.ny as isize {
                    continue;
                }
                let (i, j) = (i as usize, j as usize);
                let dist = (hf.x(i) - axis[0]).hypot(hf.y(j) - axis[1]);
                if dist <= search_radius && is_open(i, j) && best.is_none_or(|(_, d)| dist < d) {
                    best = Some(((i, j), dist));
                }
            }
        }
        best.map(|(c, _)| c)
    };
    // Flood fill (4-connected) from the seed over open cells.
    let mut region = vec![false; hf.nx * hf.ny];
    let mut count = 0usize;
    if let Some((i, j)) = seed {
        let mut stack = vec![(i, j)];
        region[j * hf.nx + i] = true;
        while let Some((i, j)) = stack.pop() {
            count += 1;
            let mut visit = |i: usize, j: usize| {
                if is_open(i, j) && !region[j * hf.nx + i] {
                    region[j * hf.nx + i] = true;
                    stack.push((i, j));
                }
            };
            if i > 0 {
                visit(i - 1, j);
            }
            if i + 1 < hf.nx {
                visit(i + 1, j);
            }
            if j > 0 {
                visit(i, j - 1);
            }
            if j + 1 < hf.ny {
                visit(i, j + 1);
            }
        }
    }
    let extent = |cells: &mut dyn Iterator<Item = usize>| -> f64 {
        let (mut lo, mut hi) = (usize::MAX, 0usize);
        let mut any = false;
        for k in cells {
            any = true;
            lo = lo.min(k);
            hi = hi.max(k);
        }
        if any {
            (hi - lo + 1) as f64 * hf.cell
        } else {
            0.0
        }
    };
    let opening_x = extent(&mut (0..hf.nx).filter(|&i| region[ja * hf.nx + i]));
    let opening_y = extent(&mut (0..hf.ny).filter(|&j| region[j * hf.nx + ia]));
    let opening_area = count as f64 * hf.cell * hf.cell;
    let bottom_z = hf.at(ia, ja);
    let mut rim = f64::NEG_INFINITY;
    for j in 0..hf.ny {
        for i in 0..hf.nx {
            if (hf.x(i) - axis[0]).hypot(hf.y(j) - axis[1]) <= 2.0 * search_radius {
                rim = rim.max(hf.at(i, j));
            }
        }
    }
    HoleMeasurement {
        surface_z,
        open_below_z,
        opening_area,
        opening_diameter: 2.0 * (opening_area / std::f64::consts::PI).sqrt(),
        opening_x,
        opening_y,
        bottom_z,
        effective_depth: surface_z - bottom_z,
        rim_height: rim - surface_z,
    }
}

/// Solid volume (m³) of the grains whose centres lie in the vertical cylinder of `radius` about
/// `axis` between `z_lo` and `z_hi`.
pub fn solid_volume_in_cylinder(
    positions: &[[f64; 3]],
    radii: &[f64],
    axis: [f64; 2],
    radius: f64,
    z_lo: f64,
    z_hi: f64,
) -> f64 {
    positions
        .iter()
        .zip(radii)
        .filter(|(p, _)| {
            p[2] >= z_lo && p[2] <= z_hi && (p[0] - axis[0]).hypot(p[1] - axis[1]) <= radius
        })
        .map(|(_, r)| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::soil::surface_level;

    /// A 160 mm bin's surface, 2 mm cells: a flat surface at `level` with a round hole of
    /// `hole_d` around the axis, 100 mm deep.
    fn field(level: f64, hole_d: f64) -> HeightField {
        let (cell, n) = (0.002, 80);
        let mut hf = HeightField {
            x0: -0.08,
            y0: -0.08,
            cell,
            nx: n,
            ny: n,
            z: vec![level; n * n],
        };
        for j in 0..n {
            for i in 0..n {
                if hf.x(i).hypot(hf.y(j)) < 0.5 * hole_d {
                    hf.z[j * n + i] = level - 0.1;
                }
            }
        }
        hf
    }

    #[test]
    fn a_sunken_surface_reads_as_the_bin_against_the_original_level_and_as_the_hole_against_the_settled_one(
    ) {
        let original = 0.168;
        let open_depth = 0.006;
        // The surface stays where it was: both levels give the 60 mm hole.
        let hf = field(original, 0.06);
        let at_original = measure_hole(&hf, original, [0.0, 0.0], open_depth, 0.03);
        assert!(
            (at_original.opening_diameter - 0.06).abs() < 0.004,
            "{at_original:?}"
        );
        let settled = surface_level(&hf, 0.012);
        assert_eq!(settled, original);
        // The whole surface sank 8 mm (more than the 6 mm open depth): against the original
        // level every cell is open and the "opening" is the bin; against the settled level it is
        // the hole again.
        let hf = field(original - 0.008, 0.06);
        let at_original = measure_hole(&hf, original, [0.0, 0.0], open_depth, 0.03);
        assert!(at_original.opening_diameter > 0.17, "{at_original:?}");
        let settled = surface_level(&hf, 0.012);
        assert!((original - settled - 0.008).abs() < 1e-12);
        let at_settled = measure_hole(&hf, settled, [0.0, 0.0], open_depth, 0.03);
        assert!(
            (at_settled.opening_diameter - 0.06).abs() < 0.004,
            "{at_settled:?}"
        );
        assert!((at_settled.effective_depth - 0.1).abs() < 1e-12);
    }
}
