//! Reading a soil surface from particle positions: a height field read by a probe sphere
//! ([`height_field`]) and its level away from the walls ([`surface_level`]). The settled bed's
//! surface is read this way, and the drilling test's hole is measured on such a field.
//!
//! Frame: z up, bin floor at z = 0.

use serde::{Deserialize, Serialize};

/// Why a surface could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeasureError {
    #[error("no grains to measure")]
    NoGrains,
    #[error("{field} must be finite and > 0, got {value}")]
    BadSetting { field: &'static str, value: f64 },
    #[error("positions ({positions}) and radii ({radii}) differ in length")]
    LengthMismatch { positions: usize, radii: usize },
}

/// Surface heights on a regular grid of square cells covering `[x0, x0 + nx cell] × [y0, y0 +
/// ny cell]`. `z[j * nx + i]` is the height at the centre of cell (i, j): the lowest height at
/// which a probe sphere lowered along that vertical would touch a grain (its bottom point), or
/// `floor` where it meets none.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeightField {
    pub x0: f64,
    pub y0: f64,
    /// m
    pub cell: f64,
    pub nx: usize,
    pub ny: usize,
    /// m, row-major (x fastest).
    pub z: Vec<f64>,
}

impl HeightField {
    /// Centre of cell `i` along x.
    pub fn x(&self, i: usize) -> f64 {
        self.x0 + (i as f64 + 0.5) * self.cell
    }

    /// Centre of cell `j` along y.
    pub fn y(&self, j: usize) -> f64 {
        self.y0 + (j as f64 + 0.5) * self.cell
    }

    pub fn at(&self, i: usize, j: usize) -> f64 {
        self.z[j * self.nx + i]
    }

    /// The cell containing (x, y), clamped to the grid.
    pub fn cell_of(&self, x: f64, y: f64) -> (usize, usize) {
        let i = ((x - self.x0) / self.cell)
            .floor()
            .clamp(0.0, (self.nx - 1) as f64) as usize;
        let j = ((y - self.y0) / self.cell)
            .floor()
            .clamp(0.0, (self.ny - 1) as f64) as usize;
        (i, j)
    }
}

/// Height field over the rectangle `[-half_x, half_x] × [-half_y, half_y]` with cells of side
/// `cell`, read by a probe sphere of radius `probe` (0: the bare grain tops, which show the gaps
/// between surface grains as pits).
pub fn height_field(
    positions: &[[f64; 3]],
    radii: &[f64],
    half_x: f64,
    half_y: f64,
    cell: f64,
    probe: f64,
    floor: f64,
) -> Result<HeightField, MeasureError> {
    if positions.len() != radii.len() {
        return Err(MeasureError::LengthMismatch {
            positions: positions.len(),
            radii: radii.len(),
        });
    }
    for (field, value) in [("half_x", half_x), ("half_y", half_y), ("cell", cell)] {
        if !(value.is_finite() && value > 0.0) {
            return Err(MeasureError::BadSetting { field, value });
        }
    }
    if !(probe.is_finite() && probe >= 0.0) {
        return Err(MeasureError::BadSetting {
            field: "probe",
            value: probe,
        });
    }
    let nx = ((2.0 * half_x / cell).ceil() as usize).max(1);
    let ny = ((2.0 * half_y / cell).ceil() as usize).max(1);
    let mut hf = HeightField {
        x0: -0.5 * nx as f64 * cell,
        y0: -0.5 * ny as f64 * cell,
        cell,
        nx,
        ny,
        z: vec![floor; nx * ny],
    };
    for (p, &r) in positions.iter().zip(radii) {
        let reach = r + probe;
        let (i0, j0) = hf.cell_of(p[0] - reach, p[1] - reach);
        let (i1, j1) = hf.cell_of(p[0] + reach, p[1] + reach);
        for j in j0..=j1 {
            let dy = hf.y(j) - p[1];
            for i in i0..=i1 {
                let dx = hf.x(i) - p[0];
                let rho2 = dx * dx + dy * dy;
                if rho2 < reach * reach {
                    let h = p[2] + (reach * reach - rho2).sqrt() - probe;
                    let z = &mut hf.z[j * nx + i];
                    if h > *z {
                        *z = h;
                    }
                }
            }
        }
    }
    Ok(hf)
}

/// The median height of the cells at least `margin` inside the rectangle's edges (all cells if
/// none are): the level of a surface as it is, insensitive to a hole or a heap.
pub fn surface_level(hf: &HeightField, margin: f64) -> f64 {
    let (hx, hy) = (0.5 * hf.nx as f64 * hf.cell, 0.5 * hf.ny as f64 * hf.cell);
    let mut inner: Vec<f64> = Vec::new();
    for j in 0..hf.ny {
        for i in 0..hf.nx {
            if hf.x(i).abs() <= hx - margin && hf.y(j).abs() <= hy - margin {
                inner.push(hf.at(i, j));
            }
        }
    }
    if inner.is_empty() {
        inner = hf.z.clone();
    }
    inner.sort_by(f64::total_cmp);
    inner[inner.len() / 2]
}
