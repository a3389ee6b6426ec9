//! Form factors between two triangles, accurate from touching to far apart.
//!
//! In: two facets (corners in metres in one frame, unit normals, areas). Out: their
//! exchange area `G = A_i F_ij = A_j F_ji` in m², for facets that see each other (mutual
//! visibility is decided by the caller).
//!
//! Far apart (centroid distance ≥ [`NearField::far_ratio`] × the larger facet's longest
//! edge) the point formula `cos θ_i cos θ_j A_i A_j / (π r²)` is used; its relative error
//! falls as (size/distance)². Closer, the inner integral over the receiving (larger)
//! triangle is exact — Lambert's formula for the form factor from a point to a polygon,
//! the polygon first clipped to the half-space in front of the sending facet's plane —
//! and the outer integral runs over the part of the sending (smaller) triangle in front
//! of the receiver's plane. Clipping both ways leaves an integrand that is smooth up to
//! the piece's edges (it falls linearly to zero at a horizon line instead of breaking
//! there), so the outer integral uses Dunavant's 6-point degree-4 rule, adaptively: a
//! triangle's Gauss value is compared with the sum over its four midpoint children, and
//! children are split again until the two agree to [`NearField::tolerance`] relative to
//! the larger of the children's sum and the triangle's area share of the pair's estimate,
//! or [`NearField::max_depth`] splits are reached. Only pairs closer than [`GAUSS_RATIO`]
//! sizes are split; farther, one Gauss pass over the clipped piece suffices.
//!
//! Between the two, pairs at least [`GAUSS_RATIO`] sizes apart whose triangles lie wholly
//! in front of each other (no horizon cuts either, so the kernel is smooth on both) get a
//! product Gauss rule: the 6-point rule on each triangle, 36 evaluations of the point
//! kernel and no arctangent. Against a 1e-8 adaptive reference on the 12,288-facet
//! Itokawa model its largest relative error is 1e-4 from 3 sizes on, 3e-5 from 4 and
//! 6e-6 from 6.

use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// One facet as the form-factor integrals see it.
#[derive(Debug, Clone, Copy)]
pub struct Facet {
    pub corners: [DVec3; 3],
    pub normal: DVec3,
    pub centroid: DVec3,
    pub area: f64,
    /// Longest edge, metres.
    pub size: f64,
}

impl Facet {
    /// A facet from its corners (counter-clockwise seen from the front).
    pub fn new(corners: [DVec3; 3]) -> Facet {
        let [a, b, c] = corners;
        let cross = (b - a).cross(c - a);
        let twice = cross.length();
        Facet {
            corners,
            normal: if twice > 0.0 {
                cross / twice
            } else {
                DVec3::ZERO
            },
            centroid: (a + b + c) / 3.0,
            area: 0.5 * twice,
            size: (b - a).length().max((c - b).length()).max((a - c).length()),
        }
    }
}

/// When and how finely the near-field integral is used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearField {
    /// Pairs closer than this many facet sizes get the exact-inner, adaptive-outer integral.
    pub far_ratio: f64,
    /// Adaptive-outer stopping tolerance, relative to the pair's exchange area: a
    /// triangle is not split when its Gauss value and its children's sum agree to this.
    pub tolerance: f64,
    /// Most splits of the outer facet (4^depth sub-triangles at most).
    pub max_depth: u32,
}

impl Default for NearField {
    /// Point formula beyond 16 sizes, splits to 3e-4 relative, at most 3 splits (64
    /// sub-triangles): rows of a 1,280-facet sphere interior then sum to 1 within 3.5e-7,
    /// and Howell's catalogue cases (tests/scatter.rs) come within 1.9e-4. The point
    /// formula from 8 sizes on instead leaves 1.2e-3 in the sphere's rows
    /// (docs/accuracy.md).
    fn default() -> Self {
        NearField {
            far_ratio: crate::scene::DEFAULT_NEAR_FIELD_RATIO,
            tolerance: 3e-4,
            max_depth: 3,
        }
    }
}

/// Pairs closer than [`NearField::far_ratio`] but at least this many facet sizes apart,
/// wholly in front of each other, get the product Gauss rule (module doc).
pub const GAUSS_RATIO: f64 = 3.0;

/// Exchange area `A_i F_ij` (m²) of two facets assumed mutually visible.
pub fn exchange_area(a: &Facet, b: &Facet, near: &NearField) -> f64 {
    let r = b.centroid - a.centroid;
    let d2 = r.length_squared();
    let size = a.size.max(b.size);
    if d2 >= (near.far_ratio * size).powi(2) {
        return point_kernel(a.normal, b.normal, r) * a.area * b.area;
    }
    let mid_range = d2 >= (GAUSS_RATIO * size).powi(2);
    if mid_range && wholly_in_front(a, b) && wholly_in_front(b, a) {
        return gauss_product(a, b);
    }
    // From GAUSS_RATIO sizes on, the integrand over the clipped outer facet is smooth:
    // one Gauss pass, no splits.
    adaptive(
        a,
        b,
        near.tolerance,
        if mid_range { 0 } else { near.max_depth },
    )
}

/// Exact inner integral over the larger facet, adaptive outer (relative `tolerance`, at
/// most `depth` splits) over the part of the smaller facet in front of the larger one's
/// plane.
fn adaptive(a: &Facet, b: &Facet, tolerance: f64, depth: u32) -> f64 {
    let (outer, inner) = if a.area <= b.area { (a, b) } else { (b, a) };
    // The part of the outer facet behind the inner one's plane sees none of it: clipping
    // it off leaves an integrand that is smooth up to the pieces' edges.
    let mut piece = [DVec3::ZERO; 4];
    let count = clip_in_front(&outer.corners, inner.centroid, inner.normal, &mut piece);
    // Every outer point shares the outer plane, so the inner facet's part in front of
    // them is the same polygon for all of them.
    let mut seen = [DVec3::ZERO; 4];
    let seen_count = clip_in_front(&inner.corners, outer.centroid, outer.normal, &mut seen);
    if count < 3 || seen_count < 3 {
        return 0.0;
    }
    let mut quad = Quadrature {
        n: outer.normal,
        inner,
        seen: &seen[..seen_count],
        per_area: 0.0,
        rel: tolerance,
        // Contributions this small (in units of the outer area) are not worth a split.
        floor: 1e-12 * outer.area,
    };
    let fan = [
        [piece[0], piece[1], piece[2]],
        [piece[0], piece[2], piece[3]],
    ];
    let fan = &fan[..count - 2];
    let first = [0, 1].map(|k| fan.get(k).map_or(0.0, |&t| quad.gauss(t)));
    quad.per_area = tolerance * (first[0] + first[1]) / outer.area;
    fan.iter()
        .zip(first)
        .map(|(&t, whole)| quad.refine(t, whole, depth))
        .sum()
}

/// `cos θ_a cos θ_b / (π r²)` for points with normals `na`, `nb` joined by `r` (a → b),
/// zero when either is behind the other.
#[inline]
fn point_kernel(na: DVec3, nb: DVec3, r: DVec3) -> f64 {
    let d2 = r.length_squared();
    let cos_a = na.dot(r).max(0.0);
    let cos_b = (-nb.dot(r)).max(0.0);
    // cos θ = n·r/|r| on both sides: |r|⁴ in the denominator.
    cos_a * cos_b / (PI * d2 * d2)
}

/// Every corner of `b` strictly in front of `a`'s plane.
fn wholly_in_front(a: &Facet, b: &Facet) -> bool {
    b.corners
        .iter()
        .all(|&p| a.normal.dot(p - a.centroid) > 0.0)
}

/// Dunavant's symmetric 6-point rule, exact for polynomials of degree 4 on a triangle:
/// (barycentric coordinates, weight), weights summing to 1.
const DUNAVANT_6: [([f64; 3], f64); 6] = {
    const A1: f64 = 0.816_847_572_980_459;
    const B1: f64 = 0.091_576_213_509_771;
    const W1: f64 = 0.109_951_743_655_322;
    const A2: f64 = 0.108_103_018_168_070;
    const B2: f64 = 0.445_948_490_915_965;
    const W2: f64 = 0.223_381_589_678_011;
    [
        ([A1, B1, B1], W1),
        ([B1, A1, B1], W1),
        ([B1, B1, A1], W1),
        ([A2, B2, B2], W2),
        ([B2, A2, B2], W2),
        ([B2, B2, A2], W2),
    ]
};

/// The exchange area by the product of [`DUNAVANT_6`] on both facets.
fn gauss_product(a: &Facet, b: &Facet) -> f64 {
    let nodes = |f: &Facet| {
        DUNAVANT_6.map(|(w, _)| f.corners[0] * w[0] + f.corners[1] * w[1] + f.corners[2] * w[2])
    };
    let (pa, pb) = (nodes(a), nodes(b));
    let mut sum = 0.0;
    for (x, (_, wx)) in pa.iter().zip(DUNAVANT_6) {
        let inner: f64 = pb
            .iter()
            .zip(DUNAVANT_6)
            .map(|(&y, (_, wy))| wy * point_kernel(a.normal, b.normal, y - *x))
            .sum();
        sum += wx * inner;
    }
    sum * a.area * b.area
}

/// The adaptive outer integral over one facet of the form factor to `inner`.
struct Quadrature<'a> {
    /// The outer facet's normal.
    n: DVec3,
    inner: &'a Facet,
    /// The part of `inner` in front of the outer facet's plane.
    seen: &'a [DVec3],
    rel: f64,
    /// The pair's error budget per unit area of the outer facet (m² of exchange area per
    /// m²): `rel ×` the pair's estimate / the outer area.
    per_area: f64,
    floor: f64,
}

impl Quadrature<'_> {
    /// [`DUNAVANT_6`] over `tri` of the point-to-inner form factor, times its area.
    fn gauss(&self, tri: [DVec3; 3]) -> f64 {
        let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length();
        let sum: f64 = DUNAVANT_6
            .iter()
            .map(|&(w, weight)| {
                let x = tri[0] * w[0] + tri[1] * w[1] + tri[2] * w[2];
                weight * self.point_to_inner(x)
            })
            .sum();
        area * sum
    }

    /// The form factor from outer point `x` to the inner facet.
    fn point_to_inner(&self, x: DVec3) -> f64 {
        if self.inner.normal.dot(x - self.inner.centroid) <= 0.0 {
            return 0.0;
        }
        lambert_polygon(x, self.n, self.seen)
    }

    /// The integral over `tri`, whose Gauss value is `whole`: accepted when the sum over
    /// its four midpoint children agrees with it to `rel` of the larger of that sum and
    /// its area's share of the pair's estimate, else each child is refined in turn, at
    /// most `depth` more times. Sub-triangles that add little to the pair (along the
    /// shared edge or horizon line, where the integrand is least smooth) stop early, and
    /// the pair's error stays below about `rel × (pair + estimate)`.
    fn refine(&self, tri: [DVec3; 3], whole: f64, depth: u32) -> f64 {
        if depth == 0 {
            return whole;
        }
        let children = split4(tri);
        let parts = children.map(|c| self.gauss(c));
        let sum: f64 = parts.iter().sum();
        let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length();
        let allowed = (self.rel * sum).max(self.per_area * area) + self.floor;
        if (sum - whole).abs() <= allowed {
            return sum;
        }
        children
            .iter()
            .zip(parts)
            .map(|(&c, p)| self.refine(c, p, depth - 1))
            .sum()
    }
}

/// The four midpoint children of a triangle.
fn split4([a, b, c]: [DVec3; 3]) -> [[DVec3; 3]; 4] {
    let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
}

/// Lambert's formula: the form factor from a differential area at `x` (unit normal `n`)
/// to the polygon `poly` lying in front of it, `(1/2π) Σ γ_k n·(a_k × a_{k+1})/|a_k × a_{k+1}|`
/// with `a_k` the vectors from `x` to the vertices and `γ_k` the angle between consecutive
/// ones. The sign depends on the polygon's winding; the magnitude is the form factor.
pub fn lambert_polygon(x: DVec3, n: DVec3, poly: &[DVec3]) -> f64 {
    let mut sum = 0.0;
    for k in 0..poly.len() {
        let a = poly[k] - x;
        let b = poly[(k + 1) % poly.len()] - x;
        let cross = a.cross(b);
        let sin = cross.length();
        if sin > 0.0 {
            sum += angle(sin, a.dot(b)) * n.dot(cross) / sin;
        }
    }
    (sum / (2.0 * PI)).abs()
}

/// The form factor from a differential area at `x` (unit normal `n`) to the triangle
/// `tri`: Lambert's formula over the part of it in front of the area's plane (what lies
/// behind sends it nothing).
pub fn point_to_triangle(x: DVec3, n: DVec3, tri: &[DVec3; 3]) -> f64 {
    let mut front = [DVec3::ZERO; 4];
    match clip_in_front(tri, x, n, &mut front) {
        count @ 3.. => lambert_polygon(x, n, &front[..count]),
        _ => 0.0,
    }
}

/// The angle in [0, π] whose sine and cosine are proportional to `sin` (> 0) and `cos`:
/// `sin.atan2(cos)` to within 1e-12 rad, without a call into libm (the near field
/// evaluates it about 10⁸ times for a 50,000-facet body). The argument is reduced to [0, tan π/8], where
/// `atan(x)/x` is a degree-7 polynomial in x² (least squares on Chebyshev nodes, largest
/// error 3e-13).
#[inline]
fn angle(sin: f64, cos: f64) -> f64 {
    const P: [f64; 8] = [
        9.999_999_999_992_706e-1,
        -3.333_333_327_838_434e-1,
        1.999_999_318_889_491e-1,
        -1.428_539_126_020_617e-1,
        1.110_353_493_587_36e-1,
        -8.993_217_497_112_789e-2,
        6.977_006_340_284_059e-2,
        -3.770_175_923_250_445e-2,
    ];
    const TAN_PI_8: f64 = 0.414_213_562_373_095_03;
    let c = cos.abs();
    let x = sin.min(c) / sin.max(c);
    let (y, base) = if x > TAN_PI_8 {
        ((x - 1.0) / (x + 1.0), FRAC_PI_4)
    } else {
        (x, 0.0)
    };
    let u = y * y;
    let poly = P.iter().rev().fold(0.0, |acc, &p| acc * u + p);
    let mut r = base + y * poly;
    if sin > c {
        r = FRAC_PI_2 - r;
    }
    if cos < 0.0 {
        r = PI - r;
    }
    r
}

/// Sutherland–Hodgman clip of a triangle to the half-space `n·(p − x) ≥ 0`; writes the
/// polygon (at most four corners) into `out` and returns its corner count.
fn clip_in_front(tri: &[DVec3; 3], x: DVec3, n: DVec3, out: &mut [DVec3; 4]) -> usize {
    let h = tri.map(|p| n.dot(p - x));
    let mut count = 0;
    for k in 0..3 {
        let (p, q) = (tri[k], tri[(k + 1) % 3]);
        let (hp, hq) = (h[k], h[(k + 1) % 3]);
        if hp >= 0.0 {
            out[count] = p;
            count += 1;
        }
        if (hp >= 0.0) != (hq >= 0.0) {
            out[count] = p + (q - p) * (hp / (hp - hq));
            count += 1;
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_below_the_centre_of_a_disc_like_square() {
        // A unit square 1 above a point facing it: F = 0.2394 (Howell catalogue B-3 as the
        // limit of a differential element below the corner, ×4 by symmetry: 4 × 0.05985).
        let sq = [
            DVec3::new(-0.5, -0.5, 1.0),
            DVec3::new(0.5, -0.5, 1.0),
            DVec3::new(0.5, 0.5, 1.0),
            DVec3::new(-0.5, 0.5, 1.0),
        ];
        let f = lambert_polygon(DVec3::ZERO, DVec3::Z, &sq);
        // Closed form for a corner element: (1/2π)[A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²)
        // atan(A/√(1+B²))] with A = B = 0.5.
        let s = (1.0f64 + 0.25).sqrt();
        let corner = (2.0 * 0.5 / s * (0.5 / s).atan()) / (2.0 * PI);
        assert!((f - 4.0 * corner).abs() < 1e-14, "{f} vs {}", 4.0 * corner);
    }

    /// A unit-sized triangle in the plane z = 0, facing +z.
    fn base_facet() -> Facet {
        Facet::new([
            DVec3::ZERO,
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.3, 0.9, 0.0),
        ])
    }

    /// The default exchange area of `a` and `b` relative to the exact-inner rule split to
    /// 1e-9, less one.
    fn error_against_fine_split(a: &Facet, b: &Facet) -> f64 {
        let reference = adaptive(a, b, 1e-9, 9);
        assert!(reference > 0.0);
        exchange_area(a, b, &NearField::default()) / reference - 1.0
    }

    #[test]
    fn gauss_product_matches_the_exact_integral_from_three_sizes() {
        // A tilted pair 3 sizes apart, wholly in front of each other: the product rule.
        let a = base_facet();
        let b = Facet::new([
            DVec3::new(0.2, 0.1, 3.0),
            DVec3::new(0.5, 1.0, 3.4),
            DVec3::new(1.1, 0.0, 3.2),
        ]);
        assert!(wholly_in_front(&a, &b) && wholly_in_front(&b, &a));
        let error = error_against_fine_split(&a, &b);
        assert!(error.abs() < 1e-4, "{error}");
    }

    #[test]
    fn one_gauss_pass_suffices_for_a_horizon_cut_pair_from_three_sizes() {
        // The plane of `a` cuts `b`: one Gauss pass over the clipped outer facet.
        let a = base_facet();
        let b = Facet::new([
            DVec3::new(5.0, 0.0, -0.3),
            DVec3::new(5.1, -0.2, 0.8),
            DVec3::new(5.0, 0.9, 0.6),
        ]);
        assert!(!wholly_in_front(&a, &b) && wholly_in_front(&b, &a));
        assert!((b.centroid - a.centroid).length() > GAUSS_RATIO * a.size.max(b.size));
        let error = error_against_fine_split(&a, &b);
        assert!(error.abs() < 1e-4, "{error}");
    }

    #[test]
    fn fast_angle_matches_atan2() {
        let mut worst: f64 = 0.0;
        for i in 1..=2000 {
            let theta = PI * i as f64 / 2001.0;
            for scale in [1e-300, 1e-3, 1.0, 7e5] {
                let (s, c) = (scale * theta.sin(), scale * theta.cos());
                worst = worst.max((angle(s, c) - s.atan2(c)).abs());
            }
        }
        // Exactly along the axes, and a sine far below the cosine.
        for (s, c) in [
            (1.0, 0.0),
            (1.0, 1.0),
            (1e-20, 1.0),
            (1e-20, -1.0),
            (2.0, -1e-30),
        ] {
            worst = worst.max((angle(s, c) - f64::atan2(s, c)).abs());
        }
        assert!(worst < 1e-12, "{worst}");
    }

    #[test]
    fn clipping_keeps_only_the_part_in_front() {
        let tri = [
            DVec3::new(0.0, 0.0, -1.0),
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(0.0, 1.0, 1.0),
        ];
        let mut out = [DVec3::ZERO; 4];
        let n = clip_in_front(&tri, DVec3::ZERO, DVec3::Z, &mut out);
        assert_eq!(n, 4);
        assert!(out[..n].iter().all(|p| p.z >= 0.0));
    }
}
