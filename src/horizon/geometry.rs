//! Horizon geometry: how high a box or a triangle rises above a plane, seen from a point.
//!
//! In: a viewpoint `c` and the unit normal `n` of its plane (metres, body frame), and a box
//! or triangle. Out: sines of elevation above that plane (`n·u` for a unit direction `u`
//! from `c`), exact for triangles and an upper bound for boxes, and the distance from a
//! point to a triangle. The horizon bound and the horizon maps are built from these.
//!
//! The elevation of a triangle seen from a point is maximal at a corner, on an edge (the
//! highest point of the great-circle arc between two corner directions) or, when the
//! normal points into the triangle's cone of directions, straight up (sin = 1).
//!
//! Also the two functions that maps and their lookups must share to agree: a facet's
//! tangent frame (from which azimuths are measured) and the fast `atan2` both take.

use crate::mesh::Mesh;
use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// The exact predicate's position error as a multiple of `ε · |v|max` (its edge
/// functions combine three roundings of coordinates that size; this is far above).
const ROUNDING_ULPS: f64 = 1024.0;

/// How far (metres) a triangle of `mesh` is widened so that a ray the exact tracers call
/// blocked through rounding is never cleared: `ROUNDING_ULPS · ε · |v|max`.
pub(crate) fn rounding_widening(mesh: &Mesh) -> f64 {
    let reach = mesh
        .vertices
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs().max_element()));
    ROUNDING_ULPS * f64::EPSILON * reach
}

/// An upper bound of the elevation sine from `c` (plane normal `n`) of every point of the
/// box `lo..hi` widened by `widening`, from −1 to 1: a box wholly below the plane is
/// bounded by its highest rise over its farthest corner's distance.
#[inline]
pub(crate) fn signed_box_bound(c: DVec3, n: DVec3, lo: DVec3, hi: DVec3, widening: f64) -> f64 {
    let (lo, hi) = (lo - widening, hi + widening);
    let mid = (lo + hi) * 0.5;
    let half = (hi - lo) * 0.5;
    let rise = n.dot(mid - c) + n.abs().dot(half);
    if rise < 0.0 {
        let far = ((mid - c).abs() + half).length();
        return (rise / far).max(-1.0);
    }
    if rise == 0.0 {
        return 0.0;
    }
    let gap = (c.clamp(lo, hi) - c).length();
    if gap <= 0.0 {
        1.0
    } else {
        (rise / gap).min(1.0)
    }
}

/// An upper bound of the elevation sine from `c` (plane normal `n`) of every point within
/// `widening` of triangle `tri`: the exact maximum over the triangle plus `widening` over
/// the distance to it, or anything not above `threshold` when a cheap bound (its highest
/// corner) shows that it is not higher.
#[inline]
pub(crate) fn triangle_bound(
    c: DVec3,
    n: DVec3,
    tri: &[DVec3; 3],
    widening: f64,
    threshold: f64,
) -> f64 {
    if !may_rise_above(c, n, tri, widening, threshold) {
        return 0.0;
    }
    let gap = distance_to_triangle(c, tri);
    if touches(gap, widening) {
        return 1.0;
    }
    (triangle_max_sin(c, n, tri) + widening / (gap - widening)).min(1.0)
}

/// Whether a triangle `gap` metres from a viewpoint touches it, for a bound of widened
/// triangles: within 64 widenings the widening's margin on the elevation sine,
/// `widening / (gap − widening)`, is no longer small, and the triangle may hide anything.
#[inline]
pub(crate) fn touches(gap: f64, widening: f64) -> bool {
    gap <= 64.0 * widening
}

/// False when no point within `widening` of triangle `tri` rises above the elevation sine
/// `threshold` seen from `c` (plane normal `n`): its highest corner's rise over the plane
/// (every point of a triangle rises less than one of its corners), widened, over the
/// distance to its widened box is no higher. Tighter than the box's own bound, and without
/// a root or a division.
#[inline]
pub(crate) fn may_rise_above(
    c: DVec3,
    n: DVec3,
    tri: &[DVec3; 3],
    widening: f64,
    threshold: f64,
) -> bool {
    let rise = tri
        .iter()
        .map(|p| n.dot(*p - c))
        .fold(f64::NEG_INFINITY, f64::max)
        + widening;
    if rise <= 0.0 || threshold < 0.0 {
        // Nothing above the plane, or a threshold below it.
        return threshold < 0.0;
    }
    let (lo, hi) = (
        tri[0].min(tri[1]).min(tri[2]) - widening,
        tri[0].max(tri[1]).max(tri[2]) + widening,
    );
    let gap_squared = (c.clamp(lo, hi) - c).length_squared();
    // rise / gap > threshold, squared; the factor covers the squares' rounding.
    rise * rise * (1.0 + 1e-12) > threshold * threshold * gap_squared
}

/// The exact largest elevation sine from `c` of a point of triangle `tri`, which does not
/// contain `c`.
pub(crate) fn triangle_max_sin(c: DVec3, n: DVec3, tri: &[DVec3; 3]) -> f64 {
    directions_max_sin(n, tri.map(|p| (p - c).normalize()))
}

/// The exact largest `n·u` over the unit directions `u` of a triangle whose corners lie
/// in the unit directions `a`, `b`, `d` from the viewpoint (which it does not contain).
pub(crate) fn directions_max_sin(n: DVec3, corners: [DVec3; 3]) -> f64 {
    polygon_max_sin(n, &corners)
}

/// The exact largest `n·u` over the unit directions `u` of a convex polygon whose
/// corners lie, in order, in the unit directions `dirs` from the viewpoint (which it does
/// not contain): 1 when `n` points into the polygon's cone, else the highest of its edges'
/// arcs. (The maximum of `n·u` over a spherically convex region not holding `n` lies on
/// its boundary.)
#[inline]
pub(crate) fn polygon_max_sin(n: DVec3, dirs: &[DVec3]) -> f64 {
    if normal_in_cone(n, dirs) {
        return 1.0;
    }
    let next = |j: usize| dirs[(j + 1) % dirs.len()];
    (0..dirs.len())
        .map(|j| arc_max_sin(n, dirs[j], next(j)))
        .fold(f64::NEG_INFINITY, f64::max)
}

/// True when `n` is a non-negative combination of the unit vectors `dirs` (the cone of
/// directions of a convex polygon seen from the origin), within rounding; false for a
/// flat cone or fewer than three directions.
fn normal_in_cone(n: DVec3, dirs: &[DVec3]) -> bool {
    if dirs.len() < 3 {
        return false;
    }
    // The fan's volumes share the polygon's orientation; their sum is its sign.
    let volume: f64 = (1..dirs.len() - 1)
        .map(|j| dirs[0].dot(dirs[j].cross(dirs[j + 1])))
        .sum();
    if volume.abs() <= 1e-12 {
        // A flat cone is its edges' arcs, which the caller takes.
        return false;
    }
    let next = |j: usize| dirs[(j + 1) % dirs.len()];
    (0..dirs.len()).all(|j| n.dot(dirs[j].cross(next(j))) * volume.signum() >= -1e-12)
}

/// The largest `n·u` over the unit directions `u` of the segment between the directions
/// of unit vectors `ua` and `ub` (seen from the origin): an end, or the top of the
/// great-circle arc between them. A segment through the origin gives 1.
#[inline]
pub(crate) fn arc_max_sin(n: DVec3, ua: DVec3, ub: DVec3) -> f64 {
    let ends = n.dot(ua).max(n.dot(ub));
    let k = ua.cross(ub);
    let k_len2 = k.length_squared();
    if k_len2 <= 1e-24 {
        // Collinear with the origin: the segment passes through it when the ends point
        // apart, and is a single direction otherwise.
        return if ua.dot(ub) < 0.0 { 1.0 } else { ends };
    }
    // The great circle's top rises √(1 − (n·k̂)²) for a unit `n`. Most arcs are short
    // and their circle's top no higher than their ends; that is settled here without a
    // square root. (For a top within rounding of the ends either answer is theirs.)
    let nk = n.dot(k);
    if ends >= 0.0 && k_len2 * (1.0 - ends * ends) <= nk * nk {
        return ends;
    }
    // The direction of the circle's top, scaled by |k|²: n with its part along k taken
    // away. Whether it lies on the arc does not depend on the scale, so the top's height
    // (a square root) is needed only when it does.
    let m = n * k_len2 - k * nk;
    let within = ua.cross(m).dot(k) >= 0.0 && m.cross(ub).dot(k) >= 0.0;
    if within {
        (m.length() / k_len2).max(ends)
    } else {
        ends
    }
}

/// Distance from `p` to the triangle `tri`: its closest point found by which feature's
/// region (corner, edge or face) `p` falls in, the textbook method (Ericson, *Real-Time
/// Collision Detection*, 5.1.5).
pub(crate) fn distance_to_triangle(p: DVec3, tri: &[DVec3; 3]) -> f64 {
    let [a, b, c] = *tri;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.length();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (p - (a + ab * (d1 / (d1 - d3)))).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (p - (a + ac * (d2 / (d2 - d6)))).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).length();
    }
    let denom = va + vb + vc;
    if denom == 0.0 {
        // A triangle without area (never a caster); no distance is claimed.
        return 0.0;
    }
    let (v, w) = (vb / denom, vc / denom);
    (p - (a + ab * v + ac * w)).length()
}

/// Largest error of [`atan2_within`], radians.
pub(super) const ANGLE_ERROR: f64 = 5e-10;

/// atan2(y, x) in (−π, π] within [`ANGLE_ERROR`], with one division and no call: the
/// lookups' hot path (libm's atan2 and asin took a fifth of a step). The map's build
/// needs no angle: its spans are taken in turns (`pseudo_angle`).
///
/// The ratio r = min/max of |x|, |y| is in [0, 1]; above tan(π/8), atan r = π/4 +
/// atan((r − 1)/(r + 1)). Either way the argument u has |u| ≤ tan(π/8), and the Taylor
/// series of atan u to u¹⁹ leaves at most |u|²¹/21 < 4.4e-10.
#[inline]
pub(super) fn atan2_within(y: f64, x: f64) -> f64 {
    const TAN_PI_8: f64 = 0.414_213_562_373_095_1;
    let (ax, ay) = (x.abs(), y.abs());
    let (small, large) = if ay > ax { (ax, ay) } else { (ay, ax) };
    if large == 0.0 {
        return 0.0;
    }
    let (u, base) = if small > TAN_PI_8 * large {
        ((small - large) / (small + large), FRAC_PI_4)
    } else {
        (small / large, 0.0)
    };
    // Σ (−1)ᵏ u²ᵏ/(2k + 1), k = 0 … 9, by Estrin's scheme: pairs, then pairs of pairs,
    // so that the terms do not wait on one another as in Horner's rule.
    const C: [f64; 10] = [
        1.0,
        -1.0 / 3.0,
        1.0 / 5.0,
        -1.0 / 7.0,
        1.0 / 9.0,
        -1.0 / 11.0,
        1.0 / 13.0,
        -1.0 / 15.0,
        1.0 / 17.0,
        -1.0 / 19.0,
    ];
    let v = u * u;
    let (v2, v4) = (v * v, v * v * v * v);
    let pair = |k: usize| C[k] + C[k + 1] * v;
    let low = pair(0) + v2 * pair(2);
    let high = pair(4) + v2 * pair(6);
    let series = low + v4 * high + v4 * v4 * pair(8);
    let mut angle = base + u * series;
    if ay > ax {
        angle = FRAC_PI_2 - angle;
    }
    if x < 0.0 {
        angle = PI - angle;
    }
    angle.copysign(y)
}

/// A number that orders directions `(cos, sin)` (any length) by their angle in
/// `(−π, π]` as `atan2` does: in `[−1, 1]` on the right half, beyond it on the left
/// (`−2` toward `−π`, `2` at `π`); 0 for the zero vector, as `atan2(0, 0)`.
pub(super) fn pseudo_angle((x, y): (f64, f64)) -> f64 {
    let r = x.abs() + y.abs();
    if r == 0.0 {
        return 0.0;
    }
    let p = y / r;
    match (x >= 0.0, y >= 0.0) {
        (true, _) => p,
        (false, true) => 2.0 - p,
        (false, false) => -2.0 - p,
    }
}

/// An orthonormal tangent basis `(t1, t2)` of the plane with unit normal `n`, with
/// `t1 × t2 = n`; a fixed function of `n` alone (Duff et al. 2017, "Building an
/// orthonormal basis, revisited"), so maps and lookups agree without storing it.
#[inline]
pub fn tangent_frame(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestRng;
    use std::f64::consts::{PI, TAU};

    fn random_point(rng: &mut TestRng, size: f64) -> DVec3 {
        DVec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5) * size
    }

    /// The largest elevation sine over a dense barycentric sampling of the triangle.
    fn sampled_max_sin(c: DVec3, n: DVec3, [a, b, d]: [DVec3; 3], steps: u32) -> f64 {
        let mut best = f64::NEG_INFINITY;
        for i in 0..=steps {
            for j in 0..=steps - i {
                let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                let p = a + (b - a) * u + (d - a) * v;
                best = best.max(n.dot((p - c).normalize()));
            }
        }
        best
    }

    /// Whether the ray `c + t·n` (t > 0) meets the triangle, within 1e-9 of its edges
    /// (Möller and Trumbore's test).
    fn ray_meets(c: DVec3, n: DVec3, [a, b, d]: [DVec3; 3]) -> bool {
        let (e1, e2) = (b - a, d - a);
        let p = n.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-300 {
            return false;
        }
        let s = c - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = n.dot(q) / det;
        let t = e2.dot(q) / det;
        t > 0.0 && u >= -1e-9 && v >= -1e-9 && u + v <= 1.0 + 1e-9
    }

    #[test]
    fn triangle_maximum_bounds_and_matches_a_dense_sampling() {
        let mut rng = TestRng::new(17);
        let (mut interior_tops, mut far) = (0, 0);
        for _ in 0..2000 {
            let c = random_point(&mut rng, 2.0);
            let n = random_point(&mut rng, 2.0).normalize();
            let tri = [0, 1, 2].map(|_| random_point(&mut rng, 4.0));
            if distance_to_triangle(c, &tri) < 0.05 {
                continue;
            }
            let exact = triangle_max_sin(c, n, &tri);
            if exact == 1.0 {
                // Straight up is claimed: the ray from `c` along `n` must meet the triangle.
                interior_tops += 1;
                assert!(
                    ray_meets(c, n, tri),
                    "{c} {n} {tri:?}: sin 1 but the normal misses"
                );
                continue;
            }
            let sampled = sampled_max_sin(c, n, tri, 120);
            // The exact maximum is never below a sampled point; from a distance of at
            // least 0.8 the sampling (steps of at most 0.06) sees the triangle in steps
            // of 0.075 rad, so it comes within (0.075)²/2 of the top.
            assert!(
                exact >= sampled - 1e-12,
                "{c} {n} {tri:?}: {exact} < {sampled}"
            );
            if distance_to_triangle(c, &tri) >= 0.8 {
                far += 1;
                assert!(
                    exact <= sampled + 3e-3,
                    "{c} {n} {tri:?}: {exact} ≫ {sampled}"
                );
            }
        }
        assert!(
            interior_tops > 0,
            "no case had the normal inside the triangle's cone"
        );
        assert!(
            far > 200,
            "too few triangles far enough to compare with the sampling"
        );
    }

    #[test]
    fn the_bounds_cheap_screen_keeps_every_triangle_rising_above_the_threshold() {
        let mut rng = TestRng::new(23);
        let (mut kept, mut screened) = (0, 0);
        for _ in 0..4000 {
            let c = random_point(&mut rng, 2.0);
            let n = random_point(&mut rng, 2.0).normalize();
            let tri = [0, 1, 2].map(|_| random_point(&mut rng, 4.0));
            if distance_to_triangle(c, &tri) < 0.05 {
                continue;
            }
            let threshold = 1.5 * rng.unit() - 0.5;
            let sampled = sampled_max_sin(c, n, tri, 60);
            let bound = triangle_bound(c, n, &tri, 0.0, threshold);
            if sampled > threshold {
                kept += 1;
                assert!(
                    bound >= sampled - 1e-12,
                    "{c} {n} {tri:?}: {bound} below {sampled}, threshold {threshold}"
                );
            } else if bound <= threshold {
                screened += 1;
            }
        }
        // Both ways, often: the screen is no mere pass-through.
        assert!(
            kept > 500 && screened > 500,
            "{kept} kept, {screened} screened"
        );
    }

    #[test]
    fn polygon_maximum_matches_a_dense_sampling() {
        // Convex polygons of 4 to 7 corners (on an ellipse in a random plane, the shapes
        // a triangle clipped to a wedge takes): the computed maximum is never below a
        // sampled point of the polygon, and near the best one.
        let mut rng = TestRng::new(23);
        let mut compared = 0;
        for _ in 0..600 {
            let n = random_point(&mut rng, 2.0).normalize();
            let centre = random_point(&mut rng, 6.0);
            let (e1, e2) = (random_point(&mut rng, 2.0), random_point(&mut rng, 2.0));
            let corners = 4 + (rng.next_u64() % 4) as usize;
            let mut angles: Vec<f64> = (0..corners).map(|_| TAU * rng.unit()).collect();
            angles.sort_by(f64::total_cmp);
            let points: Vec<DVec3> = angles
                .iter()
                .map(|a| centre + e1 * a.cos() + e2 * a.sin())
                .collect();
            let distance = (1..corners - 1)
                .map(|j| distance_to_triangle(DVec3::ZERO, &[points[0], points[j], points[j + 1]]))
                .fold(f64::INFINITY, f64::min);
            if distance < 0.8 {
                continue;
            }
            let dirs: Vec<DVec3> = points.iter().map(|p| p.normalize()).collect();
            let exact = polygon_max_sin(n, &dirs);
            let sampled = (1..corners - 1)
                .map(|j| {
                    sampled_max_sin(DVec3::ZERO, n, [points[0], points[j], points[j + 1]], 120)
                })
                .fold(f64::NEG_INFINITY, f64::max);
            // As for triangles: never below a sample; from 0.8 away with steps of at most
            // about 0.07, within (0.09)²/2 of the top.
            assert!(
                exact >= sampled - 1e-12,
                "{n} {points:?}: {exact} < {sampled}"
            );
            assert!(
                exact <= sampled + 5e-3,
                "{n} {points:?}: {exact} ≫ {sampled}"
            );
            compared += 1;
        }
        assert!(compared > 100, "only {compared} polygons far enough");
    }

    #[test]
    fn distance_to_triangle_matches_a_dense_sampling() {
        let mut rng = TestRng::new(5);
        for _ in 0..500 {
            let p = random_point(&mut rng, 3.0);
            let [a, b, d] = [0, 1, 2].map(|_| random_point(&mut rng, 4.0));
            let mut sampled = f64::INFINITY;
            for i in 0..=100 {
                for j in 0..=100 - i {
                    let (u, v) = (i as f64 / 100.0, j as f64 / 100.0);
                    sampled = sampled.min((a + (b - a) * u + (d - a) * v - p).length());
                }
            }
            let exact = distance_to_triangle(p, &[a, b, d]);
            assert!(
                exact <= sampled + 1e-12 && exact >= sampled - 0.1,
                "{exact} {sampled}"
            );
        }
    }

    #[test]
    fn fast_angles_are_within_their_stated_error() {
        let mut worst: f64 = 0.0;
        let mut check = |y: f64, x: f64| {
            let (fast, exact) = (atan2_within(y, x), y.atan2(x));
            assert!(
                fast.is_finite() && (-PI..=PI).contains(&fast),
                "{y} {x}: {fast}"
            );
            worst = worst.max((fast - exact).abs());
        };
        // Every octant edge and axis, signed zeros, and extreme magnitudes.
        let t8 = (PI / 8.0).tan();
        for (y, x) in [
            (0.0, 1.0),
            (1.0, 0.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 1.0),
            (t8, 1.0),
        ] {
            for (sy, sx) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
                check(sy * y, sx * x);
                check(sy * x, sx * y);
            }
        }
        check(1e-300, 1.0);
        check(1.0, 1e-300);
        check(1e300, -1e300);
        // Dense angles around the circle, on and beside the octant edges.
        for k in 0..2_000_000 {
            let a = -PI + TAU * (k as f64 + 0.5) / 2e6;
            check(a.sin(), a.cos());
            check(3e5 * a.sin(), 3e5 * a.cos());
        }
        assert!(worst <= ANGLE_ERROR, "worst error {worst:e} rad");
        assert_eq!(atan2_within(0.0, 0.0), 0.0);
    }

    #[test]
    fn pseudo_angles_order_turns_as_atan2_does() {
        // Axes, signed zeros, the half-turn and random directions of every size: any two
        // turns are ordered alike by both (ties of `atan2` allowed either way).
        let mut rng = TestRng::new(11);
        let mut turns = vec![
            (1.0, 0.0),
            (0.0, 1.0),
            (-1.0, 0.0),
            (-1.0, -0.0 + 0.0),
            (0.0, -1.0),
            (1.0, -0.0),
            (0.0, 0.0),
            (-1.0, 1e-300),
            (-1.0, -1e-300),
        ];
        turns.extend((0..400).map(|_| {
            let a = TAU * rng.unit() - PI;
            let scale = 10f64.powf(12.0 * rng.unit() - 6.0);
            (scale * a.cos(), scale * a.sin())
        }));
        for &p in &turns {
            for &q in &turns {
                let (ap, aq) = (p.1.atan2(p.0), q.1.atan2(q.0));
                if ap < aq {
                    assert!(pseudo_angle(p) <= pseudo_angle(q), "{p:?} {q:?}");
                }
                if pseudo_angle(p) < pseudo_angle(q) {
                    assert!(ap <= aq, "{p:?} {q:?}");
                }
            }
        }
    }
}
