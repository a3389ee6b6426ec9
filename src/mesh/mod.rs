//! Mesh input: triangle meshes from OBJ, PLY, STL and PDS plate files.
//!
//! In: a file path, its format (detected from the extension unless given) and its length
//! unit. Out: a [`RawMesh`] (vertices in file units, triangles as 0-based vertex indices,
//! facet ids = triangle order in the file, polygons fan-triangulated) and, from it, a
//! [`Mesh`] in metres with per-facet centroid, unit normal and area.
//!
//! Readers never panic: truncated, out-of-range, non-finite and empty input is reported
//! with the file and the line (text) or byte offset (binary). Topology problems (zero-area
//! facets, unreferenced vertices, boundary and non-manifold edges, inconsistent or inward
//! orientation) are found by [`inspect`], reported, and fixed only when asked.

pub mod generate;
pub mod inspect;
mod obj;
mod pds;
mod ply;
pub mod projection;
mod stl;

use crate::error::{Error, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A triangle mesh as read from a file: coordinates in the file's unit.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawMesh {
    /// Vertex positions, in the file's length unit.
    pub vertices: Vec<DVec3>,
    /// Triangles as 0-based indices into `vertices`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// The file formats slim reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Wavefront OBJ (`v`, `f`; texture/normal indices, groups and materials ignored).
    Obj,
    /// Stanford PLY: ASCII, binary little- and big-endian.
    Ply,
    /// STL: ASCII and binary.
    Stl,
    /// PDS plate-model text: `v x y z`/`f i j k` lines, or an `nv nf` (or `nv` ... `nf`)
    /// header followed by vertex and plate rows; 0- or 1-based indices.
    Pds,
}

impl MeshFormat {
    /// The format implied by a file name's extension, if any.
    pub fn from_path(path: &Path) -> Option<MeshFormat> {
        match crate::lowercase_extension(path).as_str() {
            "obj" => Some(MeshFormat::Obj),
            "ply" => Some(MeshFormat::Ply),
            "stl" => Some(MeshFormat::Stl),
            "tab" | "txt" | "plt" | "pds" | "dat" => Some(MeshFormat::Pds),
            _ => None,
        }
    }
}

/// Length unit of a mesh file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LengthUnit {
    /// Metres.
    M,
    /// Kilometres (the usual unit of planetary shape models).
    #[default]
    Km,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            LengthUnit::M => 1.0,
            LengthUnit::Km => 1000.0,
        }
    }
}

/// Reads a mesh file. `format` overrides detection by extension.
pub fn read_mesh(path: &Path, format: Option<MeshFormat>) -> Result<RawMesh> {
    let format = format
        .or_else(|| MeshFormat::from_path(path))
        .ok_or_else(|| {
            Error::file(
            path,
            "unknown mesh format: use the extension .obj, .ply, .stl or .tab/.txt (PDS plates), \
             or set the format explicitly",
        )
        })?;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = crate::without_bom(&bytes);
    let mesh = match format {
        MeshFormat::Obj => obj::parse(path, text)?,
        MeshFormat::Ply => ply::parse(path, text)?,
        // A binary STL's 80-byte header may begin with anything: only an ASCII one loses
        // its byte-order mark.
        MeshFormat::Stl => stl::parse(path, &bytes)?,
        MeshFormat::Pds => pds::parse(path, text)?,
    };
    if mesh.triangles.is_empty() {
        return Err(Error::file(path, "the file holds no facets"));
    }
    check_coordinates(path, &mesh)?;
    Ok(mesh)
}

/// Largest coordinate magnitude accepted, in the file's unit. Areas and normals square
/// the coordinates, so beyond about 1e154 they overflow to infinity or NaN; 1e100 keeps a
/// wide margin and is still far beyond any body's distance from its origin in km or m.
pub const MAX_COORDINATE: f64 = 1e100;

/// Every vertex coordinate must be finite and within ±[`MAX_COORDINATE`].
fn check_coordinates(path: &Path, mesh: &RawMesh) -> Result<()> {
    let outside = |v: &glam::DVec3| !v.is_finite() || v.abs().max_element() > MAX_COORDINATE;
    match mesh.vertices.iter().position(outside) {
        Some(i) => Err(Error::file(
            path,
            format!(
                "vertex {} at {:?} lies beyond ±{MAX_COORDINATE:e}: its facets' areas and \
                 normals would overflow",
                i + 1,
                mesh.vertices[i].to_array()
            ),
        )),
        None => Ok(()),
    }
}

/// A mesh ready for the engine: metres, body-fixed frame, per-facet geometry precomputed.
#[derive(Debug, Clone)]
pub struct Mesh {
    /// Vertex positions in metres, body-fixed frame.
    pub vertices: Vec<DVec3>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
    /// Facet centroids in metres.
    pub centroids: Vec<DVec3>,
    /// Unit outward normals; zero for degenerate (zero-area) facets.
    pub normals: Vec<DVec3>,
    /// Facet areas in m².
    pub areas: Vec<f64>,
}

/// A mesh from vertices in metres and triangles (for tests).
#[cfg(test)]
pub(crate) fn in_metres(vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Mesh {
    Mesh::from_raw(
        RawMesh {
            vertices,
            triangles,
        },
        LengthUnit::M,
    )
}

impl Mesh {
    /// This mesh followed by `other` (both in metres, same frame): the facets of `self`
    /// keep their ids, those of `other` follow.
    pub fn joined(&self, other: &Mesh) -> Mesh {
        let shift = self.vertices.len() as u32;
        let cat = |a: &[DVec3], b: &[DVec3]| [a, b].concat();
        Mesh {
            vertices: cat(&self.vertices, &other.vertices),
            triangles: self
                .triangles
                .iter()
                .copied()
                .chain(other.triangles.iter().map(|t| t.map(|i| i + shift)))
                .collect(),
            centroids: cat(&self.centroids, &other.centroids),
            normals: cat(&self.normals, &other.normals),
            areas: [&self.areas[..], &other.areas[..]].concat(),
        }
    }

    /// Builds the engine mesh from raw file content in `unit`.
    pub fn from_raw(raw: RawMesh, unit: LengthUnit) -> Mesh {
        let scale = unit.metres();
        let vertices: Vec<DVec3> = raw.vertices.iter().map(|v| *v * scale).collect();
        let mut centroids = Vec::with_capacity(raw.triangles.len());
        let mut normals = Vec::with_capacity(raw.triangles.len());
        let mut areas = Vec::with_capacity(raw.triangles.len());
        for t in &raw.triangles {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            let cross = (b - a).cross(c - a);
            let twice_area = cross.length();
            centroids.push((a + b + c) / 3.0);
            areas.push(0.5 * twice_area);
            normals.push(if twice_area > 0.0 {
                cross / twice_area
            } else {
                DVec3::ZERO
            });
        }
        Mesh {
            vertices,
            triangles: raw.triangles,
            centroids,
            normals,
            areas,
        }
    }

    /// Number of facets.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    /// True when the mesh has no facets.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// The three corners of facet `i`, in metres.
    #[inline]
    pub fn corners(&self, i: usize) -> [DVec3; 3] {
        // Spelled out: `array::map` here was left as a call in the tracers' hot loops.
        let [a, b, c] = self.triangles[i];
        let v = &self.vertices;
        [v[a as usize], v[b as usize], v[c as usize]]
    }

    /// Axis-aligned bounds (min, max) of the referenced vertices, in metres.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for t in &self.triangles {
            for &v in t {
                lo = lo.min(self.vertices[v as usize]);
                hi = hi.max(self.vertices[v as usize]);
            }
        }
        (lo, hi)
    }
}
