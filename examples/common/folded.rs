//! The folded test shape: a bilobed body like a contact binary, built from two shipped
//! shape models.
//!
//! In: `data/shapes/phobos/m1phobos.obj` and `data/shapes/itokawa/ItokawaHayabusa.obj`
//! (both in km). Out: one [`RawMesh`] in km, 81,222 facets (32,070 + 49,152): Phobos as
//! the big lobe, and Itokawa, scaled ×25 (about 14 km long) and tilted, as the small
//! lobe, pushed 1.5 km into Phobos's +x end so that the two meet at a narrow neck. The
//! vertex and triangle lists are simply concatenated: the lobes interpenetrate (no
//! boolean union), which is intended.
//!
//! Why: a smooth, nearly convex body flatters every shadow tracer. Speed claims must also
//! hold where shapes fold: the neck makes deep overhangs and long shadows across both
//! lobes, the buried parts of each lobe (and m1phobos's fins below its surface along a
//! seam) stack many facets over the same spot seen from the Sun, so a Sun-view grid gets
//! long per-cell lists and a BVH gets overlapping boxes. Itokawa is itself a contact
//! binary, so the small lobe brings a second neck. Everything is deterministic: the same
//! files always give the same mesh.

use glam::{DMat3, DVec3};
use slim::mesh::{read_mesh, RawMesh};
use std::path::PathBuf;

/// Scale applied to Itokawa (km model, about 0.56 km long) to make the small lobe.
const SMALL_LOBE_SCALE: f64 = 25.0;
/// Tilt of the small lobe about z, then about y (radians), so the neck is not symmetric
/// about the equator plane or the spin axis.
const SMALL_LOBE_YAW: f64 = 0.35;
const SMALL_LOBE_PITCH: f64 = -0.30;
/// How far (km) the small lobe's near end reaches into the big lobe along x.
const PENETRATION_KM: f64 = 1.5;

/// A shipped shape file, by its path under `data/shapes/`.
fn shape(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/shapes")
        .join(rel)
}

/// The folded body (km): see the module doc.
pub fn folded_raw() -> Result<RawMesh, slim::Error> {
    let big = read_mesh(&shape("phobos/m1phobos.obj"), None)?;
    let small = read_mesh(&shape("itokawa/ItokawaHayabusa.obj"), None)?;

    // Small lobe: centred on its vertex mean, scaled, then tilted.
    let mean = small.vertices.iter().copied().sum::<DVec3>() / small.vertices.len() as f64;
    let tilt = DMat3::from_rotation_y(SMALL_LOBE_PITCH) * DMat3::from_rotation_z(SMALL_LOBE_YAW);
    let placed: Vec<DVec3> = small
        .vertices
        .iter()
        .map(|&v| tilt * ((v - mean) * SMALL_LOBE_SCALE))
        .collect();

    // Push it along +x until its nearest point is PENETRATION_KM inside the big lobe's
    // +x extreme.
    let big_max_x = big.vertices.iter().map(|v| v.x).fold(f64::MIN, f64::max);
    let small_min_x = placed.iter().map(|v| v.x).fold(f64::MAX, f64::min);
    let shift = DVec3::X * (big_max_x - PENETRATION_KM - small_min_x);

    let offset = big.vertices.len() as u32;
    let mut vertices = big.vertices;
    vertices.extend(placed.into_iter().map(|v| v + shift));
    let mut triangles = big.triangles;
    triangles.extend(small.triangles.iter().map(|t| t.map(|i| i + offset)));
    Ok(RawMesh {
        vertices,
        triangles,
    })
}
