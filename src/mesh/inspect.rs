//! Topology and orientation report of a mesh.
//!
//! In: a [`Mesh`] (metres). Out: a [`MeshReport`] counting unreferenced vertices,
//! degenerate facets, boundary, non-manifold and inconsistently oriented edges, with the
//! signed volume (its sign tells whether the normals point outward), convexity, extent,
//! area and mean edge length. `Display` prints a readable report; [`MeshReport::problems`]
//! gives one sentence per problem, for warnings.
//!
//! Edges are found with a hash map keyed by the sorted vertex pair, so a million-facet
//! mesh takes a fraction of a second. The same map gives each facet's neighbours across
//! its edges ([`facet_neighbours`]), the graph a rover drives on.

use super::Mesh;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt;
use std::hash::{BuildHasherDefault, Hasher};

/// What [`inspect`] finds in a mesh.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct MeshReport {
    pub vertices: usize,
    pub facets: usize,
    /// Vertices used by no facet.
    pub unreferenced_vertices: usize,
    /// Facets with area <= 1e-12 × (longest edge)², or with a repeated vertex index.
    pub degenerate_facets: usize,
    /// Undirected edges used by exactly one facet.
    pub boundary_edges: usize,
    /// The length of the facets' summed area vectors over their total area: 0 for a
    /// closed surface (its area vectors cancel), the area of its openings seen face on
    /// over its area otherwise, near 1 for a patch of terrain.
    #[serde(default)]
    pub open_share: f64,
    /// Undirected edges used by more than two facets.
    pub non_manifold_edges: usize,
    /// Edges shared by two facets that traverse it in the same direction.
    pub inconsistent_edges: usize,
    /// No boundary and no non-manifold edges.
    pub closed: bool,
    /// Closed once coincident vertices are merged, consistently and outward oriented
    /// (see [`is_watertight`]).
    pub watertight: bool,
    /// Sum over facets of a·(b×c)/6; positive when the normals point outward.
    pub signed_volume_m3: f64,
    /// Closed, connected, consistently and outward oriented, without degenerate facets,
    /// and folding outward (never inward) at every edge.
    pub convex: bool,
    /// Bounding box size of the referenced vertices.
    pub extent_m: [f64; 3],
    pub total_area_m2: f64,
    /// Mean length of the distinct edges.
    pub mean_edge_m: f64,
}

/// Inspects the topology and orientation of `mesh`.
pub fn inspect(mesh: &Mesh) -> MeshReport {
    let edges = edge_map(&mesh.triangles);
    let mut boundary_edges = 0;
    let mut non_manifold_edges = 0;
    let mut inconsistent_edges = 0;
    for edge in edges.values() {
        match edge.uses {
            1 => boundary_edges += 1,
            2 if edge.forward[0] == edge.forward[1] => inconsistent_edges += 1,
            2 => {}
            _ => non_manifold_edges += 1,
        }
    }
    let closed = boundary_edges == 0 && non_manifold_edges == 0;
    let signed_volume_m3 = signed_volume(mesh);
    let degenerate_facets = (0..mesh.len()).filter(|&f| is_degenerate(mesh, f)).count();
    let convex = closed
        && inconsistent_edges == 0
        && degenerate_facets == 0
        && signed_volume_m3 > 0.0
        && is_connected(mesh)
        && folds_outward_everywhere(mesh, &edges);
    let (lo, hi) = mesh.bounds();
    let extent = if mesh.is_empty() {
        DVec3::ZERO
    } else {
        hi - lo
    };
    MeshReport {
        vertices: mesh.vertices.len(),
        facets: mesh.len(),
        unreferenced_vertices: unreferenced_vertices(mesh),
        degenerate_facets,
        boundary_edges,
        open_share: open_share(mesh),
        non_manifold_edges,
        inconsistent_edges,
        closed,
        watertight: is_watertight(mesh),
        signed_volume_m3,
        convex,
        extent_m: extent.to_array(),
        total_area_m2: mesh.areas.iter().sum(),
        mean_edge_m: mean_edge_length(mesh, &edges),
    }
}

/// The least [`MeshReport::open_share`] of a patch of a larger surface
/// ([`MeshReport::is_patch`]): a tenth. The shipped terrain stands near 1 (Haworth 0.974,
/// its surroundings 0.978); a body's shape model with boundary edges at its seams or a
/// few small holes near 0 (m1phobos, 152 boundary edges: 3e-15).
const PATCH_OPEN_SHARE: f64 = 0.1;

impl MeshReport {
    /// Whether the mesh is a patch of a larger surface (terrain), not a body: it has a
    /// boundary, and its openings are a sizeable share of its area.
    pub fn is_patch(&self) -> bool {
        self.boundary_edges > 0 && self.open_share > PATCH_OPEN_SHARE
    }
}

/// [`MeshReport::open_share`] of `mesh` (0 when it has no area).
fn open_share(mesh: &Mesh) -> f64 {
    let (vector, total) = (mesh.normals.iter().zip(&mesh.areas))
        .fold((DVec3::ZERO, 0.0), |(v, t), (&n, &a)| (v + n * a, t + a));
    if total > 0.0 {
        vector.length() / total
    } else {
        0.0
    }
}

/// True when the surface is closed once vertices at bitwise-equal positions are merged
/// (duplicated seam and pole vertices do not open a surface geometrically), every edge is
/// shared by exactly two facets running it in opposite directions, and the normals point
/// outward. A ray that leaves such a surface can only be blocked by crossing, from
/// outside, a facet that faces against the ray.
pub fn is_watertight(mesh: &Mesh) -> bool {
    let edges = edge_map(&welded_triangles(mesh));
    !edges.is_empty()
        && edges
            .values()
            .all(|e| e.uses == 2 && e.forward[0] != e.forward[1])
        && signed_volume(mesh) > 0.0
}

/// Each facet's neighbours: the facets sharing one of its edges once coincident vertices
/// are merged (so duplicated seam and pole vertices do not cut the surface), in
/// increasing id order. Degenerate facets with a repeated vertex have none; at an edge
/// shared by more than two facets, the first two are joined.
pub fn facet_neighbours(mesh: &Mesh) -> Vec<Vec<u32>> {
    edge_neighbours(mesh)
        .into_iter()
        .map(|across| {
            let mut list: Vec<u32> = across.into_iter().filter(|&f| f != NO_NEIGHBOUR).collect();
            list.sort_unstable();
            list.dedup();
            list
        })
        .collect()
}

/// No facet across this edge.
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// Each facet's neighbour across each of its edges, in corner order (edge `k` runs from
/// corner `k` to corner `k + 1`), or [`NO_NEIGHBOUR`]; joined as in [`facet_neighbours`].
pub fn edge_neighbours(mesh: &Mesh) -> Vec<[u32; 3]> {
    let welded = welded_triangles(mesh);
    let edges = edge_map(&welded);
    let across = |facet: u32, from: u32, to: u32| {
        let key = (u64::from(from.min(to)) << 32) | u64::from(from.max(to));
        match edges.get(&key) {
            Some(e) if e.uses >= 2 && e.facets[0] != e.facets[1] => match facet {
                f if f == e.facets[0] => e.facets[1],
                f if f == e.facets[1] => e.facets[0],
                _ => NO_NEIGHBOUR,
            },
            _ => NO_NEIGHBOUR,
        }
    };
    (welded.iter().enumerate())
        .map(|(facet, &[a, b, c])| {
            let facet = facet as u32;
            [
                across(facet, a, b),
                across(facet, b, c),
                across(facet, c, a),
            ]
        })
        .collect()
}

/// `mesh`'s triangles with every vertex replaced by the first vertex at the same position.
fn welded_triangles(mesh: &Mesh) -> Vec<[u32; 3]> {
    let mut first: HashMap<[u64; 3], u32> = HashMap::with_capacity(mesh.vertices.len());
    let canonical: Vec<u32> = mesh
        .vertices
        .iter()
        .enumerate()
        .map(|(i, v)| {
            // +0.0 for -0.0, so the two zeros weld.
            let key = v.to_array().map(|c| (c + 0.0).to_bits());
            *first.entry(key).or_insert(i as u32)
        })
        .collect();
    (mesh.triangles.iter())
        .map(|t| t.map(|v| canonical[v as usize]))
        .collect()
}

fn has_repeated_vertex([a, b, c]: [u32; 3]) -> bool {
    a == b || b == c || c == a
}

fn is_degenerate(mesh: &Mesh, facet: usize) -> bool {
    if has_repeated_vertex(mesh.triangles[facet]) {
        return true;
    }
    let [a, b, c] = mesh.corners(facet);
    let longest_squared = (b - a)
        .length_squared()
        .max((c - b).length_squared())
        .max((a - c).length_squared());
    mesh.areas[facet] <= 1e-12 * longest_squared
}

/// How the facets use one undirected edge.
#[derive(Debug, Clone, Copy, Default)]
struct EdgeUse {
    uses: u32,
    /// The first two facets using the edge.
    facets: [u32; 2],
    /// Whether each of those facets runs from the smaller to the larger vertex index.
    forward: [bool; 2],
}

type EdgeMap = HashMap<u64, EdgeUse, BuildHasherDefault<EdgeKeyHasher>>;

/// Maps each undirected edge of `triangles` (key: smaller vertex index in the high half,
/// larger in the low half) to the facets using it. Facets with a repeated vertex are
/// collapsed to a line and left out: their neighbours meet across them as if they were
/// absent.
fn edge_map(triangles: &[[u32; 3]]) -> EdgeMap {
    let capacity = triangles.len() * 3 / 2 + 1;
    let mut edges = EdgeMap::with_capacity_and_hasher(capacity, Default::default());
    for (facet, &triangle) in triangles.iter().enumerate() {
        if has_repeated_vertex(triangle) {
            continue;
        }
        let [a, b, c] = triangle;
        for (from, to) in [(a, b), (b, c), (c, a)] {
            let key = (u64::from(from.min(to)) << 32) | u64::from(from.max(to));
            let edge = edges.entry(key).or_default();
            if let Some(slot) = edge.facets.get_mut(edge.uses as usize) {
                *slot = facet as u32;
                edge.forward[edge.uses as usize] = from < to;
            }
            edge.uses = edge.uses.saturating_add(1);
        }
    }
    edges
}

fn edge_vertices(key: u64) -> (u32, u32) {
    ((key >> 32) as u32, key as u32)
}

fn signed_volume(mesh: &Mesh) -> f64 {
    (0..mesh.len())
        .map(|f| {
            let [a, b, c] = mesh.corners(f);
            a.dot(b.cross(c))
        })
        .sum::<f64>()
        / 6.0
}

fn unreferenced_vertices(mesh: &Mesh) -> usize {
    let mut used = vec![false; mesh.vertices.len()];
    for &v in mesh.triangles.iter().flatten() {
        used[v as usize] = true;
    }
    used.iter().filter(|&&u| !u).count()
}

fn mean_edge_length(mesh: &Mesh, edges: &EdgeMap) -> f64 {
    if edges.is_empty() {
        return 0.0;
    }
    let total: f64 = edges
        .keys()
        .map(|&key| {
            let (a, b) = edge_vertices(key);
            mesh.vertices[a as usize].distance(mesh.vertices[b as usize])
        })
        .sum();
    total / edges.len() as f64
}

/// True when all facets form one piece (joined through shared vertices).
fn is_connected(mesh: &Mesh) -> bool {
    let mut parent: Vec<u32> = (0..mesh.vertices.len() as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            let grandparent = parent[parent[v as usize] as usize];
            parent[v as usize] = grandparent;
            v = grandparent;
        }
        v
    }
    for &[a, b, c] in &mesh.triangles {
        let ra = root(&mut parent, a);
        for other in [b, c] {
            let ro = root(&mut parent, other);
            parent[ro as usize] = ra;
        }
    }
    let mut roots = mesh
        .triangles
        .iter()
        .map(|t| t[0])
        .map(|v| root(&mut parent, v));
    match roots.next() {
        Some(first) => roots.all(|r| r == first),
        None => false,
    }
}

/// True when at every edge shared by two facets, each facet's far vertex lies on or
/// below the other facet's plane: the surface never folds inward. For a closed,
/// connected, outward-oriented surface this local test implies global convexity.
fn folds_outward_everywhere(mesh: &Mesh, edges: &EdgeMap) -> bool {
    edges
        .iter()
        .filter(|(_, edge)| edge.uses == 2)
        .all(|(&key, edge)| {
            let [f, g] = edge.facets.map(|f| f as usize);
            let (u, v) = edge_vertices(key);
            let far = |facet: usize| {
                let vertex = mesh.triangles[facet]
                    .into_iter()
                    .find(|&w| w != u && w != v)
                    .unwrap_or(u);
                mesh.vertices[vertex as usize]
            };
            let tolerance = 1e-9 * longest_edge(mesh, f).max(longest_edge(mesh, g));
            let below = |facet: usize, point: DVec3| {
                (point - mesh.centroids[facet]).dot(mesh.normals[facet]) <= tolerance
            };
            below(f, far(g)) && below(g, far(f))
        })
}

fn longest_edge(mesh: &Mesh, facet: usize) -> f64 {
    let [a, b, c] = mesh.corners(facet);
    a.distance(b).max(b.distance(c)).max(c.distance(a))
}

/// A fast hasher for edge keys (two packed u32): the default SipHash is several times
/// slower and its protection against crafted keys is not needed here.
#[derive(Default)]
struct EdgeKeyHasher(u64);

impl Hasher for EdgeKeyHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            self.write_u64(u64::from(byte));
        }
    }

    fn write_u64(&mut self, n: u64) {
        // SplitMix64 finaliser: every input bit affects the high and low output bits,
        // which the map uses for its control bytes and bucket index.
        let mut x = self.0 ^ n;
        x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        self.0 = x ^ (x >> 31);
    }

    fn finish(&self) -> u64 {
        self.0
    }
}

impl MeshReport {
    /// Closed, but the signed volume says the normals point into the body.
    pub fn is_inward(&self) -> bool {
        self.closed && self.signed_volume_m3 < 0.0
    }

    /// One short sentence per problem found; empty when the mesh is sound.
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        if self.unreferenced_vertices > 0 {
            problems.push(format!(
                "{} vertices are not used by any facet",
                self.unreferenced_vertices
            ));
        }
        if self.degenerate_facets > 0 {
            problems.push(format!(
                "{} facets are degenerate (zero area)",
                self.degenerate_facets
            ));
        }
        if self.boundary_edges > 0 {
            problems.push(format!(
                "{} boundary edges: the surface is open",
                self.boundary_edges
            ));
        }
        if self.non_manifold_edges > 0 {
            problems.push(format!(
                "{} non-manifold edges are shared by more than two facets",
                self.non_manifold_edges
            ));
        }
        if self.inconsistent_edges > 0 {
            problems.push(format!(
                "{} edges join facets of opposite orientation",
                self.inconsistent_edges
            ));
        }
        if self.is_inward() {
            problems.push(
                "normals point inward (negative volume); set orient = \"outward\"".to_string(),
            );
        }
        problems
    }
}

impl fmt::Display for MeshReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.extent_m;
        writeln!(
            f,
            "mesh: {} vertices, {} facets",
            self.vertices, self.facets
        )?;
        writeln!(
            f,
            "  size: {x:.1} x {y:.1} x {z:.1} m, area {:.4e} m², mean edge {:.3} m",
            self.total_area_m2, self.mean_edge_m
        )?;
        line(
            f,
            self.unreferenced_vertices,
            "every vertex is used by a facet",
            "vertices are used by no facet; they are ignored",
        )?;
        line(
            f,
            self.degenerate_facets,
            "no degenerate facets",
            "facets have (near) zero area or a repeated vertex; they get no normal, receive \
             no light and cast no shadow",
        )?;
        line(
            f,
            self.boundary_edges,
            "no boundary edges",
            "edges belong to a single facet: the surface is open (a terrain patch or a mesh \
             with holes), so light can reach the back of facets through the holes",
        )?;
        if self.boundary_edges > 0 {
            let share = 100.0 * self.open_share;
            let kind = match self.is_patch() {
                true => "a patch of terrain (horizon maps cost more to build)",
                false => "a body with seams or small holes",
            };
            writeln!(f, "  the openings are {share:.2} % of the area: {kind}")?;
        }
        line(
            f,
            self.non_manifold_edges,
            "no non-manifold edges",
            "edges are shared by more than two facets (duplicated facets, or surfaces \
             touching along an edge)",
        )?;
        line(
            f,
            self.inconsistent_edges,
            "consistent orientation between neighbours",
            "edges are traversed in the same direction by both their facets: some facets \
             are flipped relative to their neighbours, so their normals point the wrong way",
        )?;
        write_volume(f, self)?;
        if self.watertight {
            writeln!(f, "  ok: watertight once coincident vertices are merged")?;
        } else {
            writeln!(
                f,
                "  not watertight: light may pass through gaps or reach facets' backs"
            )?;
        }
        if self.convex {
            writeln!(
                f,
                "  ok: convex (no facet can shadow another facet of this body)"
            )
        } else {
            writeln!(f, "  not convex: facets may shadow each other")
        }
    }
}

/// One report line: "ok" when `count` is zero, else the count and what it means.
fn line(f: &mut fmt::Formatter<'_>, count: usize, ok: &str, problem: &str) -> fmt::Result {
    if count == 0 {
        writeln!(f, "  ok: {ok}")
    } else {
        writeln!(f, "  problem: {count} {problem}")
    }
}

fn write_volume(f: &mut fmt::Formatter<'_>, report: &MeshReport) -> fmt::Result {
    let volume = report.signed_volume_m3;
    if !report.closed {
        writeln!(
            f,
            "  signed volume {volume:.4e} m³ (not meaningful: the surface is not closed)"
        )
    } else if report.is_inward() {
        writeln!(
            f,
            "  problem: signed volume {volume:.4e} m³ is negative: the normals point inward; \
             set orient = \"outward\" to flip them"
        )
    } else {
        writeln!(
            f,
            "  ok: signed volume {volume:.4e} m³ is positive: the normals point outward"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::{height_field, icosphere};
    use crate::mesh::{LengthUnit, RawMesh};

    /// A sphere is closed, with or without a facet taken out (its opening's area over
    /// the sphere's); a height field is a patch, its opening as wide as itself.
    #[test]
    fn terrain_is_a_patch_and_a_body_with_a_hole_is_not() {
        let raw = icosphere(3, 1.0, DVec3::new(5.0, 0.0, 0.0));
        let sphere = inspect(&Mesh::from_raw(raw.clone(), LengthUnit::M));
        assert!(
            sphere.open_share < 1e-12 && !sphere.is_patch(),
            "{sphere:?}"
        );
        let holed = RawMesh {
            triangles: raw.triangles[1..].to_vec(),
            ..raw
        };
        let holed = inspect(&Mesh::from_raw(holed, LengthUnit::M));
        // One of 1,280 nearly equal facets: its area over the rest's, about 1/1280.
        assert!(holed.boundary_edges == 3, "{holed:?}");
        assert!((holed.open_share * 1280.0 - 1.0).abs() < 0.2, "{holed:?}");
        assert!(!holed.is_patch());
        let bumps = height_field((8, 8), (0.0, 1.0), (0.0, 1.0), |x, y| 0.1 * (x * y).sin());
        let terrain = inspect(&Mesh::from_raw(bumps, LengthUnit::M));
        assert!(
            terrain.open_share > 0.9 && terrain.is_patch(),
            "{terrain:?}"
        );
    }

    #[test]
    fn each_edge_names_the_facet_on_its_other_side() {
        // A closed sphere: three neighbours each, across the edge both share, and each
        // names the facet back across the same edge.
        let sphere = Mesh::from_raw(icosphere(2, 1.0, DVec3::ZERO), LengthUnit::M);
        let across = edge_neighbours(&sphere);
        for (f, sides) in across.iter().enumerate() {
            for (k, &n) in sides.iter().enumerate() {
                assert_ne!(n, NO_NEIGHBOUR, "facet {f} edge {k}");
                let [a, b] = [sphere.triangles[f][k], sphere.triangles[f][(k + 1) % 3]];
                let back = across[n as usize].iter().position(|&m| m == f as u32);
                let k_back = back.expect("named back");
                let t = sphere.triangles[n as usize];
                assert_eq!(
                    [t[(k_back + 1) % 3], t[k_back]],
                    [a, b],
                    "facet {f} edge {k}"
                );
            }
        }
        // Two facets meeting at an edge whose vertices are repeated (a seam) are
        // neighbours across it; a facet with a repeated vertex has none, nor an open edge.
        let raw = RawMesh {
            vertices: vec![
                DVec3::ZERO,
                DVec3::X,
                DVec3::Y,
                DVec3::X,
                DVec3::Y,
                DVec3::ONE,
            ],
            triangles: vec![[0, 1, 2], [3, 5, 4], [0, 0, 1]],
        };
        let seam = edge_neighbours(&Mesh::from_raw(raw, LengthUnit::M));
        let none = NO_NEIGHBOUR;
        assert_eq!(seam, vec![[none, 1, none], [none, none, 0], [none; 3]]);
    }
}
