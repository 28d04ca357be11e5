//! Neighbour search: linked cells → a Verlet half pair list with a skin.
//!
//! Each particle has its own half skin h (chosen from its speed at the build, see
//! `particles::BuildMark`). The list holds every pair (i, j), i < j, whose surfaces are closer
//! than h_i + h_j. It stays valid until some particle has moved more than its own h since the
//! build (until then the gap of a pair left out has closed by less than h_i + h_j). Pairs are grouped by their lower index `i`
//! (CSR: `first_pair[i]..first_pair[i+1]`), so the contact loop can run over particles, each
//! owning its pairs, with no write conflicts. Each pair carries its contact history; at a
//! rebuild the histories are carried over by matching the pair's particles through their index
//! at the previous build.

use rayon::prelude::*;

use crate::math::Vec3;
use crate::particles::{Particles, NEW_PARTICLE};

/// Particles per parallel work item. Fixed (not derived from the thread count) so that work
/// partitioning never changes results.
pub(crate) const CHUNK: usize = 512;

/// Top bit of a [`PairList::partner`] entry: the pair was in contact at the last force
/// evaluation (kept across builds; a non-zero carried history sets it too). When it is clear, the
/// pair's histories and its partner share are zero: a pair within the skin but not touching
/// costs no writes (only the step it separates resets them), and the gather adds every
/// incident share without reading this flag.
pub(crate) const IN_CONTACT: u32 = 1 << 31;
/// Second bit of a [`PairList::partner`] entry: at the build the two particles were closest
/// across a periodic face, so their separation needs the minimum image. Positions are wrapped
/// into the box only at builds (between builds they move continuously), so a pair without this
/// bit needs no image until the next build, and a non-periodic world never sets it.
pub(crate) const WRAPS: u32 = 1 << 30;
/// The particle index bits of a [`PairList::partner`] entry.
pub(crate) const PARTNER_INDEX: u32 = !(IN_CONTACT | WRAPS);

/// The simulation box. Particles leaving it through a non-periodic face are removed.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Domain {
    pub min: Vec3,
    pub max: Vec3,
    /// Periodic in x and in y (z, the gravity direction, is never periodic). Positions are
    /// wrapped into the box at each neighbour rebuild; between rebuilds a particle that crossed
    /// a periodic face may sit up to half a skin outside it.
    pub periodic_x: bool,
    pub periodic_y: bool,
}

impl Domain {
    /// A closed (non-periodic) box.
    pub fn closed(min: Vec3, max: Vec3) -> Domain {
        Domain {
            min,
            max,
            periodic_x: false,
            periodic_y: false,
        }
    }

    /// The shortest periodic image of a separation vector.
    ///
    /// Both positions are kept inside the box, so |d| < L and one conditional shift suffices
    /// (much cheaper than `round`, which is a libm call).
    #[inline]
    pub(crate) fn minimum_image(&self, mut d: Vec3) -> Vec3 {
        #[inline]
        fn image(d: f64, length: f64) -> f64 {
            if d > 0.5 * length {
                d - length
            } else if d < -0.5 * length {
                d + length
            } else {
                d
            }
        }
        if self.periodic_x {
            d.x = image(d.x, self.max.x - self.min.x);
        }
        if self.periodic_y {
            d.y = image(d.y, self.max.y - self.min.y);
        }
        d
    }

    /// Map a position back into the box across periodic faces.
    #[inline]
    pub(crate) fn wrap(&self, mut p: Vec3) -> Vec3 {
        #[inline]
        fn wrap(x: f64, min: f64, max: f64) -> f64 {
            if x >= min && x < max {
                x
            } else {
                let length = max - min;
                let wrapped = x - length * ((x - min) / length).floor();
                // Rounding can land exactly on `max`.
                if wrapped >= max {
                    min
                } else {
                    wrapped
                }
            }
        }
        if self.periodic_x {
            p.x = wrap(p.x, self.min.x, self.max.x);
        }
        if self.periodic_y {
            p.y = wrap(p.y, self.min.y, self.max.y);
        }
        p
    }

    /// True if `p` is outside the box through a non-periodic face.
    #[inline]
    pub(crate) fn is_outside(&self, p: Vec3) -> bool {
        (!self.periodic_x && (p.x < self.min.x || p.x > self.max.x))
            || (!self.periodic_y && (p.y < self.min.y || p.y > self.max.y))
            || p.z < self.min.z
            || p.z > self.max.z
            || !p.iter().all(|c| c.is_finite())
    }
}

/// What particle j receives from a pair (i, j) whose force was computed by particle i.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct PartnerShare {
    pub force: Vec3,
    pub torque: Vec3,
    /// CDT rolling moment magnitude μr Fn Rj (applied against j's own ω at the gather).
    pub rolling_moment: f64,
}

/// The half pair list with per-pair contact history.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct PairList {
    /// CSR offsets, length n + 1: the pairs whose lower index is i.
    pub first_pair: Vec<u32>,
    /// The higher index j of each pair ([`PARTNER_INDEX`] bits) and the pair's
    /// [`IN_CONTACT`] flag.
    pub partner: Vec<u32>,
    /// Tangential spring δt of each pair, for i (j's is the negative).
    pub tangential: Vec<Vec3>,
    /// EPSD rolling spring torque on i (empty unless EPSD is used).
    pub rolling: Vec<Vec3>,
    /// Contributions to the higher-index particle, written by the contact loop for the pairs
    /// in contact; zero for the others (see [`IN_CONTACT`]).
    pub partner_share: Vec<PartnerShare>,
    /// CSR offsets, length n + 1: the pairs in which particle k is the higher index j.
    pub incidence_start: Vec<u32>,
    /// Pair indices (ascending) for the incidence CSR.
    pub incidence_pair: Vec<u32>,
}

impl PairList {
    pub fn pair_count(&self) -> usize {
        self.partner.len()
    }

    pub fn memory_bytes(&self) -> usize {
        self.first_pair.len() * 4
            + self.partner.len() * 4
            + self.tangential.len() * std::mem::size_of::<Vec3>()
            + self.rolling.len() * std::mem::size_of::<Vec3>()
            + self.partner_share.len() * std::mem::size_of::<PartnerShare>()
            + self.incidence_start.len() * 4
            + self.incidence_pair.len() * 4
    }

    /// Find the history of the pair (old index a, old index b) in this (previous) list.
    #[inline]
    pub(crate) fn find(&self, a: u32, b: u32) -> Option<(usize, bool)> {
        let (lo, hi, swapped) = if a < b { (a, b, false) } else { (b, a, true) };
        let lo = lo as usize;
        if lo + 1 >= self.first_pair.len() {
            return None;
        }
        let range = self.first_pair[lo] as usize..self.first_pair[lo + 1] as usize;
        let start = range.start;
        self.partner[range]
            .iter()
            .position(|&j| j & PARTNER_INDEX == hi)
            .map(|k| (start + k, swapped))
    }
}

/// At most this many cells per particle in a [`CellGrid`] (its cells are widened beyond the
/// asked size to stay within it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct CellBudget(pub usize);

/// The budget of the grid whose cell order the particle arrays are sorted in, and of the
/// sources' free-space test: 4 cells per particle. The sort order decides the order forces
/// are summed in, so this budget is part of every trajectory; it is kept as it was.
pub(crate) const SORT_CELLS: CellBudget = CellBudget(4);

/// The budget of the pair search's grid: 32 cells per particle. A heap spreads over a plate
/// much wider than it is dense: the paper-scale pour's particles end spanning 0.26 × 0.23 ×
/// 0.15 m, where 4 cells per particle widen the asked 3 mm cells to 4.3 mm (about three times
/// the candidates per particle). Only the run's late part is that spread: the whole run gained
/// 1-2 % (BENCHMARKS.md, 2026-11-26). Empty cells cost 4 bytes and one prefix-sum step each at
/// a rebuild. The pair list does not depend on the cell size (every pair within reach,
/// partners in ascending order), so neither does any result.
pub(crate) const SEARCH_CELLS: CellBudget = CellBudget(32);

/// A uniform grid of cells at least `cell_size` wide covering the domain.
#[derive(Debug, Clone)]
pub(crate) struct CellGrid {
    origin: Vec3,
    inverse_size: Vec3,
    dims: [usize; 3],
    periodic: [bool; 3],
    /// Start of each cell in `sorted` (length cells + 1).
    cell_start: Vec<u32>,
    /// Particle indices in cell order (stable within a cell).
    pub sorted: Vec<u32>,
    /// The budget widened the cells beyond the asked size (a larger budget would give
    /// another grid).
    pub widened: bool,
}

impl CellGrid {
    /// Cells at least `cell_size` wide. Periodic axes are tiled exactly by the cells (the
    /// period must be a whole number of cells); other axes span only the particles' extent, so
    /// a few particles in a huge domain do not allocate a huge grid. The cell count is also
    /// capped at `budget` cells per particle (at least 4 096 cells) by widening the cells
    /// (still correct, just more pairs tested): [`SORT_CELLS`] or [`SEARCH_CELLS`].
    pub fn build(
        domain: &Domain,
        cell_size: f64,
        positions: &[Vec3],
        budget: CellBudget,
    ) -> CellGrid {
        let periodic = [domain.periodic_x, domain.periodic_y, false];
        let (mut lo, mut hi) = (domain.min, domain.max);
        if !positions.is_empty() {
            let (plo, phi) = positions.iter().fold(
                (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
                |(lo, hi), p| (lo.inf(p), hi.sup(p)),
            );
            for a in 0..3 {
                if !periodic[a] && plo[a].is_finite() && phi[a].is_finite() {
                    lo[a] = plo[a];
                    hi[a] = phi[a].max(plo[a] + cell_size);
                }
            }
        }
        let extent = hi - lo;
        let max_cells = (budget.0 * positions.len()).max(4096) as f64;
        let volume = extent.x * extent.y * extent.z;
        let size = cell_size.max((volume / max_cells).cbrt());
        let mut dims = [1usize; 3];
        let mut inverse_size = Vec3::zeros();
        for a in 0..3 {
            let n = ((extent[a] / size).floor() as usize).clamp(1, 1 << 20);
            dims[a] = n;
            inverse_size[a] = n as f64 / extent[a];
        }
        let mut grid = CellGrid {
            origin: lo,
            inverse_size,
            dims,
            periodic,
            cell_start: Vec::new(),
            sorted: Vec::new(),
            widened: size > cell_size,
        };
        let cells: Vec<u32> = positions
            .par_iter()
            .with_min_len(CHUNK)
            .map(|p| grid.cell_of(*p) as u32)
            .collect();
        let cell_count = dims[0] * dims[1] * dims[2];
        let mut start = vec![0u32; cell_count + 1];
        for &c in &cells {
            start[c as usize + 1] += 1;
        }
        for c in 0..cell_count {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut sorted = vec![0u32; positions.len()];
        for (k, &c) in cells.iter().enumerate() {
            sorted[fill[c as usize] as usize] = k as u32;
            fill[c as usize] += 1;
        }
        grid.cell_start = start;
        grid.sorted = sorted;
        grid
    }

    #[inline]
    fn coords(&self, p: Vec3) -> [usize; 3] {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let x = ((p[a] - self.origin[a]) * self.inverse_size[a]).floor();
            let n = self.dims[a] as f64;
            let x = if self.periodic[a] {
                x - n * (x / n).floor()
            } else {
                x
            };
            c[a] = x.clamp(0.0, n - 1.0) as usize;
        }
        c
    }

    #[inline]
    fn cell_of(&self, p: Vec3) -> usize {
        let [x, y, z] = self.coords(p);
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    /// The particles of the distinct neighbouring cells (including its own) of the cell
    /// containing `p`, as ranges of [`Self::sorted`]: cells adjacent along x are adjacent in
    /// `sorted`, so each (y, z) row of up to three cells is one range (two where x wraps
    /// across a periodic face). Cells in ascending (z, y, x) order, as a cell-by-cell walk.
    fn neighbour_ranges(&self, p: Vec3, out: &mut Vec<std::ops::Range<usize>>) {
        out.clear();
        let c = self.coords(p);
        let mut along: [[usize; 3]; 3] = [[0; 3]; 3];
        let mut counts = [0usize; 3];
        for a in 0..3 {
            for d in [-1i64, 0, 1] {
                let mut x = c[a] as i64 + d;
                let n = self.dims[a] as i64;
                if self.periodic[a] {
                    x = x.rem_euclid(n);
                } else if x < 0 || x >= n {
                    continue;
                }
                let x = x as usize;
                if !along[a][..counts[a]].contains(&x) {
                    along[a][counts[a]] = x;
                    counts[a] += 1;
                }
            }
            along[a][..counts[a]].sort_unstable();
        }
        let xs = &along[0][..counts[0]];
        for &z in &along[2][..counts[2]] {
            for &y in &along[1][..counts[1]] {
                let row = (z * self.dims[1] + y) * self.dims[0];
                let mut k = 0;
                while k < xs.len() {
                    let first = xs[k];
                    while k + 1 < xs.len() && xs[k + 1] == xs[k] + 1 {
                        k += 1;
                    }
                    let last = xs[k];
                    k += 1;
                    out.push(
                        self.cell_start[row + first] as usize
                            ..self.cell_start[row + last + 1] as usize,
                    );
                }
            }
        }
    }

    /// Call `f` with every particle index in the cells overlapping the box of half-width
    /// `reach` around `p` (each at most once).
    pub fn for_each_near(&self, p: Vec3, reach: f64, mut f: impl FnMut(u32)) {
        let mut ranges = [[0i64; 2]; 3];
        for a in 0..3 {
            let n = self.dims[a] as i64;
            let lo = ((p[a] - reach - self.origin[a]) * self.inverse_size[a]).floor() as i64;
            let hi = ((p[a] + reach - self.origin[a]) * self.inverse_size[a]).floor() as i64;
            ranges[a] = if self.periodic[a] {
                if hi - lo + 1 >= n {
                    [0, n - 1]
                } else {
                    [lo, hi]
                }
            } else {
                [lo.clamp(0, n - 1), hi.clamp(0, n - 1)]
            };
        }
        let wrap = |x: i64, a: usize| x.rem_euclid(self.dims[a] as i64) as usize;
        for z in ranges[2][0]..=ranges[2][1] {
            for y in ranges[1][0]..=ranges[1][1] {
                for x in ranges[0][0]..=ranges[0][1] {
                    let c = (wrap(z, 2) * self.dims[1] + wrap(y, 1)) * self.dims[0] + wrap(x, 0);
                    self.cell(c).iter().for_each(|&k| f(k));
                }
            }
        }
    }

    #[inline]
    fn cell(&self, c: usize) -> &[u32] {
        &self.sorted[self.cell_start[c] as usize..self.cell_start[c + 1] as usize]
    }
}

/// Build the half pair list for the current particle positions (surface gap < h_i + h_j, the
/// particles' half skins), carrying
/// over histories from `previous` via `particles.index_at_build`.
pub(crate) fn build_pair_list(
    particles: &Particles,
    domain: &Domain,
    grid: &CellGrid,
    half_skin: &[f32],
    with_rolling_history: bool,
    previous: &PairList,
) -> PairList {
    let n = particles.len();
    let positions = &particles.position;
    let radius = &particles.radius;
    let index_at_build = &particles.index_at_build;
    let carry_rolling = with_rolling_history && previous.rolling.len() == previous.partner.len();
    let periodic = domain.periodic_x || domain.periodic_y;

    struct ChunkPairs {
        counts: Vec<u32>,
        partner: Vec<u32>,
        tangential: Vec<Vec3>,
        rolling: Vec<Vec3>,
    }
    // The candidates' positions and reaches in cell order, so that a row of cells is read
    // from one contiguous stretch of memory.
    let packed: Vec<(Vec3, f64)> = grid
        .sorted
        .par_iter()
        .with_min_len(CHUNK)
        .map(|&j| {
            let j = j as usize;
            (positions[j], radius[j] + half_skin[j] as f64)
        })
        .collect();

    let chunks: Vec<ChunkPairs> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .with_max_len(1)
        .map(|chunk| {
            let range = chunk * CHUNK..((chunk + 1) * CHUNK).min(n);
            let mut out = ChunkPairs {
                counts: Vec::with_capacity(range.len()),
                partner: Vec::with_capacity(range.len() * 8),
                tangential: Vec::with_capacity(range.len() * 8),
                rolling: Vec::new(),
            };
            let mut ranges = Vec::with_capacity(18);
            // Particles are sorted by cell, so runs of them share one neighbourhood.
            let mut cells_of = usize::MAX;
            for i in range {
                let start = out.partner.len();
                let pi = positions[i];
                let ri = radius[i] + half_skin[i] as f64;
                let cell = grid.cell_of(pi);
                if cell != cells_of {
                    grid.neighbour_ranges(pi, &mut ranges);
                    cells_of = cell;
                }
                for range in &ranges {
                    let candidates = grid.sorted[range.clone()]
                        .iter()
                        .zip(&packed[range.clone()]);
                    for (&j, &(pj, reach_j)) in candidates {
                        let j = j as usize;
                        if j <= i {
                            continue;
                        }
                        let raw = pj - pi;
                        let d = if periodic {
                            domain.minimum_image(raw)
                        } else {
                            raw
                        };
                        let reach = ri + reach_j;
                        if d.norm_squared() < reach * reach {
                            let wraps = if d == raw { 0 } else { WRAPS };
                            out.partner.push(j as u32 | wraps);
                        }
                    }
                }
                out.partner[start..].sort_unstable_by_key(|&j| j & PARTNER_INDEX);
                let old_i = index_at_build[i];
                for k in start..out.partner.len() {
                    let old_j = index_at_build[(out.partner[k] & PARTNER_INDEX) as usize];
                    let found = if old_i == NEW_PARTICLE || old_j == NEW_PARTICLE {
                        None
                    } else {
                        previous.find(old_i, old_j)
                    };
                    let (t, r, touching) = match found {
                        Some((p, swapped)) => {
                            let sign = if swapped { -1.0 } else { 1.0 };
                            let r = if carry_rolling {
                                previous.rolling[p] * sign
                            } else {
                                Vec3::zeros()
                            };
                            let touching = previous.partner[p] & IN_CONTACT != 0;
                            (previous.tangential[p] * sign, r, touching)
                        }
                        None => (Vec3::zeros(), Vec3::zeros(), false),
                    };
                    // The flag is carried even with zero histories: a JKR contact in its
                    // necking range (negative overlap) exists only because it was in contact.
                    if touching || t != Vec3::zeros() || r != Vec3::zeros() {
                        out.partner[k] |= IN_CONTACT;
                    }
                    out.tangential.push(t);
                    if with_rolling_history {
                        out.rolling.push(r);
                    }
                }
                out.counts.push((out.partner.len() - start) as u32);
            }
            out
        })
        .collect();

    let total: usize = chunks.iter().map(|c| c.partner.len()).sum();
    let mut list = PairList {
        first_pair: Vec::with_capacity(n + 1),
        partner: Vec::with_capacity(total),
        tangential: Vec::with_capacity(total),
        rolling: Vec::with_capacity(if with_rolling_history { total } else { 0 }),
        partner_share: vec![PartnerShare::default(); total],
        incidence_start: vec![0; n + 1],
        incidence_pair: vec![0; total],
    };
    list.first_pair.push(0);
    let mut offset = 0u32;
    for chunk in chunks {
        for c in chunk.counts {
            offset += c;
            list.first_pair.push(offset);
        }
        list.partner.extend_from_slice(&chunk.partner);
        list.tangential.extend_from_slice(&chunk.tangential);
        list.rolling.extend_from_slice(&chunk.rolling);
    }
    // Incidence CSR (pairs where k is the higher index), pair indices ascending.
    for &j in &list.partner {
        list.incidence_start[(j & PARTNER_INDEX) as usize + 1] += 1;
    }
    for k in 0..n {
        list.incidence_start[k + 1] += list.incidence_start[k];
    }
    let mut fill = list.incidence_start.clone();
    for (p, &j) in list.partner.iter().enumerate() {
        let j = j & PARTNER_INDEX;
        list.incidence_pair[fill[j as usize] as usize] = p as u32;
        fill[j as usize] += 1;
    }
    list
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::material::MaterialId;
    use crate::particles::ParticleSpec;

    /// Every (i, j > i) with surface gap < h_i + h_j, partners ascending: the list's definition.
    fn brute_force(p: &Particles, half_skin: &[f32]) -> Vec<Vec<u32>> {
        (0..p.len())
            .map(|i| {
                (i + 1..p.len())
                    .filter(|&j| {
                        let reach =
                            p.radius[i] + half_skin[i] as f64 + p.radius[j] + half_skin[j] as f64;
                        (p.position[j] - p.position[i]).norm_squared() < reach * reach
                    })
                    .map(|j| j as u32)
                    .collect()
            })
            .collect()
    }

    #[test]
    fn the_pair_list_does_not_depend_on_the_cell_budget() {
        // A dense clump of 1 mm grains and a few strays up to 0.1 m away: 4 cells per particle
        // widen the cells to ~5.5 mm, 32 per particle keep the asked 3 mm.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut p = Particles::default();
        let (r, count) = (0.001, 1500);
        for k in 0..count + 6 {
            let x = if k < count {
                Vec3::new(
                    rng.gen_range(0.0..0.03),
                    rng.gen_range(0.0..0.03),
                    rng.gen_range(0.0..0.015),
                )
            } else {
                Vec3::repeat(0.1) * (k - count) as f64 / 5.0
            };
            p.push(
                k as u64,
                &ParticleSpec::at_rest(x, r, MaterialId(0)),
                2500.0,
            );
        }
        let half_skin: Vec<f32> = (0..p.len())
            .map(|_| rng.gen_range(0.15 * r..0.5 * r) as f32)
            .collect();
        let domain = Domain::closed(Vec3::repeat(-1.0), Vec3::repeat(1.0));
        let cell_size = 2.0 * r + r;
        let expected = brute_force(&p, &half_skin);
        let listed: usize = expected.iter().map(Vec::len).sum();
        assert!(listed > 3 * count, "a dense clump: {listed} pairs");
        let mut widths = Vec::new();
        for budget in [SORT_CELLS, SEARCH_CELLS] {
            let grid = CellGrid::build(&domain, cell_size, &p.position, budget);
            widths.push(1.0 / grid.inverse_size.x);
            assert_eq!(grid.widened, budget == SORT_CELLS, "budget {budget:?}");
            let list = build_pair_list(&p, &domain, &grid, &half_skin, false, &PairList::default());
            let found: Vec<Vec<u32>> = (0..p.len())
                .map(|i| {
                    let range = list.first_pair[i] as usize..list.first_pair[i + 1] as usize;
                    list.partner[range]
                        .iter()
                        .map(|&j| j & PARTNER_INDEX)
                        .collect()
                })
                .collect();
            assert_eq!(found, expected, "budget {budget:?}");
        }
        assert!(
            widths[0] > 1.5 * cell_size,
            "the sort budget widens: {widths:?}"
        );
        assert!(
            widths[1] < 1.2 * cell_size,
            "the search budget does not: {widths:?}"
        );
    }
}
