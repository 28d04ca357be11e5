//! The voxel grid positions are held on (an integer voxel plus an f32 offset inside it) and
//! the binning of triangles into a grid's cells: what the scene (the world's voxels and static
//! triangles) and the moving meshes (their body grids) both build on. Pure data, no device.

use repose_engine::math::Vec3;
use repose_engine::world::World;

use crate::GpuError;

/// A position as the GPU holds it: an integer voxel and the f32 offset inside it.
pub type Voxel = ([i32; 3], [f32; 3]);

/// The voxel grid: it places positions (integer voxel + offset) and bins the neighbour search.
/// Periodic axes hold a whole number of voxels, so wrapping is an integer operation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub min: Vec3,
    pub voxel: Vec3,
    pub dims: [i32; 3],
    pub periodic: [bool; 2],
}

impl Grid {
    /// A grid over `world`'s domain with voxels at least `min_voxel` wide.
    pub fn new(world: &World, min_voxel: f64) -> Result<Grid, GpuError> {
        let domain = world.config().domain;
        let extent = domain.max - domain.min;
        let periodic = [domain.periodic_x, domain.periodic_y];
        let mut dims = [0i32; 3];
        let mut voxel = Vec3::zeros();
        for a in 0..3 {
            let whole = a < 2 && periodic[a];
            let n = if whole {
                (extent[a] / min_voxel).floor()
            } else {
                (extent[a] / min_voxel).ceil()
            };
            if whole && n < 3.0 {
                return Err(GpuError::Capacity(format!(
                    "a periodic axis holds {n} neighbour cells; at least 3 are needed \
                     (domain {:.4} m, cells {min_voxel:.4} m)",
                    extent[a]
                )));
            }
            if !(1.0..=65_536.0).contains(&n) {
                return Err(GpuError::Capacity(format!(
                    "the domain is {n} neighbour cells along axis {a} (at most 65536)"
                )));
            }
            dims[a] = n as i32;
            voxel[a] = if whole { extent[a] / n } else { min_voxel };
        }
        Ok(Grid {
            min: domain.min,
            voxel,
            dims,
            periodic,
        })
    }

    /// Cells in the grid.
    pub fn cells(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// `x` as a voxel and an offset in it (periodic axes wrapped into the grid).
    pub fn to_voxel(&self, x: Vec3) -> Voxel {
        self.voxel_of(x, true)
    }

    /// `x` as a voxel and an offset, not wrapped: geometry stays where it is (a particle
    /// sees a triangle at its place, not at a periodic image).
    pub fn to_voxel_unwrapped(&self, x: Vec3) -> Voxel {
        self.voxel_of(x, false)
    }

    fn voxel_of(&self, x: Vec3, wrap: bool) -> Voxel {
        let mut cell = [0i32; 3];
        let mut offset = [0f32; 3];
        for a in 0..3 {
            let u = x[a] - self.min[a];
            let k = (u / self.voxel[a]).floor();
            let mut o = (u - k * self.voxel[a]) as f32;
            // Rounding to f32 may reach the voxel's far face.
            if o >= self.voxel[a] as f32 {
                o = (self.voxel[a] as f32).next_down_f32();
            }
            let mut k = k as i64;
            if wrap && a < 2 && self.periodic[a] {
                k = k.rem_euclid(self.dims[a] as i64);
            }
            cell[a] = k as i32;
            offset[a] = o.max(0.0);
        }
        (cell, offset)
    }

    /// The position of a voxel and offset, m.
    pub fn to_position(&self, cell: [i32; 3], offset: [f32; 3]) -> Vec3 {
        Vec3::from_fn(|a, _| self.min[a] + cell[a] as f64 * self.voxel[a] + offset[a] as f64)
    }

    /// The vector from `b` to `a` as the shader computes it (minimum image across periodic
    /// faces, integer voxel difference times the voxel plus the offsets' difference, in f32).
    pub fn difference(&self, a: Voxel, b: Voxel) -> [f32; 3] {
        std::array::from_fn(|k| {
            let mut dc = a.0[k] - b.0[k];
            if k < 2 && self.periodic[k] {
                let n = self.dims[k];
                if dc > n / 2 {
                    dc -= n;
                } else if dc < -(n / 2) {
                    dc += n;
                }
            }
            dc as f32 * self.voxel[k] as f32 + (a.1[k] - b.1[k])
        })
    }
}

/// `next_down` for f32 on the toolchains this crate supports.
trait NextDown {
    fn next_down_f32(self) -> f32;
}

impl NextDown for f32 {
    fn next_down_f32(self) -> f32 {
        if self > 0.0 {
            f32::from_bits(self.to_bits() - 1)
        } else {
            self
        }
    }
}

/// The static triangles binned into the neighbour grid's voxels, in one array: `ncells + 1`
/// starts, then the triangle indices (each voxel's ascending). Triangle `t` is listed in voxel
/// `c` iff `t`'s bounding box, grown by the reach, touches `c`.
///
/// One voxel suffices for a grain: a grain of radius r touches a triangle only if its centre
/// lies within r of the triangle, hence inside the triangle's bounding box grown by r; with r
/// no larger than the reach, the voxel holding the centre touches that grown box, so the
/// triangle is listed there. The reach is the largest radius plus 1 % (f32 rounding of the
/// contact test) and the grain's voxel is its current one (updated every step), so no skin.
pub(crate) fn bin_triangles(grid: &Grid, corners: &[[Vec3; 3]], reach: f64) -> Vec<u32> {
    let ncells = grid.cells();
    let range = |corners: &[Vec3; 3]| -> Option<[[i32; 2]; 3]> {
        let mut r = [[0i32; 2]; 3];
        for a in 0..3 {
            let lo = corners.iter().map(|c| c[a]).fold(f64::INFINITY, f64::min) - reach;
            let hi = corners
                .iter()
                .map(|c| c[a])
                .fold(f64::NEG_INFINITY, f64::max)
                + reach;
            let lo = ((lo - grid.min[a]) / grid.voxel[a]).floor().max(0.0);
            let hi = ((hi - grid.min[a]) / grid.voxel[a])
                .floor()
                .min(grid.dims[a] as f64 - 1.0);
            if lo > hi {
                return None; // wholly outside the grid: no grain can reach it
            }
            r[a] = [lo as i32, hi as i32];
        }
        Some(r)
    };
    let index = |x: i32, y: i32, z: i32| (x + grid.dims[0] * (y + grid.dims[1] * z)) as usize;
    let ranges: Vec<_> = corners.iter().map(range).collect();
    let mut count = vec![0u32; ncells + 1];
    for r in ranges.iter().flatten() {
        for z in r[2][0]..=r[2][1] {
            for y in r[1][0]..=r[1][1] {
                for x in r[0][0]..=r[0][1] {
                    count[index(x, y, z) + 1] += 1;
                }
            }
        }
    }
    for c in 0..ncells {
        count[c + 1] += count[c];
    }
    let entries = count[ncells] as usize;
    let mut out = count.clone();
    out.resize(ncells + 1 + entries, 0);
    let mut next = count;
    // Triangles in ascending order: each voxel's list is ascending.
    for (t, r) in ranges.iter().enumerate() {
        let Some(r) = r else { continue };
        for z in r[2][0]..=r[2][1] {
            for y in r[1][0]..=r[1][1] {
                for x in r[0][0]..=r[0][1] {
                    let c = index(x, y, z);
                    out[ncells + 1 + next[c] as usize] = t as u32;
                    next[c] += 1;
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use repose_engine::material::{Interaction, MaterialSet};
    use repose_engine::neighbor::Domain;
    use repose_engine::world::WorldConfig;

    fn grid(periodic: bool) -> Grid {
        let materials = MaterialSet::paper(
            Interaction::new(0.5, 0.5, 0.1),
            Interaction::new(0.5, 0.5, 0.1),
        )
        .build()
        .unwrap();
        let mut domain = Domain::closed(Vec3::zeros(), Vec3::repeat(0.3));
        domain.periodic_x = periodic;
        domain.periodic_y = periodic;
        let world = World::new(materials, WorldConfig::new(1e-6, domain)).unwrap();
        Grid::new(&world, 2.75e-3).unwrap()
    }

    #[test]
    fn an_overlap_of_a_thousandth_of_a_radius_is_resolved_anywhere_in_a_03_m_domain() {
        let r = 1.0e-3;
        let overlap = 1e-3 * r;
        for periodic in [false, true] {
            let g = grid(periodic);
            for corner in [0.001, 0.15, 0.2987] {
                for axis in 0..3 {
                    let a = Vec3::repeat(corner);
                    let mut b = a;
                    b[axis] += 2.0 * r - overlap;
                    let d = g.difference(g.to_voxel(b), g.to_voxel(a));
                    let dist = (d[0] as f64).hypot(d[1] as f64).hypot(d[2] as f64);
                    let error = ((2.0 * r - dist) - overlap).abs();
                    // Plain f32 positions near 0.3 m are spaced 3e-8 m: 3 % of this overlap.
                    assert!(
                        error < 1e-3 * overlap,
                        "at {corner} m along {axis}: overlap error {error:e} m"
                    );
                }
            }
        }
    }

    #[test]
    fn positions_round_trip_through_voxels_to_the_offsets_resolution() {
        let g = grid(false);
        for x in [0.0, 1e-9, 0.123_456_789, 0.299_999] {
            let p = Vec3::new(x, 0.3 - x, x / 2.0);
            let (c, o) = g.to_voxel(p);
            let back = g.to_position(c, o);
            assert!((back - p).norm() < 1e-9, "{p:?} -> {back:?}");
            assert!(o
                .iter()
                .zip(g.voxel.iter())
                .all(|(&o, &v)| o >= 0.0 && (o as f64) < v));
        }
    }

    /// Every point within the reach of a triangle (a point of the triangle plus an offset no
    /// longer than the reach) lies in a voxel that lists the triangle; each voxel's list is
    /// ascending and a triangle outside the grid is in none.
    #[test]
    fn a_voxel_lists_every_triangle_within_reach_of_its_points() {
        let g = grid(false);
        let reach = 1.0e-3;
        let corners = vec![
            // flat, small; slanted across many voxels; a sliver; one wholly outside the grid
            [
                Vec3::new(0.1, 0.1, 0.05),
                Vec3::new(0.104, 0.1, 0.05),
                Vec3::new(0.1, 0.103, 0.05),
            ],
            [
                Vec3::new(0.02, 0.03, 0.01),
                Vec3::new(0.05, 0.02, 0.04),
                Vec3::new(0.03, 0.06, 0.02),
            ],
            [
                Vec3::new(0.2, 0.2, 0.2),
                Vec3::new(0.2101, 0.2, 0.2),
                Vec3::new(0.21, 0.2, 0.2001),
            ],
            [
                Vec3::new(0.5, 0.5, 0.5),
                Vec3::new(0.6, 0.5, 0.5),
                Vec3::new(0.5, 0.6, 0.5),
            ],
        ];
        let lists = bin_triangles(&g, &corners, reach);
        let ncells = g.cells();
        let listed = |c: [i32; 3]| -> &[u32] {
            let v = (c[0] + g.dims[0] * (c[1] + g.dims[1] * c[2])) as usize;
            &lists[ncells + 1 + lists[v] as usize..ncells + 1 + lists[v + 1] as usize]
        };
        for v in 0..ncells {
            let l = &lists[ncells + 1 + lists[v] as usize..ncells + 1 + lists[v + 1] as usize];
            assert!(l.windows(2).all(|w| w[0] < w[1]), "voxel {v}: {l:?}");
            assert!(!l.contains(&3), "the triangle outside the grid is listed");
        }
        let mut state = 12345u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for (t, [a, b, c]) in corners.iter().take(3).enumerate() {
            for _ in 0..2000 {
                let (mut u, mut v) = (uniform(), uniform());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let on = a + (b - a) * u + (c - a) * v;
                let dir = Vec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5);
                let p = on + dir.normalize() * (reach * uniform().sqrt());
                let (cell, _) = g.to_voxel(p);
                assert!(
                    listed(cell).contains(&(t as u32)),
                    "triangle {t} not listed at {p:?} (voxel {cell:?})"
                );
            }
        }
    }

    #[test]
    fn periodic_axes_wrap_positions_and_take_the_minimum_image() {
        let g = grid(true);
        let (c, _) = g.to_voxel(Vec3::new(-0.001, 0.301, 0.1));
        assert!(c[0] == g.dims[0] - 1 && c[1] == 0, "{c:?}");
        let a = g.to_voxel(Vec3::new(0.0005, 0.1, 0.1));
        let b = g.to_voxel(Vec3::new(0.2995, 0.1, 0.1));
        let d = g.difference(a, b);
        assert!((d[0] as f64 - 0.001).abs() < 1e-9, "{d:?}");
    }
}
