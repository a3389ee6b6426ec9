//! Rasterising a body's facets into images of facet ids, with a depth buffer.
//!
//! In: a mesh (metres, body frame). Out: [`IdRaster`]s — per pixel the id of the facet
//! seen there (or none) — for
//! - an equirectangular map: x = east-positive longitude −180° … 180°, y = planetocentric
//!   latitude 90° … −90°, pixel centres at ((i + ½)·360/W − 180, 90 − (j + ½)·180/H); each
//!   facet's latitude/longitude triangle is filled, split across the ±180° seam, and a
//!   facet around a pole (or with a corner on it) is widened to the pole over the
//!   longitudes it spans; where several facets overlap (a non-convex body seen from its
//!   centre) the one farthest from the centre wins;
//! - orthographic views from ±x, ±y, ±z: facets facing the camera, nearest wins, with a
//!   relief factor per pixel from a fixed light (used only in these views).

use glam::{DVec2, DVec3};

/// Marks a pixel no facet covers.
pub const NO_FACET: u32 = u32::MAX;

/// Facet ids (and depth, relief) per pixel, row by row from the top.
#[derive(Debug, Clone)]
pub struct IdRaster {
    pub width: usize,
    pub height: usize,
    facet: Vec<u32>,
    depth: Vec<f64>,
    relief: Vec<f32>,
}

impl IdRaster {
    fn new(width: usize, height: usize) -> IdRaster {
        IdRaster {
            width,
            height,
            facet: vec![NO_FACET; width * height],
            depth: vec![f64::NEG_INFINITY; width * height],
            relief: vec![1.0; width * height],
        }
    }

    /// The facet at pixel (x, y), if any.
    pub fn facet(&self, x: usize, y: usize) -> Option<usize> {
        let id = *self.facet.get(y * self.width + x)?;
        (id != NO_FACET).then_some(id as usize)
    }

    /// The relief factor at pixel (x, y): 1 on maps, about 0.75 … 1 in shaded views.
    pub fn relief(&self, x: usize, y: usize) -> f32 {
        self.relief.get(y * self.width + x).copied().unwrap_or(1.0)
    }

    /// Fills a triangle given in pixel coordinates; the larger interpolated depth wins.
    fn fill(&mut self, p: [DVec2; 3], depth: [f64; 3], facet: u32, relief: f32) {
        let area = edge(p[0], p[1], p[2]);
        if area.abs() <= 1e-12 || area.is_nan() {
            return;
        }
        let lo = p[0].min(p[1]).min(p[2]).floor().max(DVec2::ZERO);
        let hi = p[0].max(p[1]).max(p[2]).ceil();
        let (x1, y1) = (
            (hi.x as usize).min(self.width),
            (hi.y as usize).min(self.height),
        );
        for y in lo.y as usize..y1 {
            for x in lo.x as usize..x1 {
                let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let w = [
                    edge(p[1], p[2], c),
                    edge(p[2], p[0], c),
                    edge(p[0], p[1], c),
                ]
                .map(|e| e / area);
                if w.iter().all(|&wi| wi >= -1e-9) {
                    let d = w[0] * depth[0] + w[1] * depth[1] + w[2] * depth[2];
                    let i = y * self.width + x;
                    if d > self.depth[i] {
                        self.depth[i] = d;
                        self.facet[i] = facet;
                        self.relief[i] = relief;
                    }
                }
            }
        }
    }
}

/// Twice the signed area of (a, b, c).
fn edge(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - a)
}

/// Longitude and latitude (degrees) and radius of a point.
fn spherical(p: DVec3) -> (f64, f64, f64) {
    let r = p.length();
    let lat = if r > 0.0 {
        (p.z / r).clamp(-1.0, 1.0).asin().to_degrees()
    } else {
        0.0
    };
    (p.y.atan2(p.x).to_degrees(), lat, r)
}

/// `a` wrapped into (−180°, 180°].
fn wrap(a: f64) -> f64 {
    let w = (a + 180.0).rem_euclid(360.0) - 180.0;
    if w == -180.0 {
        180.0
    } else {
        w
    }
}

/// True when `p` lies on the spin axis (its longitude is undefined).
fn on_axis(p: DVec3) -> bool {
    p.truncate().length() <= 1e-12 * p.length().max(f64::MIN_POSITIVE)
}

/// A polygon in (longitude, latitude, radius).
type Polygon = Vec<(f64, f64, f64)>;

/// The latitude/longitude polygon of a facet, longitudes unwrapped to be continuous.
fn lat_lon_polygon(corners: [DVec3; 3]) -> Option<Polygon> {
    let sph = corners.map(spherical);
    let axis = corners.map(on_axis);
    if axis.iter().filter(|&&a| a).count() > 1 {
        return None;
    }
    let start = (0..3).find(|&i| !axis[i])?;
    // Longitudes of the off-axis corners, unwrapped around the first one.
    let mut lon = [0.0; 3];
    let mut prev = sph[start].0;
    for k in 0..3 {
        let i = (start + k) % 3;
        if !axis[i] {
            prev += wrap(sph[i].0 - prev);
            lon[i] = prev;
        }
    }
    if axis.iter().all(|&a| !a) {
        let winding: f64 = (0..3).map(|i| wrap(sph[(i + 1) % 3].0 - sph[i].0)).sum();
        if winding.abs() > 180.0 {
            return Some(polar_band(corners, sph));
        }
    }
    let mut poly = Polygon::new();
    for i in 0..3 {
        if axis[i] {
            // A corner on the pole becomes an edge along it, from the previous corner's
            // longitude to the next one's.
            let pole = if corners[i].z > 0.0 { 90.0 } else { -90.0 };
            poly.push((lon[(i + 2) % 3], pole, sph[i].2));
            poly.push((lon[(i + 1) % 3], pole, sph[i].2));
        } else {
            poly.push((lon[i], sph[i].1, sph[i].2));
        }
    }
    Some(poly)
}

/// A facet that surrounds a pole: a band from its lowest corner to the pole, all longitudes.
fn polar_band(corners: [DVec3; 3], sph: [(f64, f64, f64); 3]) -> Polygon {
    let north = corners.iter().map(|c| c.z).sum::<f64>() > 0.0;
    let (pole, edge_lat) = if north {
        (90.0, sph.iter().map(|s| s.1).fold(90.0, f64::min))
    } else {
        (-90.0, sph.iter().map(|s| s.1).fold(-90.0, f64::max))
    };
    let r = sph.iter().map(|s| s.2).sum::<f64>() / 3.0;
    vec![
        (-180.0, edge_lat, r),
        (180.0, edge_lat, r),
        (180.0, pole, r),
        (-180.0, pole, r),
    ]
}

/// The equirectangular facet-id map of a mesh, `width` × `height` pixels.
pub fn equirectangular(
    corners: impl Iterator<Item = [DVec3; 3]>,
    width: usize,
    height: usize,
) -> IdRaster {
    let mut raster = IdRaster::new(width, height);
    let to_px = |lon: f64, lat: f64| {
        DVec2::new(
            (lon + 180.0) / 360.0 * width as f64,
            (90.0 - lat) / 180.0 * height as f64,
        )
    };
    for (k, c) in corners.enumerate() {
        let Some(poly) = lat_lon_polygon(c) else {
            continue;
        };
        let (lo, hi) = poly
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                (a.min(p.0), b.max(p.0))
            });
        for shift in [-360.0, 0.0, 360.0] {
            if hi + shift < -180.0 || lo + shift > 180.0 {
                continue;
            }
            for t in 1..poly.len() - 1 {
                let v = [poly[0], poly[t], poly[t + 1]];
                let p = v.map(|(lon, lat, _)| to_px(lon + shift, lat));
                raster.fill(p, v.map(|q| q.2), k as u32, 1.0);
            }
        }
    }
    raster
}

/// An orthographic view: the camera looks from `from` toward the body's centre.
#[derive(Debug, Clone, Copy)]
pub struct View {
    pub label: &'static str,
    pub from: DVec3,
    pub right: DVec3,
    pub up: DVec3,
}

/// Views from +x, −x, +y, −y, +z, −z (right-handed screen axes).
pub const VIEWS: [View; 6] = [
    View {
        label: "from +x",
        from: DVec3::X,
        right: DVec3::Y,
        up: DVec3::Z,
    },
    View {
        label: "from −x",
        from: DVec3::NEG_X,
        right: DVec3::NEG_Y,
        up: DVec3::Z,
    },
    View {
        label: "from +y",
        from: DVec3::Y,
        right: DVec3::NEG_X,
        up: DVec3::Z,
    },
    View {
        label: "from −y",
        from: DVec3::NEG_Y,
        right: DVec3::X,
        up: DVec3::Z,
    },
    View {
        label: "from +z",
        from: DVec3::Z,
        right: DVec3::X,
        up: DVec3::Y,
    },
    View {
        label: "from −z",
        from: DVec3::NEG_Z,
        right: DVec3::X,
        up: DVec3::NEG_Y,
    },
];

/// Where an orthographic picture is centred and how large it is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Framing {
    /// Centre of the mesh's bounding box, metres.
    pub centre: DVec3,
    /// Pixels per metre.
    pub px_per_m: f64,
}

impl Framing {
    /// The mesh's bounding box centred, its farthest vertex from that centre at 95 % of
    /// the smaller half-side of a `width` × `height` picture; `None` for an empty mesh.
    pub fn fit(mesh: &crate::mesh::Mesh, width: usize, height: usize) -> Option<Framing> {
        let (lo, hi) = bounding_box(mesh)?;
        let centre = 0.5 * (lo + hi);
        let reach = mesh
            .vertices
            .iter()
            .map(|v| (*v - centre).length())
            .fold(0.0, f64::max);
        (reach > 0.0 && reach.is_finite()).then(|| Framing {
            centre,
            px_per_m: 0.95 * width.min(height) as f64 / (2.0 * reach),
        })
    }
}

fn bounding_box(mesh: &crate::mesh::Mesh) -> Option<(DVec3, DVec3)> {
    let first = *mesh.vertices.first()?;
    Some(
        mesh.vertices
            .iter()
            .fold((first, first), |(lo, hi), v| (lo.min(*v), hi.max(*v))),
    )
}

/// True for a terrain patch: a mesh whose bounding box leaves out the body's centre (the
/// frame origin). Whole bodies surround their centre.
pub fn is_patch(mesh: &crate::mesh::Mesh) -> bool {
    bounding_box(mesh)
        .is_some_and(|(lo, hi)| lo.cmpgt(DVec3::ZERO).any() || hi.cmplt(DVec3::ZERO).any())
}

/// The view from straight above a patch (from the body's centre through the patch's
/// centre), north (the body's +z) up.
pub fn overhead_view(mesh: &crate::mesh::Mesh) -> View {
    let from = bounding_box(mesh)
        .map(|(lo, hi)| (0.5 * (lo + hi)).normalize_or(DVec3::Z))
        .unwrap_or(DVec3::Z);
    let north = DVec3::Z - DVec3::Z.dot(from) * from;
    let north = north
        .try_normalize()
        .unwrap_or_else(|| from.any_orthonormal_vector());
    View {
        label: "from above",
        from,
        right: north.cross(from),
        up: north,
    }
}

/// The orthographic facet-id view of a mesh, `width` × `height` pixels, framed by
/// [`Framing::fit`].
pub fn orthographic(
    mesh: &crate::mesh::Mesh,
    view: &View,
    width: usize,
    height: usize,
) -> IdRaster {
    let mut raster = IdRaster::new(width, height);
    let Some(framing) = Framing::fit(mesh, width, height) else {
        return raster;
    };
    let half = DVec2::new(width as f64, height as f64) / 2.0;
    let light = (-0.35 * view.right + 0.45 * view.up + 0.82 * view.from).normalize();
    for k in 0..mesh.len() {
        let n = mesh.normals[k];
        if n.dot(view.from) <= 0.0 {
            continue;
        }
        let c = mesh.corners(k).map(|v| v - framing.centre);
        let p = c.map(|v| half + framing.px_per_m * DVec2::new(v.dot(view.right), -v.dot(view.up)));
        let relief = 0.75 + 0.25 * n.dot(light).max(0.0) as f32;
        raster.fill(p, c.map(|v| v.dot(view.from)), k as u32, relief);
    }
    raster
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{generate::icosphere, LengthUnit, Mesh, RawMesh};

    fn south_polar_patch() -> Mesh {
        // Two triangles 1 km across, 1737 km below the centre, facing down (outward).
        let z = -1_737.0;
        let raw = RawMesh {
            vertices: vec![
                DVec3::new(70.0, 0.0, z),
                DVec3::new(71.0, 0.0, z),
                DVec3::new(71.0, 1.0, z),
                DVec3::new(70.0, 1.0, z),
            ],
            triangles: vec![[0, 2, 1], [0, 3, 2]],
        };
        Mesh::from_raw(raw, LengthUnit::Km)
    }

    #[test]
    fn patches_are_told_from_whole_bodies_and_seen_from_above() {
        assert!(!is_patch(&Mesh::from_raw(
            icosphere(2, 1.0, DVec3::ZERO),
            LengthUnit::Km
        )));
        let patch = south_polar_patch();
        assert!(is_patch(&patch));
        let view = overhead_view(&patch);
        assert!(view.from.z < -0.99, "{:?}", view.from);
        assert!((view.right.cross(view.up) - view.from).length() < 1e-12);
        // North (+z) projects upward on the screen.
        assert!(view.up.z > 0.0);
        let raster = orthographic(&patch, &view, 60, 30);
        let seen = (0..30)
            .flat_map(|y| (0..60).map(move |x| (x, y)))
            .filter(|&(x, y)| raster.facet(x, y).is_some())
            .count();
        // The square's half-diagonal spans 95 % of half the 30-pixel height, so its side
        // is 0.95 · 30 / √2 pixels.
        let side = 0.95 * 30.0 / 2f64.sqrt();
        assert!(
            (seen as f64 - side * side).abs() < 0.1 * side * side,
            "{seen}"
        );
    }
}
