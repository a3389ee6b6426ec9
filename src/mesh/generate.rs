//! Generated meshes: geodesic spheres, height fields and midpoint subdivision.
//!
//! Out: [`RawMesh`]es in whatever unit the caller uses, with outward (counter-clockwise)
//! facets. Used for validation against closed forms (a sphere has them), for tests that
//! must stay small, and for benchmarks on large meshes built from shipped ones.

use super::RawMesh;
use glam::DVec3;
use std::collections::HashMap;

/// A geodesic sphere: an icosahedron split `levels` times (20·4^levels facets), every
/// vertex on the sphere of `radius` about `centre`.
pub fn icosphere(levels: u32, radius: f64, centre: DVec3) -> RawMesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let corners = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ];
    let mut mesh = RawMesh {
        vertices: corners
            .iter()
            .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
            .collect(),
        triangles: vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ],
    };
    for _ in 0..levels {
        mesh = subdivide(&mesh);
        mesh.vertices.iter_mut().for_each(|v| *v = v.normalize());
    }
    mesh.vertices
        .iter_mut()
        .for_each(|v| *v = centre + *v * radius);
    mesh
}

/// A triaxial ellipsoid with semi-axes `radii` along x, y, z: a geodesic sphere of
/// `levels` subdivisions stretched along the axes (outward facets stay outward).
pub fn ellipsoid(levels: u32, radii: DVec3) -> RawMesh {
    let mut mesh = icosphere(levels, 1.0, DVec3::ZERO);
    mesh.vertices.iter_mut().for_each(|v| *v *= radii);
    mesh
}

/// A height field over the rectangle `x0..x1 × y0..y1`: `nx × ny` cells, each split along
/// its (x0,y0)–(x1,y1) diagonal, facets facing up (+z side). `z(x, y)` is called once per
/// vertex, row by row (y outer, x inner).
pub fn height_field(
    (nx, ny): (usize, usize),
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    mut z: impl FnMut(f64, f64) -> f64,
) -> RawMesh {
    let mut vertices = Vec::with_capacity((nx + 1) * (ny + 1));
    for j in 0..=ny {
        for i in 0..=nx {
            let x = x0 + (x1 - x0) * i as f64 / nx as f64;
            let y = y0 + (y1 - y0) * j as f64 / ny as f64;
            vertices.push(DVec3::new(x, y, z(x, y)));
        }
    }
    let v = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut triangles = Vec::with_capacity(2 * nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            triangles.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            triangles.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
        }
    }
    RawMesh {
        vertices,
        triangles,
    }
}

/// A floor (two triangles at z = 0 on the square −1..1, facing +z) and a vertical wall of
/// height `h` along x = `wall_x`, from y = −`half` to `half`: seen from a point of the
/// floor at x, the wall's top is a horizon of elevation atan(h / (wall_x − x)) toward
/// +x, a closed form for horizon and shadow tests.
pub fn floor_and_wall(h: f64, wall_x: f64, half: f64) -> RawMesh {
    RawMesh {
        vertices: vec![
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(-1.0, 1.0, 0.0),
            DVec3::new(wall_x, -half, 0.0),
            DVec3::new(wall_x, half, 0.0),
            DVec3::new(wall_x, half, h),
            DVec3::new(wall_x, -half, h),
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]],
    }
}

/// Splits every facet into four at its edge midpoints (shared midpoints are shared
/// vertices, so a closed mesh stays closed). Facet count ×4, shape unchanged.
pub fn subdivide(mesh: &RawMesh) -> RawMesh {
    let mut vertices = mesh.vertices.clone();
    let mut midpoints: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.triangles.len() * 2);
    let mut midpoint = |a: u32, b: u32, vertices: &mut Vec<DVec3>| -> u32 {
        *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
            vertices.push((vertices[a as usize] + vertices[b as usize]) * 0.5);
            (vertices.len() - 1) as u32
        })
    };
    let mut triangles = Vec::with_capacity(mesh.triangles.len() * 4);
    for &[a, b, c] in &mesh.triangles {
        let ab = midpoint(a, b, &mut vertices);
        let bc = midpoint(b, c, &mut vertices);
        let ca = midpoint(c, a, &mut vertices);
        triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    RawMesh {
        vertices,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn icosphere_counts_and_radius() {
        let m = icosphere(3, 2.0, DVec3::new(1.0, 0.0, 0.0));
        assert_eq!(m.triangles.len(), 20 * 64);
        assert_eq!(m.vertices.len(), 10 * 64 + 2);
        for v in &m.vertices {
            assert!(((*v - DVec3::X).length() - 2.0).abs() < 1e-12);
        }
        // Outward: every facet's normal points away from the centre.
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| m.vertices[i as usize] - DVec3::X);
            assert!((b - a).cross(c - a).dot(a + b + c) > 0.0);
        }
    }
}
