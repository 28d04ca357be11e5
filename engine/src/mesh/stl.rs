//! STL import (ASCII and binary) and export (binary and ASCII).
//!
//! The library stays I/O-free: callers hand over the bytes (and, with
//! [`TriMesh::from_stl_bytes_named`], the name errors should carry: the file's path).
//!
//! STL stores every triangle with its own three corners, so shared corners are repeated; they
//! are welded on import, otherwise the mesh would have no edge adjacency and contact
//! de-duplication across triangle edges would not work.

use super::{weld_vertices, MeshError, TriMesh, RELATIVE_TOLERANCE};
use crate::math::Vec3;

/// Why an STL file could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("STL `{source_name}`: {reason}")]
pub struct StlError {
    /// File name (or `<bytes>` when parsed from memory).
    pub source_name: String,
    pub reason: String,
}

/// Corners closer than this fraction of the bounding-box diagonal are welded. STL stores
/// `f32` (about 7 significant digits), so repeated corners written by different tools can
/// differ in the last bits; 1e-7 of the model size merges those but no real features.
const STL_WELD_RELATIVE_TOLERANCE: f64 = 1e-7;

const BINARY_HEADER_LEN: usize = 80;
const BINARY_TRIANGLE_LEN: usize = 50;
/// Written at the start of binary files. Deliberately not "solid", which readers (including
/// ours, as a fallback) take as the sign of an ASCII file.
const BINARY_HEADER_TEXT: &[u8] = b"binary STL written by repose-engine";

impl TriMesh {
    /// Parses an ASCII or binary STL and multiplies every coordinate by `scale` (e.g. 0.001 for
    /// a file in millimetres). Corners are welded, triangles that become degenerate are
    /// dropped. Never panics: malformed input gives an error.
    pub fn from_stl_bytes(bytes: &[u8], scale: f64) -> Result<TriMesh, MeshError> {
        Self::from_stl_bytes_named(bytes, scale, "<bytes>")
    }

    /// As [`TriMesh::from_stl_bytes`], with `source_name` (usually the file name) in errors.
    pub fn from_stl_bytes_named(
        bytes: &[u8],
        scale: f64,
        source_name: &str,
    ) -> Result<TriMesh, MeshError> {
        let fail = |reason: String| StlError {
            source_name: source_name.to_owned(),
            reason,
        };
        if !(scale.is_finite() && scale > 0.0) {
            return Err(MeshError::parameter(
                "scale",
                scale,
                "must be finite and positive",
            ));
        }
        let soup = parse_soup(bytes).map_err(fail)?;
        soup_to_mesh(soup, scale).map_err(|e| match e {
            MeshError::Stl(inner) => MeshError::Stl(fail(inner.reason)),
            MeshError::InvalidParameter { .. } => e,
            other => MeshError::Stl(fail(other.to_string())),
        })
    }

    /// Binary STL of this mesh (coordinates as `f32`, in metres, normals from the mesh).
    pub fn to_stl_binary(&self) -> Vec<u8> {
        let mut out =
            Vec::with_capacity(BINARY_HEADER_LEN + 4 + BINARY_TRIANGLE_LEN * self.triangles.len());
        let mut header = [b' '; BINARY_HEADER_LEN];
        header[..BINARY_HEADER_TEXT.len()].copy_from_slice(BINARY_HEADER_TEXT);
        out.extend_from_slice(&header);
        out.extend_from_slice(&(self.triangles.len() as u32).to_le_bytes());
        for (t, normal) in self.normals.iter().enumerate() {
            let corners = self.corners(t);
            for v in std::iter::once(normal).chain(corners.iter()) {
                for c in v.iter() {
                    out.extend_from_slice(&(*c as f32).to_le_bytes());
                }
            }
            out.extend_from_slice(&0u16.to_le_bytes());
        }
        out
    }

    /// ASCII STL of this mesh (full `f64` precision, which STL readers accept).
    pub fn to_stl_ascii(&self, solid_name: &str) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        // Writing to a String cannot fail.
        let _ = writeln!(s, "solid {solid_name}");
        for (t, n) in self.normals.iter().enumerate() {
            let _ = writeln!(s, "  facet normal {:e} {:e} {:e}", n.x, n.y, n.z);
            let _ = writeln!(s, "    outer loop");
            for v in self.corners(t) {
                let _ = writeln!(s, "      vertex {:e} {:e} {:e}", v.x, v.y, v.z);
            }
            let _ = writeln!(s, "    endloop");
            let _ = writeln!(s, "  endfacet");
        }
        let _ = writeln!(s, "endsolid {solid_name}");
        s
    }
}

/// Unwelded triangles as read from the file, in file units.
type Soup = Vec<[Vec3; 3]>;

fn parse_soup(bytes: &[u8]) -> Result<Soup, String> {
    // A binary file whose size matches its declared triangle count is binary even when its
    // header starts with "solid" (several exporters write that).
    if bytes.len() >= BINARY_HEADER_LEN + 4 {
        let count = declared_binary_count(bytes);
        let expected = (count as u64) * BINARY_TRIANGLE_LEN as u64 + (BINARY_HEADER_LEN + 4) as u64;
        if expected == bytes.len() as u64 {
            return parse_binary(bytes, count as usize);
        }
    }
    if looks_like_ascii(bytes) {
        return parse_ascii(bytes);
    }
    if bytes.len() < BINARY_HEADER_LEN + 4 {
        return Err(format!(
            "file is {} bytes long: too short for a binary STL header (84 bytes) and not ASCII STL",
            bytes.len()
        ));
    }
    let count = declared_binary_count(bytes);
    Err(format!(
        "binary STL declares {count} triangles, which needs {} bytes, but the file has {} bytes \
         (truncated or wrong triangle count)",
        (count as u64) * BINARY_TRIANGLE_LEN as u64 + (BINARY_HEADER_LEN + 4) as u64,
        bytes.len()
    ))
}

fn declared_binary_count(bytes: &[u8]) -> u32 {
    let mut c = [0u8; 4];
    c.copy_from_slice(&bytes[BINARY_HEADER_LEN..BINARY_HEADER_LEN + 4]);
    u32::from_le_bytes(c)
}

fn looks_like_ascii(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    bytes[start..].len() >= 5 && bytes[start..start + 5].eq_ignore_ascii_case(b"solid")
}

fn parse_binary(bytes: &[u8], count: usize) -> Result<Soup, String> {
    let mut soup = Vec::with_capacity(count);
    let body = &bytes[BINARY_HEADER_LEN + 4..];
    for (t, record) in body.chunks_exact(BINARY_TRIANGLE_LEN).enumerate() {
        let read = |i: usize| -> f64 {
            let mut b = [0u8; 4];
            b.copy_from_slice(&record[i * 4..i * 4 + 4]);
            f32::from_le_bytes(b) as f64
        };
        // Floats 0..3 are the stored normal, which we recompute from the corners.
        let corner = |k: usize| Vec3::new(read(3 + 3 * k), read(4 + 3 * k), read(5 + 3 * k));
        let tri = [corner(0), corner(1), corner(2)];
        check_finite(&tri, t)?;
        soup.push(tri);
    }
    Ok(soup)
}

fn check_finite(tri: &[Vec3; 3], t: usize) -> Result<(), String> {
    for (k, v) in tri.iter().enumerate() {
        if !v.iter().all(|c| c.is_finite()) {
            return Err(format!(
                "triangle {t}, corner {k} has a non-finite coordinate ({}, {}, {})",
                v.x, v.y, v.z
            ));
        }
    }
    Ok(())
}

fn parse_ascii(bytes: &[u8]) -> Result<Soup, String> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| format!("ASCII STL is not valid UTF-8 text: {e}"))?;
    let mut soup = Vec::new();
    let mut corners: Vec<Vec3> = Vec::with_capacity(3);
    let mut in_loop = false;
    for (line_index, line) in text.lines().enumerate() {
        let line_number = line_index + 1;
        let mut tokens = line.split_whitespace();
        let Some(keyword) = tokens.next() else {
            continue;
        };
        match keyword.to_ascii_lowercase().as_str() {
            // Names after solid/endsolid may contain anything, and facet normals are
            // recomputed from the corners, so the rest of those lines is ignored.
            "solid" | "endsolid" | "facet" | "endfacet" => {}
            "outer" => {
                if in_loop {
                    return Err(format!("line {line_number}: `outer loop` inside a loop"));
                }
                in_loop = true;
                corners.clear();
            }
            "vertex" => {
                if !in_loop {
                    return Err(format!("line {line_number}: `vertex` outside `outer loop`"));
                }
                let mut xyz = [0.0; 3];
                for (axis, value) in xyz.iter_mut().enumerate() {
                    let token = tokens.next().ok_or_else(|| {
                        format!("line {line_number}: vertex has {axis} coordinates, expected 3")
                    })?;
                    *value = token.parse::<f64>().map_err(|_| {
                        format!("line {line_number}: vertex coordinate `{token}` is not a number")
                    })?;
                    if !value.is_finite() {
                        return Err(format!(
                            "line {line_number}: vertex coordinate `{token}` is not finite"
                        ));
                    }
                }
                if tokens.next().is_some() {
                    return Err(format!(
                        "line {line_number}: vertex has more than 3 coordinates"
                    ));
                }
                if corners.len() == 3 {
                    return Err(format!(
                        "line {line_number}: more than 3 vertices in a facet"
                    ));
                }
                corners.push(Vec3::new(xyz[0], xyz[1], xyz[2]));
            }
            "endloop" => {
                if !in_loop || corners.len() != 3 {
                    return Err(format!(
                        "line {line_number}: facet has {} vertices, expected 3",
                        corners.len()
                    ));
                }
                in_loop = false;
                soup.push([corners[0], corners[1], corners[2]]);
            }
            other => {
                return Err(format!(
                    "line {line_number}: unexpected keyword `{}`",
                    other.chars().take(40).collect::<String>()
                ))
            }
        }
    }
    if in_loop {
        return Err("file ends inside a facet (truncated)".to_owned());
    }
    Ok(soup)
}

fn soup_to_mesh(soup: Soup, scale: f64) -> Result<TriMesh, MeshError> {
    if soup.is_empty() {
        return Err(StlError {
            source_name: String::new(),
            reason: "file contains no triangles".to_owned(),
        }
        .into());
    }
    let mut corners = Vec::with_capacity(soup.len() * 3);
    for (t, tri) in soup.iter().enumerate() {
        let scaled = tri.map(|v| v * scale);
        // Finite f32/f64 times a finite scale can still overflow to infinity.
        check_finite(&scaled, t).map_err(|reason| StlError {
            source_name: String::new(),
            reason: format!("{reason} after scaling by {scale}"),
        })?;
        corners.extend_from_slice(&scaled);
    }
    let (lo, hi) = corners.iter().fold(
        (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
        |(lo, hi), v| (lo.inf(v), hi.sup(v)),
    );
    let diagonal = (hi - lo).norm();
    let (vertices, map) = weld_vertices(&corners, STL_WELD_RELATIVE_TOLERANCE * diagonal);
    let minimum_double_area = RELATIVE_TOLERANCE * diagonal * diagonal;
    let triangles: Vec<[u32; 3]> = map
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .filter(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            t[0] != t[1]
                && t[1] != t[2]
                && t[0] != t[2]
                && (b - a).cross(&(c - a)).norm() > minimum_double_area
        })
        .collect();
    if triangles.is_empty() {
        return Err(StlError {
            source_name: String::new(),
            reason: format!("all {} triangles are degenerate", soup.len()),
        }
        .into());
    }
    TriMesh::new(vertices, triangles)
}
