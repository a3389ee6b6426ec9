//! The exact ray–triangle predicate shared by every tracer.
//!
//! A ray direction `d` defines an orthonormal frame (u, w, d). Points are projected once
//! into it, `(p·u, p·w, p·d)`; a ray then becomes a point `q` in the (u, w) plane moving
//! along the third axis. The ray hits a triangle when `q` lies inside the triangle's
//! projection, at the depth interpolated over the triangle.
//!
//! Watertightness: the 2-D edge function of an edge is always evaluated from the same end
//! (the lexicographically smaller projected vertex), so the two triangles sharing an edge
//! get exactly opposite values. A ray through a shared edge or vertex is therefore inside
//! at least one of them (points on an edge count as inside), and no ray slips between
//! neighbours. Because the frame depends only on the direction and the projection of a
//! vertex only on the vertex, every tracer computes bit-identical values.

use glam::{DVec2, DVec3};

/// Orthonormal frame whose third axis is a ray direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayFrame {
    u: DVec3,
    w: DVec3,
    d: DVec3,
}

impl RayFrame {
    /// The frame for unit direction `d` (branch-light construction of Duff et al. 2017,
    /// "Building an orthonormal basis, revisited", JCGT 6(1)).
    pub fn new(d: DVec3) -> RayFrame {
        let sign = 1f64.copysign(d.z);
        let a = -1.0 / (sign + d.z);
        let b = d.x * d.y * a;
        RayFrame {
            u: DVec3::new(1.0 + sign * d.x * d.x * a, sign * b, -sign * d.x),
            w: DVec3::new(b, sign + d.y * d.y * a, -d.y),
            d,
        }
    }

    /// The direction this frame was built for.
    pub fn dir(&self) -> DVec3 {
        self.d
    }

    /// `p` in frame coordinates: (across, across, along the ray).
    #[inline]
    pub fn project(&self, p: DVec3) -> DVec3 {
        DVec3::new(p.dot(self.u), p.dot(self.w), p.dot(self.d))
    }
}

/// 2-D edge function of edge a→b at q, evaluated from the canonical end (see module doc).
#[inline]
fn edge(a: DVec2, b: DVec2, q: DVec2) -> f64 {
    let canonical = |a: DVec2, b: DVec2| (b.x - a.x) * (q.y - a.y) - (b.y - a.y) * (q.x - a.x);
    if (a.x, a.y) <= (b.x, b.y) {
        canonical(a, b)
    } else {
        -canonical(b, a)
    }
}

/// The plane of a facet in a ray frame, as depth over the projection plane:
/// depth(x, y) = a·x + b·y + c.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthPlane {
    a: f64,
    b: f64,
    c: f64,
}

impl DepthPlane {
    /// The plane with projected unit normal `n` through projected point `p`. A facet seen
    /// edge-on (n.z = 0) gets a plane that is never in front of anything.
    #[inline]
    pub fn new(n: DVec3, p: DVec3) -> DepthPlane {
        if n.z == 0.0 {
            return DepthPlane {
                a: 0.0,
                b: 0.0,
                c: f64::NEG_INFINITY,
            };
        }
        DepthPlane {
            a: -n.x / n.z,
            b: -n.y / n.z,
            c: n.dot(p) / n.z,
        }
    }

    /// Distance along the ray from projected point `q` to the plane (negative: behind).
    #[inline]
    pub fn distance(&self, q: DVec3) -> f64 {
        self.a * q.x + self.b * q.y + self.c - q.z
    }
}

/// True when projected point `q` lies inside the projected triangle `tri` or on its edges
/// (never for a triangle seen edge-on).
#[inline]
pub fn inside(tri: &[DVec3; 3], q: DVec3) -> bool {
    let [a, b, c] = tri.map(|p| p.truncate());
    let q = q.truncate();
    let e_ab = edge(a, b, q);
    let e_bc = edge(b, c, q);
    // Opposite strict signs on two edges already put q outside.
    if (e_ab < 0.0 && e_bc > 0.0) || (e_ab > 0.0 && e_bc < 0.0) {
        return false;
    }
    let e_ca = edge(c, a, q);
    let all_ge = e_ab >= 0.0 && e_bc >= 0.0 && e_ca >= 0.0;
    let all_le = e_ab <= 0.0 && e_bc <= 0.0 && e_ca <= 0.0;
    (all_ge || all_le) && e_ab + e_bc + e_ca != 0.0
}

/// The predicate every tracer uses: the ray through projected point `q` hits the facet with
/// projected corners `tri` and depth plane `plane` at a distance greater than `t_min`.
/// The cheap plane test runs first; the order does not change the answer.
#[inline]
pub fn blocks(tri: &[DVec3; 3], plane: &DepthPlane, q: DVec3, t_min: f64) -> bool {
    plane.distance(q) > t_min && inside(tri, q)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_for_awkward_directions() {
        for d in [
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            -DVec3::Z,
            DVec3::new(1.0, 1.0, 1.0).normalize(),
            DVec3::new(0.0, -1e-300, -1.0).normalize(),
        ] {
            let f = RayFrame::new(d);
            assert!((f.u.length() - 1.0).abs() < 1e-15);
            assert!((f.w.length() - 1.0).abs() < 1e-15);
            assert!(f.u.dot(f.w).abs() < 1e-15);
            assert!(f.u.dot(d).abs() < 1e-15 && f.w.dot(d).abs() < 1e-15);
        }
    }

    #[test]
    fn shared_edge_is_hit_by_at_least_one_side() {
        // Two triangles sharing edge (0,0)-(1,1); points exactly on it must hit.
        let t1 = [
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(1.0, 1.0, 1.0),
        ];
        let t2 = [
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(0.0, 1.0, 1.0),
        ];
        for k in 0..=100 {
            let s = k as f64 / 100.0 * 0.7 + 0.1;
            let q = DVec3::new(s, s, 0.0);
            assert!(inside(&t1, q) || inside(&t2, q));
        }
        // Points a hair off the edge fall into exactly one of the two.
        let q = DVec3::new(0.5, f64::from_bits(0.5f64.to_bits() + 1), 0.0);
        assert!(inside(&t1, q) != inside(&t2, q));
    }

    #[test]
    fn plane_depth_and_blocking() {
        // The plane z = x + 2y through the origin; its unit normal is (1, 2, -1)/√6.
        let t = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(2.0, 0.0, 2.0),
            DVec3::new(0.0, 2.0, 4.0),
        ];
        let plane = DepthPlane::new(DVec3::new(1.0, 2.0, -1.0).normalize(), t[0]);
        let q = DVec3::new(0.5, 0.5, -1.0);
        assert!((plane.distance(q) - 2.5).abs() < 1e-12);
        assert!(blocks(&t, &plane, q, 2.4) && !blocks(&t, &plane, q, 2.6));
        assert!(!blocks(&t, &plane, DVec3::new(1.5, 1.5, 0.0), 0.0));
        let edge_on = DepthPlane::new(DVec3::X, DVec3::ZERO);
        assert!(edge_on.distance(q) < 0.0);
    }
}
