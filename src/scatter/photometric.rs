//! The first bounce with each body's reflectance model (Hapke, Lommel–Seeliger, Lambert)
//! instead of Lambert's law — the paper's non-Lambertian scattering, which keeps only this
//! first order (section 6.2); higher orders stay Lambertian with the bodies' albedos.
//!
//! In: the step's direct irradiance `D` (W/m²), the exchange areas `G_ij = A_i F_ij` (m²),
//! the Sun direction and flux `J` at every body, and one [`Material`] per body. Out: the
//! first-order scattered irradiance at every facet,
//!
//! `S1_i = (1/A_i) Σ_j G_ij · π J r_j(i_j, e_ji, g_ji)` for every lit facet j,
//!
//! where `r_j` (sr⁻¹) is facet j's bidirectional reflectance for the Sun at incidence
//! `i_j`, facet i seen at emission `e_ji` and phase `g_ji` between the Sun and facet i as
//! seen from j. `π J r` is the radiance leaving j toward i times π, so for a Lambert
//! material (r = ρ cos i / π) this is exactly the Lambertian `S1 = F ρ D`.

use super::{Block, FirstOrderInput, FirstScatter};
use crate::photometry::{Angles, Material, Reflectance};
use glam::DVec3;

/// First bounce with one reflectance model per body.
#[derive(Debug, Clone)]
pub struct Photometric {
    /// One material per body, in world order.
    pub materials: Vec<Material>,
}

/// Per facet, in the scene frame: centroid (m), unit normal, unit Sun direction, and the
/// flux (W/m²) and body it belongs to.
struct FacetGeometry {
    centroid: Vec<DVec3>,
    normal: Vec<DVec3>,
    sun: Vec<DVec3>,
    flux: Vec<f64>,
    body: Vec<usize>,
}

impl FacetGeometry {
    fn of(input: &FirstOrderInput) -> FacetGeometry {
        let n = input.direct.len();
        let mut g = FacetGeometry {
            centroid: Vec::with_capacity(n),
            normal: Vec::with_capacity(n),
            sun: Vec::with_capacity(n),
            flux: Vec::with_capacity(n),
            body: Vec::with_capacity(n),
        };
        for (b, (body, state)) in input
            .world
            .bodies
            .iter()
            .zip(&input.state.bodies)
            .enumerate()
        {
            let axes = state.pose.body_to_scene;
            let sun = axes * state.sun_dir;
            for k in 0..body.mesh.len() {
                g.centroid
                    .push(axes * body.mesh.centroids[k] + state.pose.position_m);
                g.normal.push(axes * body.mesh.normals[k]);
                g.sun.push(sun);
                g.flux.push(state.flux_w_m2);
                g.body.push(b);
            }
        }
        g
    }
}

impl Photometric {
    /// `π J r_j` toward facet `i`: the light facet `j` sends to `i` per unit of `F_ij`
    /// (W/m²); 0 when `j` is unlit.
    fn sent(&self, g: &FacetGeometry, direct: &[f64], j: usize, i: usize) -> f64 {
        if direct[j] <= 0.0 {
            return 0.0;
        }
        let Some(toward) = (g.centroid[i] - g.centroid[j]).try_normalize() else {
            return 0.0;
        };
        let angles = Angles::from_vectors(g.normal[j], g.sun[j], toward);
        std::f64::consts::PI * g.flux[j] * self.materials[g.body[j]].reflectance(&angles)
    }

    /// Adds block `b`'s contributions to `acc` (global ids; exchange areas, not yet
    /// divided by the receiving areas).
    fn add_block(&self, b: &Block, g: &FacetGeometry, direct: &[f64], acc: &mut [f64]) {
        for r in 0..b.matrix.rows() {
            let i = b.row_offset + r;
            for (c, value) in b.matrix.row(r) {
                let j = b.col_offset + c as usize;
                let exchange = value as f64;
                acc[i] += exchange * self.sent(g, direct, j, i);
                if b.matrix.symmetric {
                    acc[j] += exchange * self.sent(g, direct, i, j);
                }
            }
        }
    }
}

impl FirstScatter for Photometric {
    fn first_order(&self, input: &FirstOrderInput, out: &mut [f64]) {
        let geometry = FacetGeometry::of(input);
        out.fill(0.0);
        for block in &input.exchange.blocks {
            self.add_block(block, &geometry, input.direct, out);
        }
        for (s, a) in out.iter_mut().zip(input.exchange.areas) {
            *s = if *a > 0.0 { *s / a } else { 0.0 };
        }
    }
}
