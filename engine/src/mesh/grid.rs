//! Uniform-grid broad phase over the triangles of one mesh, in the mesh's body frame.
//!
//! Built once per mesh. A sphere query visits only the cells its bounding box overlaps, so its
//! cost is proportional to the number of triangles near the sphere. A uniform grid (rather than a
//! BVH) suits DEM geometry well: walls, funnels and augers are made of triangles of similar size,
//! and the grid needs no per-query stack or allocation.

use crate::math::Vec3;

/// Cells stored in compressed-row form: the triangles of cell `c` are
/// `items[starts[c]..starts[c + 1]]`.
#[derive(Debug, Clone)]
pub(crate) struct Grid {
    origin: Vec3,
    inverse_cell_size: f64,
    dims: [usize; 3],
    starts: Vec<u32>,
    items: Vec<u32>,
    /// Lowest cell (per axis) each triangle occupies. A triangle spanning several cells is
    /// listed in each of them; a query processes it only in the first cell of the overlap of
    /// its own cell range with the query's range, so it is tested once without a visited-set.
    first_cell: Vec<[u32; 3]>,
}

/// Upper bound on grid cells per triangle, so a mesh of a few large triangles in a big bounding
/// box cannot allocate an absurd grid.
const MAX_CELLS_PER_TRIANGLE: usize = 4;
const MIN_CELL_BUDGET: usize = 64;
/// Upper bound on the average number of cells a triangle is listed in (memory bound).
const MAX_ENTRIES_PER_TRIANGLE: usize = 16;

/// Cell containing `p`, clamped into the grid.
fn cell_index(p: Vec3, lo: Vec3, inverse_cell_size: f64, dims: [usize; 3]) -> [u32; 3] {
    let mut idx = [0u32; 3];
    for axis in 0..3 {
        let f = ((p[axis] - lo[axis]) * inverse_cell_size).floor();
        idx[axis] = f.clamp(0.0, (dims[axis] - 1) as f64) as u32;
    }
    idx
}

impl Grid {
    /// Builds the grid from per-triangle bounding boxes and the overall bounds.
    pub(crate) fn build(tri_boxes: &[(Vec3, Vec3)], lo: Vec3, hi: Vec3) -> Grid {
        let extent = hi - lo;
        let n = tri_boxes.len().max(1);
        // Start from the mean triangle size: most triangles then touch only a few cells.
        let mean_size = tri_boxes.iter().map(|(a, b)| (b - a).max()).sum::<f64>() / n as f64;
        let mut cell = mean_size.max(extent.max() * 1e-6).max(f64::MIN_POSITIVE);
        let budget = (MAX_CELLS_PER_TRIANGLE * n).max(MIN_CELL_BUDGET);
        let dims_for = |cell: f64| -> [usize; 3] {
            let mut d = [1usize; 3];
            for (axis, dim) in d.iter_mut().enumerate() {
                // `as usize` saturates, and the clamp keeps the product from overflowing.
                *dim = ((extent[axis] / cell).floor() as usize + 1).clamp(1, 1 << 20);
            }
            d
        };
        // Grow the cells until both the cell count and the total number of (triangle, cell)
        // entries fit their budgets. The second matters for long thin triangles, such as a
        // fine fan closing a disc, whose bounding boxes each cover many cells.
        let entry_budget = (MAX_ENTRIES_PER_TRIANGLE * n).max(MIN_CELL_BUDGET);
        let (dims, inverse_cell_size) = loop {
            let dims = dims_for(cell);
            let inverse = 1.0 / cell;
            if dims[0] * dims[1] * dims[2] <= budget {
                let entries: usize = tri_boxes
                    .iter()
                    .map(|(a, b)| {
                        let (ca, cb) = (
                            cell_index(*a, lo, inverse, dims),
                            cell_index(*b, lo, inverse, dims),
                        );
                        (0..3)
                            .map(|k| (cb[k] - ca[k] + 1) as usize)
                            .product::<usize>()
                    })
                    .sum();
                if entries <= entry_budget || dims == [1, 1, 1] {
                    break (dims, inverse);
                }
            }
            cell *= 1.25;
        };
        let cell_count = dims[0] * dims[1] * dims[2];
        let cell_of = |p: Vec3| cell_index(p, lo, inverse_cell_size, dims);
        let linear = |i: usize, j: usize, k: usize| (k * dims[1] + j) * dims[0] + i;

        let ranges: Vec<([u32; 3], [u32; 3])> = tri_boxes
            .iter()
            .map(|(a, b)| (cell_of(*a), cell_of(*b)))
            .collect();

        // Two passes (count, then fill) so the cell lists live in one contiguous array.
        let mut counts = vec![0u32; cell_count + 1];
        for (a, b) in &ranges {
            for k in a[2]..=b[2] {
                for j in a[1]..=b[1] {
                    for i in a[0]..=b[0] {
                        counts[linear(i as usize, j as usize, k as usize) + 1] += 1;
                    }
                }
            }
        }
        for c in 0..cell_count {
            counts[c + 1] += counts[c];
        }
        let starts = counts;
        let mut cursor = starts.clone();
        let mut items = vec![0u32; starts[cell_count] as usize];
        for (t, (a, b)) in ranges.iter().enumerate() {
            for k in a[2]..=b[2] {
                for j in a[1]..=b[1] {
                    for i in a[0]..=b[0] {
                        let c = linear(i as usize, j as usize, k as usize);
                        items[cursor[c] as usize] = t as u32;
                        cursor[c] += 1;
                    }
                }
            }
        }
        Grid {
            origin: lo,
            inverse_cell_size,
            dims,
            starts,
            items,
            first_cell: ranges.into_iter().map(|(a, _)| a).collect(),
        }
    }

    /// Calls `visit` once for every triangle whose cells overlap the box `[lo, hi]`.
    pub(crate) fn for_each_candidate(&self, lo: Vec3, hi: Vec3, mut visit: impl FnMut(u32)) {
        let mut first = [0u32; 3];
        let mut last = [0u32; 3];
        for axis in 0..3 {
            let a = ((lo[axis] - self.origin[axis]) * self.inverse_cell_size).floor();
            let b = ((hi[axis] - self.origin[axis]) * self.inverse_cell_size).floor();
            let max = (self.dims[axis] - 1) as f64;
            // Also rejects NaN: comparisons with NaN are false, so `!(..)` is true.
            if !(b >= 0.0 && a <= max) {
                return;
            }
            first[axis] = a.clamp(0.0, max) as u32;
            last[axis] = b.clamp(0.0, max) as u32;
        }
        for k in first[2]..=last[2] {
            for j in first[1]..=last[1] {
                for i in first[0]..=last[0] {
                    let c = (k as usize * self.dims[1] + j as usize) * self.dims[0] + i as usize;
                    let cell = [i, j, k];
                    for &t in &self.items[self.starts[c] as usize..self.starts[c + 1] as usize] {
                        let own = self.first_cell[t as usize];
                        let reference = [
                            own[0].max(first[0]),
                            own[1].max(first[1]),
                            own[2].max(first[2]),
                        ];
                        if reference == cell {
                            visit(t);
                        }
                    }
                }
            }
        }
    }

    /// Number of cells, for diagnostics and tests.
    pub(crate) fn cell_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
}
