//! STL reader (binary and ASCII).
//!
//! In: the bytes of an STL file. Out: a [`RawMesh`] with one triangle per facet, in file
//! order, keeping each facet's vertex order (the stored normal is ignored: orientation
//! comes from the winding). STL stores every facet's corners separately; corners at
//! exactly equal positions are merged into one vertex so that the topology can be
//! inspected.
//!
//! A file is binary when its length is exactly 84 + 50 × (the facet count at byte 80),
//! whatever its first bytes say (some binary writers start the header with "solid").
//! Otherwise a file starting with "solid" and holding text is ASCII, and anything else
//! is read as binary, which then reports why it does not fit.

use super::obj::text;
use super::RawMesh;
use crate::error::{Error, Result};
use glam::DVec3;
use std::collections::HashMap;
use std::path::Path;

const HEADER_BYTES: usize = 80;
const COUNT_END: usize = HEADER_BYTES + 4;
const FACET_BYTES: usize = 50;

/// Parses an STL file, binary or ASCII.
pub(super) fn parse(path: &Path, bytes: &[u8]) -> Result<RawMesh> {
    if bytes.is_empty() {
        return Err(Error::file(path, "the file is empty"));
    }
    let text = crate::without_bom(bytes);
    if is_exact_binary(bytes) || !looks_like_ascii(text) {
        parse_binary(path, bytes)
    } else {
        parse_ascii(path, text)
    }
}

/// The facet count in a binary header, if the file is long enough to have one.
fn binary_count(bytes: &[u8]) -> Option<u32> {
    let count = bytes.get(HEADER_BYTES..COUNT_END)?;
    Some(u32::from_le_bytes(count.try_into().ok()?))
}

fn binary_length(count: u32) -> Option<usize> {
    (count as usize)
        .checked_mul(FACET_BYTES)?
        .checked_add(COUNT_END)
}

fn is_exact_binary(bytes: &[u8]) -> bool {
    binary_count(bytes).and_then(binary_length) == Some(bytes.len())
}

/// "solid" in any case (after optional whitespace) followed by text without NUL bytes.
fn looks_like_ascii(bytes: &[u8]) -> bool {
    const SNIFF: usize = 512;
    let start = &bytes[..bytes.len().min(SNIFF)];
    let keyword = start.trim_ascii_start().get(..5).unwrap_or_default();
    keyword.eq_ignore_ascii_case(b"solid") && !start.contains(&0)
}

fn parse_binary(path: &Path, bytes: &[u8]) -> Result<RawMesh> {
    let count = binary_count(bytes).ok_or_else(|| {
        Error::file(
            path,
            format!(
                "not an STL file: {} bytes is too short for a binary STL header (84 bytes) \
                 and the file does not start with 'solid'",
                bytes.len()
            ),
        )
    })?;
    let facets = &bytes[COUNT_END..];
    let complete = facets.len() / FACET_BYTES;
    if (complete as u64) < u64::from(count) {
        return Err(Error::at_byte(
            path,
            (COUNT_END + complete * FACET_BYTES) as u64,
            format!("file ends after {complete} of {count} facets (binary STL)"),
        ));
    }
    // Bytes after the announced facets are tolerated: some writers pad files.
    let mut mesh = Welder::with_capacity(count as usize);
    for (facet, record) in facets
        .chunks_exact(FACET_BYTES)
        .take(count as usize)
        .enumerate()
    {
        let offset = COUNT_END + facet * FACET_BYTES;
        // A record is a normal (3 × f32), three corners (3 × 3 × f32) and 2 spare bytes.
        let mut triangle = [0; 3];
        for (corner, index) in triangle.iter_mut().enumerate() {
            let start = 12 + 12 * corner;
            let position = binary_corner(&record[start..start + 12]);
            if let Some(axis) = (0..3).find(|&axis| !position[axis].is_finite()) {
                return Err(Error::at_byte(
                    path,
                    (offset + start + 4 * axis) as u64,
                    format!(
                        "facet {facet}: vertex coordinate is not a finite number: {}",
                        position[axis]
                    ),
                ));
            }
            *index = mesh.vertex(position);
        }
        mesh.triangles.push(triangle);
    }
    Ok(mesh.finish())
}

/// Three little-endian f32 coordinates.
fn binary_corner(bytes: &[u8]) -> DVec3 {
    let mut xyz = [0.0; 3];
    for (coordinate, chunk) in xyz.iter_mut().zip(bytes.chunks_exact(4)) {
        let mut word = [0; 4];
        word.copy_from_slice(chunk);
        *coordinate = f64::from(f32::from_le_bytes(word));
    }
    DVec3::from_array(xyz)
}

/// What an ASCII STL expects next.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Expect {
    Solid,
    FacetOrEndSolid,
    OuterLoop,
    VertexOrEndLoop,
    EndFacet,
}

impl Expect {
    fn describe(self) -> &'static str {
        match self {
            Expect::Solid => "'solid'",
            Expect::FacetOrEndSolid => "'facet normal' or 'endsolid'",
            Expect::OuterLoop => "'outer loop'",
            Expect::VertexOrEndLoop => "'vertex' or 'endloop'",
            Expect::EndFacet => "'endfacet'",
        }
    }
}

fn parse_ascii(path: &Path, bytes: &[u8]) -> Result<RawMesh> {
    let mut mesh = Welder::with_capacity(0);
    let mut expect = Expect::Solid;
    let mut corners = Vec::with_capacity(3);
    for row in text::rows(bytes) {
        let mut tokens = row.tokens();
        let keyword = tokens.next().unwrap_or_default();
        let is = |word: &str| keyword.eq_ignore_ascii_case(word.as_bytes());
        expect = match expect {
            Expect::Solid if is("solid") => Expect::FacetOrEndSolid,
            Expect::FacetOrEndSolid if is("facet") => Expect::OuterLoop,
            Expect::FacetOrEndSolid if is("endsolid") => Expect::Solid,
            Expect::OuterLoop if is("outer") => Expect::VertexOrEndLoop,
            Expect::VertexOrEndLoop if is("vertex") => {
                corners.push(ascii_corner(path, &row, tokens)?);
                Expect::VertexOrEndLoop
            }
            Expect::VertexOrEndLoop if is("endloop") => {
                let [a, b, c] = corners[..] else {
                    return Err(row.error(
                        path,
                        format!("facet has {} vertices; STL facets have 3", corners.len()),
                    ));
                };
                let triangle = [mesh.vertex(a), mesh.vertex(b), mesh.vertex(c)];
                mesh.triangles.push(triangle);
                corners.clear();
                Expect::EndFacet
            }
            Expect::EndFacet if is("endfacet") => Expect::FacetOrEndSolid,
            _ => {
                return Err(row.error(
                    path,
                    format!(
                        "expected {}, found {}",
                        expect.describe(),
                        text::quoted(row.content)
                    ),
                ))
            }
        };
    }
    if expect != Expect::Solid {
        return Err(Error::at_line(
            path,
            text::last_line(bytes),
            format!(
                "file ends after {} complete facets, where {} was expected",
                mesh.triangles.len(),
                expect.describe()
            ),
        ));
    }
    Ok(mesh.finish())
}

fn ascii_corner<'a>(
    path: &Path,
    row: &text::Row,
    tokens: impl Iterator<Item = &'a [u8]>,
) -> Result<DVec3> {
    let mut xyz = [0.0; 3];
    let mut found = 0;
    for token in tokens {
        let coordinate = xyz
            .get_mut(found)
            .ok_or_else(|| row.error(path, "vertex has more than 3 coordinates".to_string()))?;
        *coordinate = text::coordinate(token).map_err(|msg| row.error(path, msg))?;
        found += 1;
    }
    if found < 3 {
        return Err(row.error(
            path,
            format!("vertex has {found} coordinates; 3 (x y z) needed"),
        ));
    }
    Ok(DVec3::from_array(xyz))
}

/// Builds an indexed mesh from separate facet corners, merging equal positions.
struct Welder {
    vertices: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    index_of: HashMap<[u64; 3], u32>,
}

impl Welder {
    fn with_capacity(facets: usize) -> Self {
        Welder {
            vertices: Vec::with_capacity(facets / 2),
            triangles: Vec::with_capacity(facets),
            index_of: HashMap::with_capacity(facets / 2),
        }
    }

    /// The index of the vertex at `position`, added if new.
    fn vertex(&mut self, position: DVec3) -> u32 {
        // Adding 0.0 turns -0.0 into +0.0, so corners on a coordinate plane still merge.
        let key = (position + DVec3::ZERO).to_array().map(f64::to_bits);
        // Cannot wrap: 2^32 distinct corners would take a file of more than 50 GB, far
        // beyond what `read_mesh` holds in memory.
        let next = self.vertices.len() as u32;
        *self.index_of.entry(key).or_insert_with(|| {
            self.vertices.push(position);
            next
        })
    }

    fn finish(self) -> RawMesh {
        RawMesh {
            vertices: self.vertices,
            triangles: self.triangles,
        }
    }
}
