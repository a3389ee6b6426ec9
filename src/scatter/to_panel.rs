//! Terrain light on a panel: the sunlight a body's facets scatter toward a small panel
//! standing above them, to first order.
//!
//! In: the body's mesh (metres, body frame), how many of its facets receive light (the
//! rest, its surroundings, only hide), a tree over the mesh with its surroundings, and
//! the panel's point; per step the panel's unit normal and each kept facet's radiosity B
//! (W/m²). Out: the irradiance (W/m²) the facets send onto the panel, `Σ_j B_j F_j`.
//!
//! - **Form factors.** `F_j` is the exact form factor from a differential area at the
//!   panel's point with its normal to triangle j: Lambert's formula over the part of the
//!   triangle in front of the panel's plane ([`super::form_factor::point_to_triangle`]).
//!   Facets facing away from the point, or whose centroid the point cannot see (the
//!   segment between them crosses another facet), are left out whole.
//! - **Which facets.** A facet can give a panel of any orientation at most `Ω_j/π` of its
//!   radiosity (Ω_j its solid angle from the point). The visible facets are kept in
//!   decreasing Ω_j until those left hold at most [`LEFT_OUT`] in Σ Ω/π, or
//!   [`MOST_FACETS`] are kept; [`TerrainView::left_out`] says how much was dropped, so
//!   the light missed is at most that times the largest radiosity among them.
//! - **Radiosity.** The caller gives `B_j = ρ_j E_j` (first order: facet j's albedo times
//!   its direct irradiance, Lambertian). Light scattered more than once before reaching
//!   the panel is left out: it adds at most `ρ/(1−ρ)` of the first order, less than 14 %
//!   for the Moon's 0.12.

use super::form_factor::point_to_triangle;
use crate::mesh::Mesh;
use crate::trace::bvh::Bvh;
use glam::DVec3;

/// The most form factor, for any panel orientation, that the facets dropped may hold.
pub const LEFT_OUT: f64 = 2e-3;

/// The most facets kept: each costs a direct-irradiance evaluation per step.
pub const MOST_FACETS: usize = 128;

/// What a panel's point sees of the terrain's facets.
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainView {
    point: DVec3,
    /// Kept facets (indices of the mesh's receiving facets), largest solid angle first.
    facets: Vec<u32>,
    corners: Vec<[DVec3; 3]>,
    left_out: f64,
}

impl TerrainView {
    /// The facets `0..receivers` of `mesh` that the point `point` sees, through `bvh`
    /// (built over `mesh`, whose facets past `receivers` only hide), kept as the module
    /// doc says.
    pub fn new(mesh: &Mesh, receivers: usize, bvh: &Bvh, point: DVec3) -> TerrainView {
        let margin = 1e-9 * point.length().max(1.0);
        let mut seen: Vec<(f64, u32)> = (0..receivers)
            .filter(|&j| {
                mesh.areas[j] > 0.0 && mesh.normals[j].dot(point - mesh.centroids[j]) > 0.0
            })
            .filter(|&j| {
                !bvh.segment_blocked(point, mesh.centroids[j], [u32::MAX, j as u32], margin)
            })
            .map(|j| {
                (
                    solid_angle(point, mesh.corners(j)) / std::f64::consts::PI,
                    j as u32,
                )
            })
            .collect();
        seen.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let total: f64 = seen.iter().map(|s| s.0).sum();
        let mut kept = 0;
        let mut rest = total;
        while kept < seen.len() && kept < MOST_FACETS && rest > LEFT_OUT {
            rest -= seen[kept].0;
            kept += 1;
        }
        let facets: Vec<u32> = seen[..kept].iter().map(|s| s.1).collect();
        TerrainView {
            point,
            corners: facets.iter().map(|&j| mesh.corners(j as usize)).collect(),
            facets,
            left_out: seen[kept..].iter().map(|s| s.0).sum(),
        }
    }

    /// The kept facets, whose radiosities [`TerrainView::irradiance`] takes in this order.
    pub fn facets(&self) -> &[u32] {
        &self.facets
    }

    /// Σ Ω/π of the visible facets dropped: the most form factor they could hold.
    pub fn left_out(&self) -> f64 {
        self.left_out
    }

    /// The irradiance (W/m²) on a panel with unit normal `normal` at the point, from the
    /// kept facets with radiosities `radiosity` (W/m², one per kept facet).
    pub fn irradiance(&self, normal: DVec3, radiosity: &[f64]) -> f64 {
        self.corners
            .iter()
            .zip(radiosity)
            .filter(|(_, &b)| b > 0.0)
            .map(|(tri, b)| b * point_to_triangle(self.point, normal, tri))
            .sum()
    }
}

/// The solid angle (sr) of triangle `tri` seen from `x` (Van Oosterom and Strackee, 1983).
fn solid_angle(x: DVec3, tri: [DVec3; 3]) -> f64 {
    let [a, b, c] = tri.map(|p| p - x);
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let numerator = a.dot(b.cross(c)).abs();
    let denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    2.0 * numerator.atan2(denominator)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{LengthUnit, RawMesh};
    use std::f64::consts::PI;

    /// A square plane of half-width `half` (m) in z = 0, facing +z, cut into `n × n`
    /// squares of two triangles each.
    fn plane(half: f64, n: u32) -> Mesh {
        let side = 2.0 * half / n as f64;
        let vertices = (0..=n)
            .flat_map(|j| (0..=n).map(move |i| (i, j)))
            .map(|(i, j)| DVec3::new(-half + i as f64 * side, -half + j as f64 * side, 0.0))
            .collect();
        let at = |i: u32, j: u32| j * (n + 1) + i;
        let triangles = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .flat_map(|(i, j)| {
                [
                    [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                    [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                ]
            })
            .collect();
        Mesh::from_raw(
            RawMesh {
                vertices,
                triangles,
            },
            LengthUnit::M,
        )
    }

    /// A panel h above an infinite plane of uniform radiosity B, tilted β from facing up,
    /// receives B·(1 − cos β)/2 (the plane fills the half of its view below the horizon:
    /// 0 facing up, 1/2 vertical, 1 facing down). The finite plane (half-width L) misses
    /// the part beyond the inscribed disk of radius L, at most ∫_L^∞ (h/r)/(πr²) 2πρ dρ =
    /// 2h/√(L² + h²) of form factor, and the facets dropped at most `left_out`.
    #[test]
    fn a_panel_over_a_uniform_plane_gets_the_closed_form() {
        let (half, h) = (1000.0, 1.0);
        // Off the grid's vertices, so that no triangle edge passes under the point.
        let point = DVec3::new(3.7, -11.2, h);
        let mesh = plane(half, 40);
        let bvh = Bvh::build(&mesh);
        let view = TerrainView::new(&mesh, mesh.len(), &bvh, point);
        assert!(view.left_out() <= LEFT_OUT || view.facets().len() == MOST_FACETS);
        let bound = 2.0 * h / (half * half + h * h).sqrt() + view.left_out();
        assert!(bound < 0.02, "{bound}");
        let b = vec![100.0; view.facets().len()];
        for beta_deg in [0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0] {
            let beta = f64::to_radians(beta_deg);
            let normal = DVec3::new(beta.sin(), 0.0, beta.cos());
            let got = view.irradiance(normal, &b) / 100.0;
            let want = (1.0 - beta.cos()) / 2.0;
            assert!(got <= want + 1e-12, "β {beta_deg}: {got} vs {want}");
            assert!(
                want - got <= bound,
                "β {beta_deg}: {got} vs {want} (bound {bound})"
            );
        }
        // The sum of kept and dropped solid angles is the lower half of the sky: 2π sr.
        let kept: f64 = view
            .facets()
            .iter()
            .map(|&j| solid_angle(point, mesh.corners(j as usize)))
            .sum();
        let all = kept + PI * view.left_out();
        assert!((all - 2.0 * PI).abs() < 2.0 * PI * 2.0 * h / half, "{all}");
    }

    /// A point below the plane sees only the facets' backs; a panel above it facing up
    /// sees none of them, facing down nearly all.
    #[test]
    fn facets_seen_from_behind_or_behind_the_panel_give_nothing() {
        let mesh = plane(100.0, 10);
        let bvh = Bvh::build(&mesh);
        // Below the plane: every facet faces away.
        let under = TerrainView::new(&mesh, mesh.len(), &bvh, DVec3::new(0.3, 0.1, -1.0));
        assert!(under.facets().is_empty() && under.left_out() == 0.0);
        let above = TerrainView::new(&mesh, mesh.len(), &bvh, DVec3::new(0.3, 0.1, 1.0));
        let b = vec![1.0; above.facets().len()];
        assert_eq!(above.irradiance(DVec3::Z, &b), 0.0);
        assert!(above.irradiance(-DVec3::Z, &b) > 0.9);
    }
}
