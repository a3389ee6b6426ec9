//! A triangle's outline in a viewpoint's sky: its highest point at any azimuth and over
//! any wedge of azimuths, without clipping it.
//!
//! In: a triangle's corners relative to the viewpoint (metres) and the viewpoint's frame
//! (unit zenith `n`, tangent axes `t1`, `t2`). Out: sines of elevation above the plane of
//! `n`. Azimuths are given as in-plane vectors `(x, y)` along `t1`, `t2` (any length).
//!
//! The vertical half-plane at an azimuth cuts the triangle in a segment whose ends lie on
//! two of its edges; elevation along a straight segment seen from a point off it changes
//! monotonically, so the triangle's highest point at that azimuth is the higher of those
//! two ends. Each end is found by where the half-plane meets the edge's projection on the
//! tangent plane: a combination of the edge's two corners whose weights (the turns from
//! each corner to the azimuth) have one sign, so it stays on the edge whatever the
//! rounding.
//! Over a wedge, the triangle's part is bounded by its edges and the wedge's two
//! half-planes; its highest point is a corner inside the wedge, the top of an edge's arc
//! inside it, or the highest point at one of the wedge's bounding azimuths.
//!
//! An outline is only made where this holds and is well conditioned: the zenith axis
//! must not pass through the triangle, no corner may lie within 10⁻³ rad of it (where its
//! azimuth is lost), and no edge's projection may turn by less than 10⁻⁶ of its corners'
//! in-plane distances (nearly radial, or passing by the axis). The map clips such
//! triangles instead.

use glam::DVec3;

/// Least in-plane part of a corner, relative to its distance.
const LEAST_IN_PLANE: f64 = 1e-3;

/// Least turn of an edge's projection, relative to its corners' in-plane distances.
const LEAST_TURN: f64 = 1e-6;

/// A triangle as seen from a viewpoint, in the viewpoint's frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct Outline {
    /// The corners: `x`, `y` along the tangent axes, `z` along the zenith (metres).
    corners: [DVec3; 3],
    /// The corners' elevation sines.
    sines: [f64; 3],
    /// Per edge (corner `j` to `j + 1`), the sign of its projection's turn about the axis.
    turns: [f64; 3],
    /// Per edge, the top of its great circle (in-plane direction and elevation sine) when
    /// the top lies on the edge's arc.
    tops: [Option<((f64, f64), f64)>; 3],
}

/// The turn from in-plane vector `a` to `b` (their cross product's zenith part).
#[inline]
fn cross((ax, ay): (f64, f64), (bx, by): (f64, f64)) -> f64 {
    ax * by - ay * bx
}

/// The azimuths `lo` and `hi` (in-plane directions bounding a span counterclockwise from
/// `lo`) each turned outward, `lo` clockwise and `hi` counterclockwise, by an angle given
/// as its `(cos, sin)`: a span widened for [`Outline::max_within`] past the rounding of
/// the turns it is compared with.
pub(super) fn turned_outward(
    (c0, s0): (f64, f64),
    (c1, s1): (f64, f64),
    (co, so): (f64, f64),
) -> ((f64, f64), (f64, f64)) {
    (
        (c0 * co + s0 * so, s0 * co - c0 * so),
        (c1 * co - s1 * so, s1 * co + c1 * so),
    )
}

impl Outline {
    /// The outline of the triangle `rel` (corners relative to the viewpoint), or `None`
    /// where it would be ill conditioned (module docs).
    #[inline]
    pub(super) fn new(rel: &[DVec3; 3], n: DVec3, t1: DVec3, t2: DVec3) -> Option<Outline> {
        let corners = rel.map(|p| DVec3::new(p.dot(t1), p.dot(t2), p.dot(n)));
        let mut sines = [0.0; 3];
        for (sine, p) in sines.iter_mut().zip(&corners) {
            let length_squared = p.length_squared();
            let in_plane_squared = p.x * p.x + p.y * p.y;
            if in_plane_squared < LEAST_IN_PLANE * LEAST_IN_PLANE * length_squared {
                return None;
            }
            *sine = p.z / length_squared.sqrt();
        }
        let mut turns = [0.0; 3];
        let mut tops = [None; 3];
        for j in 0..3 {
            let (a, b) = (corners[j], corners[(j + 1) % 3]);
            let k = a.cross(b);
            let least = LEAST_TURN * ((a.x * a.x + a.y * a.y) * (b.x * b.x + b.y * b.y)).sqrt();
            if k.z.abs() < least || k.z == 0.0 {
                return None;
            }
            turns[j] = k.z.signum();
            // The great circle's top lies at the in-plane direction opposite its pole's
            // in-plane part, seen from the pole's side; it rises |k_xy| / |k|.
            let top = (-turns[j] * k.x, -turns[j] * k.y);
            let on_arc = turns[j] * cross((a.x, a.y), top) >= 0.0
                && turns[j] * cross(top, (b.x, b.y)) >= 0.0;
            if on_arc {
                tops[j] = Some((top, (k.x * k.x + k.y * k.y).sqrt() / k.length()));
            }
        }
        if turns[0] == turns[1] && turns[1] == turns[2] {
            // The projection winds around the zenith axis: the triangle holds the zenith
            // or the nadir, where every azimuth meets.
            return None;
        }
        Some(Outline {
            corners,
            sines,
            turns,
            tops,
        })
    }

    /// The highest elevation sine of the whole triangle: a corner or an edge's top (the
    /// zenith lies outside it).
    #[inline]
    pub(super) fn highest(&self) -> f64 {
        self.tops.iter().flatten().map(|&(_, sine)| sine).fold(
            self.sines[0].max(self.sines[1]).max(self.sines[2]),
            f64::max,
        )
    }

    /// The highest elevation sine of the triangle in the vertical half-plane at the
    /// in-plane direction `w`; `None` when the half-plane misses it.
    #[inline]
    pub(super) fn top_at(&self, w: (f64, f64)) -> Option<f64> {
        // By index, not `map`: a copy of the corners taken for `map` is read back at
        // other offsets than it was written, which stalls the loads behind the stores.
        let q: [f64; 3] = std::array::from_fn(|j| {
            let p = &self.corners[j];
            cross((p.x, p.y), w)
        });
        let mut best: Option<f64> = None;
        for j in 0..3 {
            let (qa, qb) = (q[j], q[(j + 1) % 3]);
            // The edge's projection runs from corner `j` to `j + 1` turning `turns[j]`;
            // `w` lies between them when it is past the first and short of the second.
            if self.turns[j] * qa < 0.0 || self.turns[j] * qb > 0.0 || qa == qb {
                continue;
            }
            // The cut is at `a + (b − a)·qa/(qa − qb)`; scaled by `qa − qb`, whose sign is
            // the edge's turn, it needs no division.
            let (a, b) = (self.corners[j], self.corners[(j + 1) % 3]);
            let cut = b * qa - a * qb;
            let sine = self.turns[j] * cut.z / cut.length();
            best = Some(best.map_or(sine, |m| m.max(sine)));
        }
        best
    }

    /// The highest elevation sine of the triangle's part between the in-plane directions
    /// `lo` and `hi` (turning counterclockwise from `lo`, by less than half a turn);
    /// `None` when it has none there.
    #[inline]
    pub(super) fn max_within(&self, lo: (f64, f64), hi: (f64, f64)) -> Option<f64> {
        let inside = |d: (f64, f64)| cross(lo, d) >= 0.0 && cross(d, hi) >= 0.0;
        let mut best = match (self.top_at(lo), self.top_at(hi)) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        let mut raise = |sine: f64| best = Some(best.map_or(sine, |m: f64| m.max(sine)));
        for (p, &sine) in self.corners.iter().zip(&self.sines) {
            if inside((p.x, p.y)) {
                raise(sine);
            }
        }
        for &(dir, sine) in self.tops.iter().flatten() {
            if inside(dir) {
                raise(sine);
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::horizon::geometry::tangent_frame;
    use crate::TestRng;
    use std::f64::consts::{PI, TAU};

    fn random_unit(rng: &mut TestRng) -> DVec3 {
        loop {
            let v = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 2.0 - 1.0;
            if (1e-3..=1.0).contains(&v.length_squared()) {
                return v.normalize();
            }
        }
    }

    /// A viewpoint frame and a triangle near it, some far and small, some near and large,
    /// some slivers; the frame's zenith tilted anyhow.
    fn random_case(rng: &mut TestRng) -> ([DVec3; 3], DVec3, DVec3, DVec3) {
        let n = random_unit(rng);
        let (t1, t2) = tangent_frame(n);
        let centre = random_unit(rng) * (1.0 + 9.0 * rng.unit());
        let size = 0.1 + 3.0 * rng.unit();
        let a = centre + random_unit(rng) * size;
        let b = centre + random_unit(rng) * size;
        let sliver = rng.unit() < 0.2;
        let d = if sliver {
            a + (b - a) * rng.unit() + random_unit(rng) * 1e-3 * size
        } else {
            centre + random_unit(rng) * size
        };
        ([a, b, d], n, t1, t2)
    }

    fn in_plane(p: DVec3, t1: DVec3, t2: DVec3) -> (f64, f64) {
        (p.dot(t1), p.dot(t2))
    }

    /// The highest elevation sine where the triangle meets the vertical half-plane of the
    /// in-plane direction `w`, found in 3D: each edge crossed with the plane, then kept
    /// on the half of it toward `w`.
    fn plane_cut_max(
        tri: &[DVec3; 3],
        n: DVec3,
        t1: DVec3,
        t2: DVec3,
        w: (f64, f64),
    ) -> Option<f64> {
        let toward = t1 * w.0 + t2 * w.1;
        let normal = n.cross(toward);
        let mut best: Option<f64> = None;
        for j in 0..3 {
            let (a, b) = (tri[j], tri[(j + 1) % 3]);
            let (ha, hb) = (a.dot(normal), b.dot(normal));
            if (ha > 0.0) == (hb > 0.0) {
                continue;
            }
            let p = a + (b - a) * (ha / (ha - hb));
            if p.dot(toward) > 0.0 {
                let sine = p.normalize().dot(n);
                best = Some(best.map_or(sine, |m| m.max(sine)));
            }
        }
        best
    }

    #[test]
    fn the_top_at_an_azimuth_is_where_the_vertical_half_plane_cuts_the_triangle() {
        let mut rng = TestRng::new(41);
        let mut compared = 0;
        for _ in 0..4000 {
            let (tri, n, t1, t2) = random_case(&mut rng);
            let Some(outline) = Outline::new(&tri, n, t1, t2) else {
                continue;
            };
            // Half toward a point of the triangle, half anywhere.
            let w = if rng.unit() < 0.5 {
                let (u, v) = (rng.unit(), rng.unit());
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                in_plane(
                    tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v,
                    t1,
                    t2,
                )
            } else {
                let phi = TAU * rng.unit();
                (phi.cos(), phi.sin())
            };
            let (ours, cut) = (outline.top_at(w), plane_cut_max(&tri, n, t1, t2, w));
            match (ours, cut) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 1e-9, "{a} against the cut's {b}");
                    compared += 1;
                }
                (None, None) => {}
                // The half-plane grazes a corner: both see at most that corner.
                (a, b) => {
                    let near_corner = tri.iter().any(|p| {
                        let (x, y) = in_plane(*p, t1, t2);
                        (x * w.1 - y * w.0).abs() < 1e-9 * x.hypot(y)
                    });
                    assert!(near_corner, "{a:?} against the cut's {b:?}");
                }
            }
        }
        assert!(compared > 2000, "only {compared} cuts compared");
    }

    #[test]
    fn a_wedges_maximum_bounds_and_matches_a_dense_sampling_of_the_triangle() {
        let mut rng = TestRng::new(42);
        let (mut compared, mut ill) = (0, 0);
        for _ in 0..1500 {
            let (tri, n, t1, t2) = random_case(&mut rng);
            let Some(outline) = Outline::new(&tri, n, t1, t2) else {
                ill += 1;
                continue;
            };
            // Wedges from 0.02 to 0.52 of half a turn, each holding a corner's azimuth.
            let width = (0.02 + 0.5 * rng.unit()) * PI;
            let (x, y) = in_plane(tri[(rng.unit() * 3.0) as usize % 3], t1, t2);
            let start = y.atan2(x) - width * rng.unit();
            let (lo, hi) = (
                (start.cos(), start.sin()),
                ((start + width).cos(), (start + width).sin()),
            );
            let inside = |p: DVec3| {
                let d = in_plane(p, t1, t2);
                cross(lo, d) >= 0.0 && cross(d, hi) >= 0.0
            };
            // Barycentric samples 1/steps apart: each point of the triangle lies within
            // an edge length / steps of one, which bounds how far their sines fall short.
            let steps = 200;
            let mut sampled: Option<f64> = None;
            for i in 0..=steps {
                for j in 0..=steps - i {
                    let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                    let p = tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v;
                    if inside(p) {
                        let sine = p.normalize().dot(n);
                        sampled = Some(sampled.map_or(sine, |m| m.max(sine)));
                    }
                }
            }
            let longest = (0..3)
                .map(|j| (tri[j] - tri[(j + 1) % 3]).length())
                .fold(0.0, f64::max);
            let nearest = tri.iter().map(|p| p.length()).fold(f64::INFINITY, f64::min);
            let spacing = 2.0 * longest / steps as f64 / (nearest - longest).max(1e-3);
            match (outline.max_within(lo, hi), sampled) {
                (Some(ours), Some(s)) => {
                    assert!(ours >= s - 1e-12, "{ours} below a sample's {s}");
                    if nearest > 2.0 * longest {
                        assert!(
                            ours <= s + spacing,
                            "{ours} above the samples' {s} + {spacing}"
                        );
                    }
                    compared += 1;
                }
                (None, Some(s)) => panic!("no part in the wedge, yet a sample at {s}"),
                // Too thin a part for any sample to fall in it.
                (_, None) => {}
            }
        }
        assert!(compared > 1000, "only {compared} wedges compared");
        assert!(ill < 100, "{ill} of 1500 triangles ill conditioned");
    }

    #[test]
    fn ill_conditioned_triangles_get_no_outline() {
        let (n, t1, t2) = (DVec3::Z, DVec3::X, DVec3::Y);
        // A corner straight above the viewpoint: its azimuth is lost.
        let above = [
            DVec3::new(0.0, 0.0, 5.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(0.0, 1.0, 1.0),
        ];
        assert!(Outline::new(&above, n, t1, t2).is_none());
        // An edge pointing away from the viewpoint: its projection does not turn.
        let radial = [
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(3.0, 0.0, 1.0),
            DVec3::new(2.0, 1.0, 0.0),
        ];
        assert!(Outline::new(&radial, n, t1, t2).is_none());
        // The zenith inside the triangle.
        let around = [
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(-1.0, 1.0, 1.0),
            DVec3::new(-1.0, -1.0, 1.0),
        ];
        assert!(Outline::new(&around, n, t1, t2).is_none());
        let fine = [
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(3.0, 0.5, 1.0),
            DVec3::new(2.0, 1.0, 0.0),
        ];
        assert!(Outline::new(&fine, n, t1, t2).is_some());
    }
}
