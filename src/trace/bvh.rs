//! A bounding-volume hierarchy for rays in any direction: the segment any-hit query that
//! facet-to-facet visibility needs, the shadow rays of the `bvh` tracer, and a branch and
//! bound over its boxes (the horizon bound's search).
//!
//! In: a mesh (metres, body frame). Out: [`Bvh::segment_blocked`] — whether the open
//! segment from `a` to `b` crosses a facet other than the (up to two) facets it joins;
//! as a [`Tracer`], whether a ray toward the Sun is blocked (a segment reaching past the
//! tree); the branch and bound (`Bvh::search`); the facets a cone of directions may
//! reach (`Bvh::near_cone`), from which a ray within the cone is answered without the
//! tree (`BvhRays::blocked_among`).
//! The hit decision is the shared exact predicate of [`super::ray`] evaluated in the frame
//! of the segment's direction, so a segment is classified exactly as a shadow ray of the
//! other tracers would be. The tree is built with the binned surface-area heuristic;
//! leaves hold at most `LEAF_SIZE` facets. The tree borrows the mesh, whose `f64`
//! facets the exact tests read; it keeps only its `f32` boxes and leaf screens (their
//! edge planes in `i16`, measured from each leaf's centre, so that a screen's tolerance
//! is the `f32` crossing point's own error, millimetres on a body of hundreds of metres).
//! For traversal the binary tree is collapsed into one of four children per node, whose
//! boxes are stored in `f32` by axis (one child per SIMD lane), relative to the mesh's
//! centre and rounded outward with a margin far above `f32` rounding, so the box tests
//! can only let through more, never fewer, segments than exact ones would; facets are
//! then screened in `f32` and tested in `f64`.

use super::ray::{inside, DepthPlane, RayFrame};
use super::{caster_facets, casts_shadows, Blocker, ShadowQuery, ShadowRay, Tracer, WALK_FACETS};
use crate::mesh::inspect::NO_NEIGHBOUR;
use crate::mesh::Mesh;
use glam::{BVec4A, DVec3, Vec3, Vec4};

/// Most facets in a leaf: one per lane of its [`Leaf`] screen.
const LEAF_SIZE: usize = 4;

/// Nodes below this depth are split at the median instead of by the surface-area
/// heuristic, which on strongly clustered facets can peel off a few at a time; the tree
/// is then at most `SAH_DEPTH + 31` levels deep for any `u32` facet count.
const SAH_DEPTH: u32 = 32;

/// Room on the traversal stack: a quad pushes at most four children having popped
/// itself, so three more per level of the (binary) tree.
const STACK: usize = 3 * (SAH_DEPTH as usize + 31) + 1;

/// One node while building: a box and either two children (`count == 0`, children at
/// `first` and `first + 1`) or a run of `count` facets starting at `first` in the facet
/// order.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    first: u32,
    count: u32,
}

/// The facets of one leaf as the quick screen sees them (relative to the tree's centre,
/// one facet per lane): their planes `n·x = d` by component in `f32` and, per edge, the
/// inward unit vector in the plane perpendicular to it with its offset, in [`EdgeRows`].
/// An unused lane has a zero normal and `d = -∞`: every point lies infinitely far in
/// front of it.
#[derive(Debug, Clone, Copy)]
struct Leaf {
    plane: [Vec4; 4],
    edges: [EdgeRows; 3],
    /// Mesh facet ids, per lane (`u32::MAX` for an unused one).
    ids: [u32; 4],
}

/// One edge plane per lane, measured from its leaf's [`LeafFrame`] and quantised to
/// `i16`: the normal's components in units of `1/EDGE_UNITS`, the offset in units of
/// `2·half/EDGE_UNITS` (`half` the frame's, which bounds every corner's coordinates about
/// its origin, so `|d| ≤ √3·half` fits). Rounding moves a height at a point `p` (from
/// the origin) by at most `|Δn|·|p| + |Δd|`, under `2.7e-5·|p| + 3.1e-5·half`. The edge
/// planes only ever decide that a crossing lies outside a facet, which lies within
/// `√3·half` of the origin: a crossing within the screen's tolerance of it is within
/// `1.8·half` plus that tolerance, where the error is under `8e-5·half` (the frame's
/// `slack`) and 2.7e-5 of the tolerance. At 96 bytes instead of 192, a leaf is 176
/// bytes, which brings the tree under Embree's BVH in memory.
#[derive(Debug, Clone, Copy)]
struct EdgeRows([[i16; 4]; 4]);

/// Quantisation steps per unit of an [`EdgeRows`] normal component (and per `2·half`
/// of its offset).
const EDGE_UNITS: f64 = i16::MAX as f64;

impl EdgeRows {
    /// The plane of unit normal `n` through `p` (metres from the frame's origin, each
    /// coordinate within `half` of it) in lane `lane`.
    fn put(&mut self, lane: usize, n: DVec3, p: DVec3, half: f64) {
        let quantise = |x: f64| (x * EDGE_UNITS).round().clamp(-EDGE_UNITS, EDGE_UNITS) as i16;
        for (k, v) in n.to_array().into_iter().enumerate() {
            self.0[k][lane] = quantise(v);
        }
        self.0[3][lane] = quantise(n.dot(p) / (2.0 * half).max(f64::MIN_POSITIVE));
    }

    /// The planes' heights at `p` (from the frame's origin), in lanes, in units of
    /// `1/EDGE_UNITS` metres, with the offset's unit (`2·half`) given.
    #[inline(always)]
    fn scaled_height(&self, p: &[Vec4; 3], offset_unit: Vec4) -> Vec4 {
        let [x, y, z, d] = self.0.map(|row| Vec4::from_array(row.map(f32::from)));
        x * p[0] + y * p[1] + z * p[2] - d * offset_unit
    }
}

/// Where a leaf's edge planes are measured from: the centre of the leaf's box as its
/// parent [`Quad`] holds it (metres from the tree's centre) and half the box's longest
/// side, in all four lanes. Measured from the tree's centre instead, the quantised
/// normals would err by 2.7e-5 of the distance to it, a tolerance of the tree's size
/// rather than the leaf's. Read from the quad at every visit, by the same `f32`
/// operations as at the build, the frame costs the leaf no memory.
#[derive(Debug, Clone, Copy)]
struct LeafFrame {
    origin: [Vec4; 3],
    /// The unit of the edge planes' offsets, `2·half` (m).
    offset_unit: Vec4,
    /// What quantising the edge planes may move a height by at a crossing near the
    /// facets (m): `1e-4·half`, over the `8e-5·half` of [`EdgeRows`].
    slack: Vec4,
}

impl LeafFrame {
    /// The frame of the leaf in `quad`'s lane `lane`. The boxes' margin (1e-5 of the
    /// tree's reach) keeps `half` over 80 times the rounding of the centre, so that every
    /// corner lies within `1.01·√3·half` of the origin.
    #[inline]
    fn of(quad: &Quad, lane: usize) -> LeafFrame {
        let (lo, hi) = (quad.lo.map(|v| v[lane]), quad.hi.map(|v| v[lane]));
        let half = (0..3).fold(0.0f32, |h, k| h.max((hi[k] - lo[k]) * 0.5));
        LeafFrame {
            origin: [0, 1, 2].map(|k| Vec4::splat((lo[k] + hi[k]) * 0.5)),
            offset_unit: Vec4::splat(2.0 * half),
            slack: Vec4::splat(1e-4 * half),
        }
    }

    /// The origin (metres from the tree's centre) and `half`, in `f64`.
    fn origin_and_half(&self) -> (DVec3, f64) {
        let origin = DVec3::from_array(self.origin.map(|v| v.x as f64));
        (origin, self.offset_unit.x as f64 / 2.0)
    }
}

impl Leaf {
    /// The leaf over facets `ids` of a tree centred on `centre` whose quad gives it the
    /// frame `frame`.
    fn new(mesh: &Mesh, ids: &[u32], centre: DVec3, frame: &LeafFrame) -> Leaf {
        let (origin, half) = frame.origin_and_half();
        let mut leaf = Leaf {
            plane: [Vec4::ZERO, Vec4::ZERO, Vec4::ZERO, Vec4::NEG_INFINITY],
            edges: [EdgeRows([[0; 4]; 4]); 3],
            ids: [u32::MAX; 4],
        };
        for (lane, &id) in ids.iter().enumerate() {
            let (corners, normal) = (mesh.corners(id as usize), mesh.normals[id as usize]);
            let n32 = normal.as_vec3();
            for (k, v) in n32.to_array().into_iter().enumerate() {
                leaf.plane[k][lane] = v;
            }
            leaf.plane[3][lane] = n32.as_dvec3().dot(corners[0] - centre) as f32;
            for (k, rows) in leaf.edges.iter_mut().enumerate() {
                let edge = corners[(k + 1) % 3] - corners[k];
                let inward = normal.cross(edge).normalize_or_zero();
                rows.put(lane, inward, corners[k] - centre - origin, half);
            }
            leaf.ids[lane] = id;
        }
        leaf
    }

    /// Bit `k` clear when the segment clearly misses facet `k`: both ends lie on one side
    /// of its plane by more than the segment's `slack`, or it crosses the plane (at an
    /// angle of at least 0.01 rad) farther outside an edge than the crossing point's
    /// error ([`Screened`]) and the edge planes' (`frame.slack`). A set bit leaves the
    /// decision to the exact predicate.
    #[inline]
    fn may_cross(&self, s: &Screened, frame: &LeafFrame) -> u32 {
        self.may_meet(s, frame, None)
    }

    /// As [`Leaf::may_cross`] for the cone of directions around the segment `s` from its
    /// apex (its axis, of length `spread.length`): bit `k` clear when no point of the
    /// cone comes near facet `k`.
    ///
    /// A point of the cone is `a + t·d + r`, `d` the unit axis, `0 ≤ t ≤ T` and
    /// `|r| ≤ t·tan h` across it. Its height above a plane (unit normal `n`) is the
    /// axis's, `sa + t·n·d`, within `t·tan h`: so the cone lies on one side when the apex
    /// does and the far end does by the cone's radius there (`grow = T·tan h`) more.
    /// Where the cone meets the plane, `n·r = −(sa + t·n·d)` puts the point within
    /// `t·tan h·(1 + 1/|n·d|)` of the axis's crossing `t*`, and `t ≤ t*/(1 − tan h/|n·d|)`:
    /// the crossing widened by that much more than a ray's tolerance (the axis steeper
    /// than twice the cone's slope, so that the division stays well away from zero). The
    /// widening falls as `|n·d|` grows, so it is taken at the steepness less its error.
    #[inline]
    fn may_reach(&self, s: &Screened, frame: &LeafFrame, spread: &Spread) -> u32 {
        self.may_meet(s, frame, Some(spread))
    }

    /// [`Leaf::may_cross`] and [`Leaf::may_reach`]: a segment is a cone without spread.
    #[inline(always)]
    fn may_meet(&self, s: &Screened, frame: &LeafFrame, spread: Option<&Spread>) -> u32 {
        let height =
            |p: &[Vec4; 3], [x, y, z, d]: &[Vec4; 4]| *x * p[0] + *y * p[1] + *z * p[2] - *d;
        let (sa, sb) = (height(&s.a, &self.plane), height(&s.b, &self.plane));
        // The far end's lowest and highest height over the cone's cross-section there.
        let (sb_low, sb_high) = match spread {
            None => (sb, sb),
            Some(c) => (sb - c.grow, sb + c.grow),
        };
        let one_side = (sa.cmpgt(s.slack) & sb_low.cmpgt(s.slack))
            | (sa.cmplt(-s.slack) & sb_high.cmplt(-s.slack));
        let rise = sa - sb;
        let steepness = rise.abs();
        let steep = steepness.cmpgt(s.steep);
        let per_rise = Vec4::ONE / rise;
        let t = sa * per_rise;
        let p = [0, 1, 2].map(|k| s.a[k] + s.d[k] * t - frame.origin[k]);
        let mut tolerance = s.reach + frame.slack + s.crossing * per_rise.abs();
        if let Some(c) = spread {
            let low = steepness - s.rise_error;
            tolerance += t.max(Vec4::ZERO) * c.grow * (low + c.length) / (low - c.grow);
        }
        let scaled_tolerance = tolerance * EDGE_UNITS as f32;
        let outside = self.edges.iter().fold(BVec4A::splat(false), |out, e| {
            out | e
                .scaled_height(&p, frame.offset_unit)
                .cmplt(-scaled_tolerance)
        });
        (!(one_side | (steep & outside))).bitmask()
    }
}

/// How a cone of directions widens a [`Screened`] segment along its axis, in all four
/// lanes: its radius at the segment's far end (`grow`, m) and the segment's length.
struct Spread {
    grow: Vec4,
    length: Vec4,
}

/// A segment's ends as the screen sees them, with its tolerances, each in all four lanes.
///
/// Where the screen puts a crossing, and how far off it may be: the ends `a`, `b` and the
/// leaves' planes are `f32`, within the segment's `scale` of the tree's centre (each
/// coordinate; corners within the tree's reach), so a plane's height at an end errs by
/// at most `ε_h ≈ 9·2⁻²³·scale` (the ends' and the plane's rounding, three products and
/// three sums: 1.1e-6 of the scale). The crossing's parameter `t = sa/(sa − sb)` then
/// errs from the true one by `(ha·eb − hb·ea)/(rise·rise')`, at most `ε_h/|rise|` for a
/// crossing between the ends (where `|ha| + |hb| = |rise'|`): the crossing point errs by
/// `ε_h·|b − a|/|rise|`, `ε_h` over the sine of the crossing angle. The point's own
/// arithmetic adds under 1e-6 of the scale. So a facet is screened out only when the
/// crossing lies farther outside it than `reach + crossing/|rise|` (and the edge
/// planes' allowance): one to a few millimetres on Itokawa (whose tree reaches 270 m),
/// where one of 3e-4 of the scale (8 cm) had let the rays passing within a quarter of a
/// facet's side of it through to the exact test at 3 million facets.
struct Screened {
    /// The ends and `b - a`, by axis.
    a: [Vec4; 3],
    b: [Vec4; 3],
    d: [Vec4; 3],
    /// Plane heights within this of zero count as either side (m): about 10× `ε_h`.
    slack: Vec4,
    /// Crossings within this outside an edge count as inside (m), whatever the angle:
    /// 3e-6 of the scale, three times the rounding of the crossing point's arithmetic.
    reach: Vec4,
    /// Over `|rise|`, the further tolerance for the crossing point's error (m²): for a
    /// segment `2·ε_h` times its length, `ε_h` taken as [`HEIGHT_ERROR`] of the scale.
    /// For a cone four times that: its axis's true crossing may lie up to half its
    /// length past the far end (then `|ha| + |hb| ≤ 2·|rise'|`), and its widening grows
    /// with the crossing's parameter by up to twice the point's error again.
    crossing: Vec4,
    /// What the difference of the two ends' heights may err by (m): `2·ε_h`.
    rise_error: Vec4,
    /// Differences of the two ends' heights above this (0.01 × the length) mean a
    /// crossing angle of at least 0.01 rad; kept above twice `rise_error`, so that a
    /// segment judged steep is not one lying in the plane (a short one, under 6e-4 of
    /// the scale).
    steep: Vec4,
}

/// `ε_h`, the bound on a plane height's `f32` error at either end of a [`Screened`]
/// segment, relative to its scale, rounded up from 1.1e-6.
const HEIGHT_ERROR: f32 = 1.5e-6;

impl Screened {
    fn new(a: DVec3, b: DVec3, centre: DVec3, tree_reach: f64) -> Screened {
        let (a, b) = (a - centre, b - centre);
        let scale = tree_reach
            .max(a.abs().max_element())
            .max(b.abs().max_element()) as f32;
        let (a32, b32) = (a.as_vec3(), b.as_vec3());
        let length = (b - a).length() as f32;
        Screened {
            a: a32.to_array().map(Vec4::splat),
            b: b32.to_array().map(Vec4::splat),
            d: (b32 - a32).to_array().map(Vec4::splat),
            slack: Vec4::splat(1e-5 * scale),
            reach: Vec4::splat(3e-6 * scale),
            crossing: Vec4::splat(2.0 * HEIGHT_ERROR * scale * length),
            rise_error: Vec4::splat(2.0 * HEIGHT_ERROR * scale),
            steep: Vec4::splat((0.01 * length).max(4.0 * HEIGHT_ERROR * scale)),
        }
    }
}

/// One node as traversed: the boxes of up to four children (metres from the tree's
/// centre, one child per lane, by axis) and, per child, the index of its [`Leaf`] (with
/// [`LEAF_BIT`] set) or of its own node. An unused lane has its box at +∞ on every axis,
/// which no segment reaches.
#[derive(Debug, Clone, Copy)]
struct Quad {
    lo: [Vec4; 3],
    hi: [Vec4; 3],
    child: [u32; 4],
}

/// Marks a [`Quad`]'s child as a leaf; the flag lives in the index so that a quad fills
/// seven 16-byte rows, not eight.
const LEAF_BIT: u32 = 1 << 31;

/// What a [`Quad`]'s lane leads to.
enum Child {
    Node(u32),
    Leaf(u32),
}

impl Quad {
    /// Bit `k` set when child `k` is a leaf.
    #[inline]
    fn leaf_lanes(&self) -> u32 {
        (0..4).fold(0, |m, k| {
            m | (u32::from(self.child[k] & LEAF_BIT != 0) << k)
        })
    }

    #[inline]
    fn child(&self, lane: usize) -> Child {
        match self.child[lane] {
            c if c & LEAF_BIT != 0 => Child::Leaf(c & !LEAF_BIT),
            c => Child::Node(c),
        }
    }
}

/// A BVH over one mesh's facets of non-zero area. The exact tests read the facets from
/// the mesh itself, which the tree borrows rather than copies.
pub struct Bvh<'m> {
    mesh: &'m Mesh,
    /// The root's children at index 0 (absent for a mesh without facets).
    quads: Vec<Quad>,
    leaves: Vec<Leaf>,
    /// Origin of the boxes' coordinates (m, mesh frame).
    centre: DVec3,
    /// Radius of a sphere about `centre` holding every facet (m).
    radius: f64,
    /// Half the root box's longest side (m).
    reach: f64,
    /// The side of a square of a facet's mean area (m).
    facet_size: f64,
}

impl<'m> Bvh<'m> {
    /// Builds the tree.
    pub fn build(mesh: &'m Mesh) -> Bvh<'m> {
        let mut facets = caster_facets(mesh);
        let mut nodes = Vec::with_capacity(2 * facets.len() / LEAF_SIZE + 1);
        if !facets.is_empty() {
            nodes.push(leaf(mesh, &facets, 0));
            split(mesh, &mut nodes, &mut facets, 0, 0);
        }
        let (centre, reach) = match nodes.first() {
            Some(root) => {
                let centre = (root.lo + root.hi) * 0.5;
                (centre, (root.hi - centre).max_element())
            }
            None => (DVec3::ZERO, 0.0),
        };
        let (quads, runs) = quads(&nodes, centre, BOX_MARGIN * reach as f32);
        let leaves = runs
            .iter()
            .map(|&(first, count, ref frame)| {
                Leaf::new(
                    mesh,
                    &facets[first as usize..(first + count) as usize],
                    centre,
                    frame,
                )
            })
            .collect();
        Bvh {
            mesh,
            quads,
            leaves,
            centre,
            radius: 2.0 * reach,
            reach,
            facet_size: (mesh.areas.iter().sum::<f64>() / mesh.len().max(1) as f64).sqrt(),
        }
    }

    /// True if a facet other than those in `skip` crosses the segment `a → b` (mesh frame,
    /// metres) farther than `margin` from both ends.
    pub fn segment_blocked(&self, a: DVec3, b: DVec3, skip: [u32; 2], margin: f64) -> bool {
        self.segment(a, b, skip, margin)
            .is_some_and(|segment| self.blocker_of(&segment).is_some())
    }

    /// The first facet found that blocks the segment, if any.
    fn blocker_of(&self, segment: &Segment) -> Option<u32> {
        let mut found = None;
        self.walk(
            |quad| segment.slab.hits(quad),
            |_, leaf, frame| {
                found = self.leaf_blocker(leaf, frame, segment);
                found.is_some()
            },
        );
        found
    }

    /// [`Bvh::blocker_of`] for each of up to [`PACKET`] parallel `segments` together
    /// (their first blockers in `found`): one walk, whose box tests widen each box by the
    /// packet's spread; at a quad whose children hold leaves, each segment not yet
    /// blocked takes its own box tests, and screens and tests the leaves they let through.
    /// So each segment meets the leaves a lone walk would, in the same order (and, at
    /// most, leaves below a box its own test missed, which hold no facet it crosses):
    /// it finds the same first blocker as alone.
    fn blockers_of(&self, segments: &[Segment], found: &mut [Option<u32>; PACKET]) {
        let packet = PacketSlab::new(segments);
        let open = std::cell::Cell::new((1u32 << segments.len()) - 1);
        // Per segment, the leaves among the last quad's children its own box test lets through.
        let reached = std::cell::Cell::new([0u32; PACKET]);
        self.walk(
            |quad| {
                let lanes = packet.hits(quad);
                if lanes & quad.leaf_lanes() != 0 {
                    let mut each = [0u32; PACKET];
                    let mut rays = open.get();
                    while rays != 0 {
                        let r = rays.trailing_zeros() as usize;
                        rays &= rays - 1;
                        each[r] = segments[r].slab.hits(quad);
                    }
                    reached.set(each);
                }
                lanes
            },
            |lane, leaf, frame| {
                let each = reached.get();
                let mut rays = open.get();
                while rays != 0 {
                    let r = rays.trailing_zeros() as usize;
                    rays &= rays - 1;
                    if each[r] & (1 << lane) == 0 {
                        continue;
                    }
                    if let Some(id) = self.leaf_blocker(leaf, frame, &segments[r]) {
                        found[r] = Some(id);
                        open.set(open.get() & !(1 << r));
                    }
                }
                open.get() == 0
            },
        );
    }

    /// The order of `rays` along a Morton curve through their origins.
    fn morton_order(&self, rays: &[ShadowRay]) -> Vec<usize> {
        let cell = self.reach / 512.0;
        let mut keys: Vec<(u64, u32)> = (rays.iter().enumerate())
            .map(|(k, r)| (morton(r.origin - self.centre, cell), k as u32))
            .collect();
        keys.sort_unstable();
        keys.into_iter().map(|(_, k)| k as usize).collect()
    }

    /// Depth-first walk of the tree: into every child whose lane `hits` sets, handing
    /// each leaf reached, with its lane and frame, to `at_leaf`; stops, returning true,
    /// as soon as that does.
    #[inline]
    fn walk(
        &self,
        hits: impl Fn(&Quad) -> u32,
        mut at_leaf: impl FnMut(usize, &Leaf, &LeafFrame) -> bool,
    ) -> bool {
        if self.quads.is_empty() {
            return false;
        }
        let mut stack = [0u32; STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let quad = &self.quads[stack[top] as usize];
            let mut lanes = hits(quad);
            while lanes != 0 {
                let k = lanes.trailing_zeros() as usize;
                lanes &= lanes - 1;
                match quad.child(k) {
                    Child::Node(q) => {
                        stack[top] = q;
                        top += 1;
                    }
                    Child::Leaf(l) => {
                        let frame = LeafFrame::of(quad, k);
                        if at_leaf(k, &self.leaves[l as usize], &frame) {
                            return true;
                        }
                    }
                }
            }
        }
        false
    }

    /// The segment `a → b` prepared for testing; `None` when it cannot cross any facet
    /// (no longer than the two margins, or missing the tree's bounding sphere).
    fn segment(&self, a: DVec3, b: DVec3, skip: [u32; 2], margin: f64) -> Option<Segment> {
        let length = (b - a).length();
        if self.quads.is_empty() || length <= 2.0 * margin {
            return None;
        }
        let dir = (b - a) / length;
        let toward = Toward::new(dir);
        self.along(a, b, &toward, margin, length - margin, skip)
    }

    /// The segment `a → b` along `toward`, whose hits count between `t0` and `t1` from
    /// `a`, prepared for testing; `None` when it misses the tree's bounding sphere.
    fn along(
        &self,
        a: DVec3,
        b: DVec3,
        toward: &Toward,
        t0: f64,
        t1: f64,
        skip: [u32; 2],
    ) -> Option<Segment> {
        let Toward { frame, inv } = *toward;
        let dir = frame.dir();
        // The box tests start from the segment's point nearest the tree's centre, so that
        // their `f32` coordinates stay of the tree's size however far away `a` lies.
        let tc = (self.centre - a).dot(dir).clamp(t0, t1);
        let start = a + dir * tc - self.centre;
        if start.length() > self.radius {
            return None;
        }
        Some(Segment {
            screened: Screened::new(a, b, self.centre, self.reach),
            exact: Exact::new(a, frame, (t0, t1), skip),
            slab: Slab::new(start.as_vec3(), inv, t0 - tc, t1 - tc),
        })
    }

    /// True if a facet other than those in `skip` crosses the ray from `a` along
    /// `toward` farther than `t_min`: [`Bvh::segment_blocked`] for a segment reaching past
    /// the tree, with the frame built from the direction itself, as the other tracers
    /// build it.
    fn ray_blocked(&self, a: DVec3, toward: &Toward, t_min: f64, skip: [u32; 2]) -> bool {
        self.ray(a, toward, t_min, skip)
            .is_some_and(|ray| self.blocker_of(&ray).is_some())
    }

    /// The ray from `a` along `toward`, hits counting beyond `t_min`, as the segment
    /// reaching past the tree that [`Bvh::ray_blocked`] tests; `None` when it cannot
    /// cross any facet.
    fn ray(&self, a: DVec3, toward: &Toward, t_min: f64, skip: [u32; 2]) -> Option<Segment> {
        if self.quads.is_empty() {
            return None;
        }
        let length = self.ray_length(a, t_min);
        let b = a + toward.frame.dir() * length;
        self.along(a, b, toward, t_min, length - t_min, skip)
    }

    /// How long the segment standing for a ray from `a` is: past the tree's bounding
    /// sphere by twice `t_min`.
    fn ray_length(&self, a: DVec3, t_min: f64) -> f64 {
        (a - self.centre).length() + self.radius + 2.0 * t_min
    }

    /// A facet of `leaf` that blocks the segment, if any.
    #[inline]
    fn leaf_blocker(&self, leaf: &Leaf, frame: &LeafFrame, s: &Segment) -> Option<u32> {
        let mut lanes = leaf.may_cross(&s.screened, frame);
        while lanes != 0 {
            let k = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            if self.crosses(&s.exact, leaf.ids[k]) {
                return Some(leaf.ids[k]);
            }
        }
        None
    }

    /// The exact predicate for facet `id` (false for a facet left out) and the segment,
    /// with the hit distance bounded on both sides.
    #[inline]
    fn crosses(&self, s: &Exact, id: u32) -> bool {
        self.crosses_seen(s, id, &self.seen(s, id))
    }

    /// Facet `id`'s corners in the frame of the segment's direction.
    #[inline]
    fn seen(&self, s: &Exact, id: u32) -> [DVec3; 3] {
        self.mesh.corners(id as usize).map(|p| s.frame.project(p))
    }

    /// [`Bvh::crosses`] for facet `id` with its corners `seen` along the segment. The
    /// projection test comes first: a walk over the surface meets mostly facets the ray
    /// passes beside, which it rules out without the depth plane's divisions (the order
    /// does not change the answer).
    #[inline]
    fn crosses_seen(&self, s: &Exact, id: u32, seen: &[DVec3; 3]) -> bool {
        !s.skip.contains(&id) && inside(seen, s.q) && {
            let normal = s.frame.project(self.mesh.normals[id as usize]);
            let t = DepthPlane::new(normal, seen[0]).distance(s.q);
            t > s.t0 && t < s.t1
        }
    }

    /// The edge of a facet whose corners are `seen` along the ray (corner `k` to
    /// `k + 1`) beyond which the ray passes farthest, or `None` when it passes within all
    /// three or the facet is seen edge-on: where a walk toward the facet the ray crosses
    /// goes next.
    fn edge_passed(s: &Exact, seen: &[DVec3; 3]) -> Option<usize> {
        let p = seen.map(|c| c.truncate());
        let q = s.q.truncate();
        let turn = (p[1] - p[0]).perp_dot(p[2] - p[0]);
        if turn == 0.0 {
            return None;
        }
        // The ray passes beyond edge `k` by `h / |edge|`, `h` its edge function turned
        // outward. The farthest is found by comparing `h² |other edge|²` with `h_other²
        // |edge|²` among the positive `h`: no root and no division, on a path where a
        // walk spends most of its time.
        let mut farthest: Option<(usize, f64, f64)> = None;
        for k in 0..3 {
            let edge = p[(k + 1) % 3] - p[k];
            let h = -turn.signum() * edge.perp_dot(q - p[k]);
            if h > 0.0 {
                let (h2, length2) = (h * h, edge.length_squared());
                if farthest
                    .is_none_or(|(_, best_h2, best_length2)| h2 * best_length2 > best_h2 * length2)
                {
                    farthest = Some((k, h2, length2));
                }
            }
        }
        farthest.map(|(k, ..)| k)
    }
}

/// What every ray along one unit direction shares: the exact predicate's frame and the
/// box tests' reciprocal direction.
#[derive(Clone, Copy)]
struct Toward {
    frame: RayFrame,
    inv: Vec3,
}

impl Toward {
    fn new(dir: DVec3) -> Toward {
        Toward {
            frame: RayFrame::new(dir),
            inv: dir.as_vec3().recip(),
        }
    }
}

/// Shadow rays along one direction, answered by the tree.
#[derive(Clone, Copy)]
pub(crate) struct BvhRays<'b> {
    bvh: &'b Bvh<'b>,
    toward: Toward,
}

impl Tracer for Bvh<'_> {
    fn toward(&self, dir: DVec3) -> Box<dyn ShadowQuery + '_> {
        Box::new(BvhRays::new(self, dir))
    }
}

impl ShadowQuery for BvhRays<'_> {
    fn blocked(&self, origin: DVec3, t_min: f64, skip: Option<u32>) -> bool {
        let skip = [skip.unwrap_or(u32::MAX), u32::MAX];
        self.bvh.ray_blocked(origin, &self.toward, t_min, skip)
    }

    fn blocker(&self, origin: DVec3, t_min: f64, skip: Option<u32>) -> Blocker {
        let skip = [skip.unwrap_or(u32::MAX), u32::MAX];
        let ray = self.bvh.ray(origin, &self.toward, t_min, skip);
        match ray.and_then(|ray| self.bvh.blocker_of(&ray)) {
            Some(id) => Blocker::Facet(id),
            None => Blocker::Clear,
        }
    }

    fn blockers(&self, rays: &[ShadowRay]) -> Vec<Blocker> {
        let mut found = vec![Blocker::Clear; rays.len()];
        let bvh = self.bvh;
        let mut packet = Packet::default();
        for k in bvh.morton_order(rays) {
            let r = &rays[k];
            let Some(segment) = bvh.ray(r.origin, &self.toward, r.t_min, [r.facet, u32::MAX])
            else {
                continue;
            };
            if !packet.takes(&segment, bvh) {
                packet.trace(bvh, &mut found);
            }
            packet.push(k, segment);
        }
        packet.trace(bvh, &mut found);
        found
    }

    fn blocker_near(
        &self,
        origin: DVec3,
        t_min: f64,
        skip: u32,
        start: u32,
        neighbours: &[[u32; 3]],
    ) -> Option<u32> {
        let exact = self.exact(origin, t_min, skip);
        let (mut facet, mut came_from) = (start, NO_NEIGHBOUR);
        for _ in 0..WALK_FACETS {
            // Each facet is projected once, for the test and for the way on; its
            // neighbours are asked for first, so that their load overlaps the tests.
            let seen = self.bvh.seen(&exact, facet);
            let around = neighbours[facet as usize];
            // Only facets the tree holds may block: the answer must be the tree's.
            if self.bvh.crosses_seen(&exact, facet, &seen) && casts_shadows(self.bvh.mesh, facet) {
                return Some(facet);
            }
            let next = around[Bvh::edge_passed(&exact, &seen)?];
            if next == NO_NEIGHBOUR || next == came_from {
                return None;
            }
            (facet, came_from) = (next, facet);
        }
        None
    }
}

impl<'b> BvhRays<'b> {
    /// Shadow rays along the unit `dir`, answered by `bvh`.
    pub(crate) fn new(bvh: &'b Bvh<'b>, dir: DVec3) -> BvhRays<'b> {
        BvhRays {
            bvh,
            toward: Toward::new(dir),
        }
    }

    /// [`ShadowQuery::blocked`] (the facet `skip` left out) decided by the facets
    /// `among` alone (mesh ids), without walking the tree: the same answer, bit for bit,
    /// when `among` holds every facet the ray can cross, as those [`Bvh::near_cone`]
    /// finds reaching into a cone around it do.
    pub(crate) fn blocked_among(
        &self,
        origin: DVec3,
        t_min: f64,
        skip: u32,
        among: &[u32],
    ) -> bool {
        // Only the exact tests: the boxes and screens that `ray` would also prepare
        // decide nothing here, and a ray missing the tree's sphere crosses no facet.
        self.blocker_among(origin, t_min, skip, among).is_some()
    }

    /// [`BvhRays::blocked_among`] naming the first facet of `among` that blocks the ray.
    pub(crate) fn blocker_among(
        &self,
        origin: DVec3,
        t_min: f64,
        skip: u32,
        among: &[u32],
    ) -> Option<u32> {
        let exact = self.exact(origin, t_min, skip);
        among
            .iter()
            .copied()
            .find(|&id| self.bvh.crosses(&exact, id))
    }

    /// The exact predicate's view of the ray from `origin` (the facet `skip` left out).
    fn exact(&self, origin: DVec3, t_min: f64, skip: u32) -> Exact {
        let t1 = self.bvh.ray_length(origin, t_min) - t_min;
        Exact::new(origin, self.toward.frame, (t_min, t1), [skip, u32::MAX])
    }
}

impl Bvh<'_> {
    /// Branch and bound over the tree, seen from a point above a plane: `open` of a
    /// child's box (a [`SearchBox`], with an upper bound of the elevation sine of its
    /// points above the plane of `view`) and of what its parent's `open` handed on (`root`
    /// for the root's children) says whether to descend, with which priority (higher
    /// first) and what to hand on to its own children; `visit(facet id, corners, what its
    /// leaf's open handed on)` sees every facet of every leaf opened.
    pub(crate) fn search<C: Copy>(
        &self,
        view: &Viewpoint,
        root: C,
        mut open: impl FnMut(&SearchBox, C) -> Option<(f64, C)>,
        mut visit: impl FnMut(u32, &[DVec3; 3], C),
    ) {
        if self.quads.is_empty() {
            return;
        }
        let mut stack = [(0u32, root); STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (q, handed) = stack[top];
            let quad = &self.quads[q as usize];
            let (bounds, [lowest, highest]) = quad.elevation_bounds(view);
            let mut lanes: [(f64, usize, C); 4] = [(f64::NEG_INFINITY, 4, handed); 4];
            for (lane, slot) in lanes.iter_mut().enumerate() {
                if quad.lo[0][lane] != f32::INFINITY {
                    let child = SearchBox {
                        quad,
                        lane,
                        centre: self.centre,
                        bound: bounds[lane] as f64,
                        axial: (lowest[lane] as f64, highest[lane] as f64),
                    };
                    if let Some((priority, on)) = open(&child, handed) {
                        *slot = (priority, lane, on);
                    }
                }
            }
            // Highest priority pushed last, so that it is taken first.
            lanes.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            for &(_, lane, on) in lanes.iter().filter(|(_, lane, _)| *lane < 4) {
                match quad.child(lane) {
                    Child::Node(q) => {
                        stack[top] = (q, on);
                        top += 1;
                    }
                    Child::Leaf(l) => {
                        for &id in self.leaves[l as usize].ids.iter() {
                            if id != u32::MAX {
                                visit(id, &self.mesh.corners(id as usize), on);
                            }
                        }
                    }
                }
            }
        }
    }

    /// The point `c` above the plane of unit normal `n` (mesh frame, metres) as
    /// [`Bvh::search`] sees it, for facets widened by `widening` (m).
    pub(crate) fn viewpoint(&self, c: DVec3, n: DVec3, widening: f64) -> Viewpoint {
        let from = c - self.centre;
        let splat = |v: DVec3| v.as_vec3().to_array().map(Vec4::splat);
        // Every coordinate the bounds combine is within `size` of zero; a few dozen
        // roundings of that size, and the widening, are far within this.
        let size = from.abs().max_element() + 2.0 * self.reach;
        Viewpoint {
            c: splat(from),
            n: splat(n),
            n_abs: splat(n.abs()),
            error: Vec4::splat(round_up(64.0 * f32::EPSILON as f64 * size + widening)),
            axial: false,
        }
    }
}

impl Viewpoint {
    /// The same view, with each box's range of elevation sines above the plane normal to
    /// the z axis ([`SearchBox::axial`]) bounded too: a Sun band's declinations.
    pub(crate) fn with_axial(self) -> Viewpoint {
        Viewpoint {
            axial: true,
            ..self
        }
    }
}

/// A viewpoint and its plane's unit normal as the `f32` elevation bounds of
/// [`Bvh::search`] see them: relative to the tree's centre, in all four lanes, with the
/// bounds' allowance for rounding (m).
pub(crate) struct Viewpoint {
    c: [Vec4; 3],
    n: [Vec4; 3],
    n_abs: [Vec4; 3],
    error: Vec4,
    axial: bool,
}

/// A child's box as [`Bvh::search`] meets it.
pub(crate) struct SearchBox<'q> {
    quad: &'q Quad,
    lane: usize,
    centre: DVec3,
    /// An upper bound of the elevation sine of every point of the box (−1 to 1).
    pub(crate) bound: f64,
    /// Bounds of the least and the greatest elevation sine of its points above the
    /// plane normal to the z axis (−1 and 1 unless the view asks for them).
    pub(crate) axial: (f64, f64),
}

impl SearchBox<'_> {
    /// The box's lower and upper corners (mesh frame, metres); it holds every facet
    /// below it.
    pub(crate) fn corners(&self) -> (DVec3, DVec3) {
        let corner = |c: &[Vec4; 3]| {
            DVec3::new(
                c[0][self.lane] as f64,
                c[1][self.lane] as f64,
                c[2][self.lane] as f64,
            ) + self.centre
        };
        (corner(&self.quad.lo), corner(&self.quad.hi))
    }
}

impl Quad {
    /// Per child, an upper bound of the elevation sine above the plane of `view` of every
    /// point of its box: the box's highest rise over the plane, over its distance from
    /// the viewpoint (1 when it holds the viewpoint); for a box wholly below the plane,
    /// that rise (negative) over its farthest corner's distance. Rises are taken up, and
    /// distances down (up for the farthest), by the view's rounding allowance. Beside
    /// it, where the view asks ([`Viewpoint::with_axial`]), the least and the greatest
    /// elevation sine of its points above the plane normal to the mesh frame's z axis,
    /// bounded alike; else −1 and 1.
    #[inline]
    fn elevation_bounds(&self, view: &Viewpoint) -> (Vec4, [Vec4; 2]) {
        let (mut rise, mut near, mut far) = (view.error, Vec4::ZERO, Vec4::ZERO);
        for k in 0..3 {
            let mid = (self.lo[k] + self.hi[k]) * 0.5 - view.c[k];
            let half = (self.hi[k] - self.lo[k]) * 0.5;
            rise += view.n[k] * mid + view.n_abs[k] * half;
            let outside = (self.lo[k] - view.c[k])
                .max(view.c[k] - self.hi[k])
                .max(Vec4::ZERO);
            near += outside * outside;
            let reach = mid.abs() + half;
            far += reach * reach;
        }
        let gap = near.sqrt() * (1.0 - 1e-6) - view.error;
        let far = far.sqrt() * (1.0 + 1e-6) + view.error;
        let bound = |rise: Vec4| {
            let above = Vec4::select(
                gap.cmple(Vec4::ZERO),
                Vec4::ONE,
                (rise / gap).min(Vec4::ONE),
            );
            let below = (rise / far).max(Vec4::NEG_ONE);
            Vec4::select(rise.cmpge(Vec4::ZERO), above, below)
        };
        let axial = if view.axial {
            let mid = (self.lo[2] + self.hi[2]) * 0.5 - view.c[2];
            let half = (self.hi[2] - self.lo[2]) * 0.5;
            [
                -bound(view.error - mid + half),
                bound(view.error + mid + half),
            ]
        } else {
            [Vec4::NEG_ONE, Vec4::ONE]
        };
        (bound(rise), axial)
    }
}

impl Bvh<'_> {
    /// Every facet that the cone of directions from `apex` within the angle of tangent
    /// `tan_half` of the unit `axis` may reach (mesh frame, metres), to
    /// `visit(facet, corners)`, until it returns `true`. The boxes are tested in
    /// `f32` as for shadow rays ([`ConeSlab`]), and so are the leaves' facets
    /// ([`Leaf::may_reach`]), their margins keeping the tests conservative.
    pub(crate) fn near_cone(
        &self,
        apex: DVec3,
        axis: DVec3,
        tan_half: f64,
        mut visit: impl FnMut(u32, &[DVec3; 3]) -> bool,
    ) {
        let from = apex - self.centre;
        // A little above the cone's own slope, for the rounding of the slopes in `f32`.
        let slope = tan_half * (1.0 + 1e-6);
        let slab = ConeSlab::new(from, axis, slope, 2.0 * (from.length() + self.radius));
        // Every facet lies within this of the apex, so the cone's axis need go no farther.
        let length = from.length() + self.radius;
        let (screened, spread) = self.screened_cone(apex, axis, slope, length);
        self.walk(
            |quad| slab.hits(quad),
            |_, leaf, frame| {
                let mut lanes = leaf.may_reach(&screened, frame, &spread);
                while lanes != 0 {
                    let k = lanes.trailing_zeros() as usize;
                    lanes &= lanes - 1;
                    let id = leaf.ids[k];
                    if visit(id, &self.mesh.corners(id as usize)) {
                        return true;
                    }
                }
                false
            },
        );
    }

    /// The cone from `apex` along the unit `axis`, of slope `slope` and axis length
    /// `length`, as the leaf screen sees it ([`Leaf::may_reach`]).
    fn screened_cone(
        &self,
        apex: DVec3,
        axis: DVec3,
        slope: f64,
        length: f64,
    ) -> (Screened, Spread) {
        let mut screened = Screened::new(apex, apex + axis * length, self.centre, self.reach);
        screened.crossing *= 4.0;
        // The cone's radius at the far end, rounded up with room for the widening's own
        // few `f32` operations and for the edge planes' error across it (2.7e-5 of it).
        let grow = round_up(slope * length * (1.0 + 1e-4));
        screened.steep = screened.steep.max(Vec4::splat(2.0 * grow));
        let spread = Spread {
            grow: Vec4::splat(grow),
            length: Vec4::splat(length as f32),
        };
        (screened, spread)
    }
}

/// A cone as the `f32` box tests see it: from `origin` (relative to the tree's centre)
/// along `dir`, over `0 ≤ t ≤ t1`, every point within `t · g` of the axis on every
/// coordinate (a square cross-section holding the round one). Per coordinate a box's
/// interval `[lo, hi]` is reached at `t` when `lo − t·g ≤ o + t·d ≤ hi + t·g`: two
/// linear bounds on `t`, each a lower or an upper bound by the sign of `d ± g`.
struct ConeSlab {
    origin: [Vec4; 3],
    /// Per coordinate, `1/(d + g)` and `1/(d − g)`.
    widening: [Vec4; 3],
    narrowing: [Vec4; 3],
    /// Per coordinate, whether each bound is a lower bound (`d + g > 0`, `d − g < 0`).
    lo_from_below: [bool; 3],
    hi_from_below: [bool; 3],
    t1: Vec4,
}

impl ConeSlab {
    fn new(origin: DVec3, dir: DVec3, g: f64, t1: f64) -> ConeSlab {
        let splat = |x: f64| Vec4::splat(x as f32);
        ConeSlab {
            origin: origin.to_array().map(splat),
            widening: dir.to_array().map(|d| splat(1.0 / (d + g))),
            narrowing: dir.to_array().map(|d| splat(1.0 / (d - g))),
            lo_from_below: dir.to_array().map(|d| d + g > 0.0),
            hi_from_below: dir.to_array().map(|d| d - g < 0.0),
            t1: Vec4::splat(round_up(t1)),
        }
    }

    /// Bit `k` set when the cone may reach into child `k`'s box. A NaN (0·∞, for
    /// `d ± g = 0` and a face through the origin) is the first operand of `max` or
    /// `min`, which then return the second: it drops out, widening the range. The
    /// unused lanes' boxes, at +∞, stay beyond `t1`.
    #[inline]
    fn hits(&self, quad: &Quad) -> u32 {
        let (mut near, mut far) = (Vec4::ZERO, self.t1);
        for axis in 0..3 {
            let a = (quad.lo[axis] - self.origin[axis]) * self.widening[axis];
            let b = (quad.hi[axis] - self.origin[axis]) * self.narrowing[axis];
            if self.lo_from_below[axis] {
                near = a.max(near);
            } else {
                far = a.min(far);
            }
            if self.hi_from_below[axis] {
                near = b.max(near);
            } else {
                far = b.min(far);
            }
        }
        near.cmple(far).bitmask()
    }
}

/// A segment prepared for the box tests, the screen and the exact facet tests.
struct Segment {
    screened: Screened,
    exact: Exact,
    slab: Slab,
}

/// A segment as the exact predicate sees it.
struct Exact {
    frame: RayFrame,
    /// The segment's start in `frame`.
    q: DVec3,
    /// The range of hit distances that count (m).
    t0: f64,
    t1: f64,
    /// Facets left out.
    skip: [u32; 2],
}

impl Exact {
    fn new(a: DVec3, frame: RayFrame, (t0, t1): (f64, f64), skip: [u32; 2]) -> Exact {
        Exact {
            frame,
            q: frame.project(a),
            t0,
            t1,
            skip,
        }
    }
}

/// A segment as the `f32` box tests see it, each value in all four lanes: origin
/// relative to the tree's centre, reciprocal direction (by axis), and the parameter range.
struct Slab {
    origin: [Vec4; 3],
    inv: [Vec4; 3],
    t0: Vec4,
    t1: Vec4,
}

impl Slab {
    /// The range `[t0, t1]` (m) is rounded outward to `f32`.
    fn new(origin: Vec3, inv: Vec3, t0: f64, t1: f64) -> Slab {
        Slab {
            origin: origin.to_array().map(Vec4::splat),
            inv: inv.to_array().map(Vec4::splat),
            t0: Vec4::splat(round_down(t0)),
            t1: Vec4::splat(round_up(t1)),
        }
    }

    /// The segment's start of its box tests (m from the tree's centre).
    fn start(&self) -> Vec3 {
        Vec3::new(self.origin[0].x, self.origin[1].x, self.origin[2].x)
    }

    /// Ray–box slab tests over [t0, t1] of a node's four children: bit `k` set when the
    /// segment may pass through child `k`'s box.
    #[inline]
    fn hits(&self, quad: &Quad) -> u32 {
        self.hits_widened(quad, None)
    }

    /// [`Slab::hits`] with each box first widened by `half` on each axis (m), when given.
    #[inline(always)]
    fn hits_widened(&self, quad: &Quad, half: Option<&[Vec4; 3]>) -> u32 {
        let (mut near, mut far) = (self.t0, self.t1);
        for axis in 0..3 {
            let (mut lo, mut hi) = (quad.lo[axis], quad.hi[axis]);
            if let Some(half) = half {
                (lo, hi) = (lo - half[axis], hi + half[axis]);
            }
            let a = (lo - self.origin[axis]) * self.inv[axis];
            let b = (hi - self.origin[axis]) * self.inv[axis];
            // A NaN (0·∞: the segment runs parallel to this axis, in a box face's plane)
            // either drops out (widening the range) or rejects the box; it rejects only a
            // segment lying in the plane of a face padded `BOX_MARGIN` beyond every facet
            // inside, which therefore crosses none of them.
            near = a.min(b).max(near);
            far = a.max(b).min(far);
        }
        near.cmple(far).bitmask()
    }
}

/// The box of the segments' starts (m from the tree's centre); empty (`lo` above `hi`)
/// for no segments.
fn starts_box(segments: &[Segment]) -> (Vec3, Vec3) {
    let starts = segments.iter().map(|s| s.slab.start());
    let lo = starts.clone().fold(Vec3::INFINITY, Vec3::min);
    (lo, starts.fold(Vec3::NEG_INFINITY, Vec3::max))
}

/// Most segments in one packet. At 786k facets (`bench_peer --tracer bvh --steps 36`,
/// one thread) packets of 8 took 0.91 of the step a ray alone took, 16 no less, and
/// 16 with twice the spread more; at 49k with 360 steps, the same as alone.
const PACKET: usize = 8;

/// How widely a packet's starts may spread on any axis, in typical facets: each
/// segment of it tests the leaves the widened boxes let through, so a wider packet
/// saves fewer box tests than it adds.
const PACKET_SPREAD: f64 = 4.0;

/// The box tests of a packet of parallel segments: one segment from the centre of their
/// starts over the union of their ranges, against every box widened by the starts' half
/// spread `h` on each axis. A segment of the packet meets a box at `t` only where the
/// centre's segment at the same `t` lies within `h` of it, so the widened test lets
/// through every box any segment of the packet may pass through.
struct PacketSlab {
    slab: Slab,
    /// `h` per axis (m).
    half: [Vec4; 3],
}

impl PacketSlab {
    fn new(segments: &[Segment]) -> PacketSlab {
        let (lo, hi) = starts_box(segments);
        let first = &segments[0].slab;
        let t0 = segments
            .iter()
            .map(|s| s.slab.t0.x)
            .fold(f32::INFINITY, f32::min);
        let t1 = segments
            .iter()
            .map(|s| s.slab.t1.x)
            .fold(f32::NEG_INFINITY, f32::max);
        // The centre and half spread in `f32` are rounded by far less than the boxes'
        // margin, which covers them as it covers a lone segment's start.
        let (centre, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
        PacketSlab {
            slab: Slab {
                origin: centre.to_array().map(Vec4::splat),
                inv: first.inv,
                t0: Vec4::splat(t0),
                t1: Vec4::splat(t1),
            },
            half: half.to_array().map(Vec4::splat),
        }
    }

    #[inline]
    fn hits(&self, quad: &Quad) -> u32 {
        self.slab.hits_widened(quad, Some(&self.half))
    }
}

/// Parallel segments gathered to go through the tree together, with the indices of the
/// rays they stand for.
#[derive(Default)]
struct Packet {
    rays: Vec<usize>,
    segments: Vec<Segment>,
}

impl Packet {
    /// Whether `segment` may join: the packet is not full, and its starts would still
    /// lie within [`PACKET_SPREAD`] typical facets on every axis.
    fn takes(&self, segment: &Segment, bvh: &Bvh) -> bool {
        let p = segment.slab.start();
        let (lo, hi) = starts_box(&self.segments);
        let spread = (hi.max(p) - lo.min(p)).max_element();
        self.rays.len() < PACKET && spread <= (PACKET_SPREAD * bvh.facet_size) as f32
    }

    fn push(&mut self, ray: usize, segment: Segment) {
        self.rays.push(ray);
        self.segments.push(segment);
    }

    /// Traces the packet, marks the rays found blocked in `found`, and empties it.
    fn trace(&mut self, bvh: &Bvh, found: &mut [Blocker]) {
        let mut blockers = [None; PACKET];
        match self.segments.as_slice() {
            [] => {}
            [alone] => blockers[0] = bvh.blocker_of(alone),
            together => bvh.blockers_of(together, &mut blockers),
        }
        for (&k, b) in self.rays.iter().zip(blockers) {
            if let Some(id) = b {
                found[k] = Blocker::Facet(id);
            }
        }
        self.rays.clear();
        self.segments.clear();
    }
}

/// The index of `p` along a Morton curve through cells of side `cell`.
fn morton(p: DVec3, cell: f64) -> u64 {
    let spread = |x: f64| -> u64 {
        let mut v = ((x / cell).floor() as i64 + (1 << 20)).clamp(0, (1 << 21) - 1) as u64;
        v = (v | v << 32) & 0x1f00000000ffff;
        v = (v | v << 16) & 0x1f0000ff0000ff;
        v = (v | v << 8) & 0x100f00f00f00f00f;
        v = (v | v << 4) & 0x10c30c30c30c30c3;
        (v | v << 2) & 0x1249249249249249
    };
    spread(p.x) | spread(p.y) << 1 | spread(p.z) << 2
}

/// Outward margin of the `f32` boxes, relative to the tree's reach from its centre (half
/// its root box's longest side). A segment's box tests start within twice that reach of
/// the centre, so `f32` rounds their coordinates and slab parameters by a few 1e-7 of it
/// at most; a margin well above that keeps every box test conservative.
const BOX_MARGIN: f32 = 1e-5;

/// An `f32` not above `x` (`x` rounded, then moved down by at least one unit in the last
/// place if rounding went up).
fn round_down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x {
        f - f.abs() * f32::EPSILON - f32::MIN_POSITIVE
    } else {
        f
    }
}

/// An `f32` not below `x`.
pub(crate) fn round_up(x: f64) -> f32 {
    -round_down(-x)
}

/// The traversal layout of the built `nodes`: one [`Quad`] per node that owns one (the
/// root's first), with boxes relative to `centre` and widened by `margin` metres, and
/// the leaves' runs of facets `(first, count)` with their frames, in tree order. A quad holds a binary
/// node's children, with the largest inner ones replaced by theirs until there are four
/// (a leaf root's quad holds just itself).
fn quads(nodes: &[Node], centre: DVec3, margin: f32) -> (Vec<Quad>, Vec<(u32, u32, LeafFrame)>) {
    let mut quads = Vec::new();
    let mut runs = Vec::new();
    // Nodes owning a quad, in quad order.
    let mut owners = if nodes.is_empty() { vec![] } else { vec![0] };
    while let Some(&owner) = owners.get(quads.len()) {
        let mut quad = Quad {
            lo: [Vec4::INFINITY; 3],
            hi: [Vec4::INFINITY; 3],
            child: [0; 4],
        };
        for (lane, c) in grandchildren(nodes, owner).into_iter().enumerate() {
            let child = &nodes[c];
            let lo = (child.lo - centre).as_vec3() - margin;
            let hi = (child.hi - centre).as_vec3() + margin;
            for axis in 0..3 {
                quad.lo[axis][lane] = lo[axis];
                quad.hi[axis][lane] = hi[axis];
            }
            quad.child[lane] = if child.count > 0 {
                runs.push((child.first, child.count, LeafFrame::of(&quad, lane)));
                // Leaves hold at least one facet each, and facet ids are below 2³¹ in any
                // mesh that fits in memory (44 bytes of leaf per facet alone).
                assert!(
                    runs.len() <= LEAF_BIT as usize,
                    "too many leaves for LEAF_BIT"
                );
                (runs.len() as u32 - 1) | LEAF_BIT
            } else {
                owners.push(c);
                owners.len() as u32 - 1
            };
        }
        quads.push(quad);
    }
    // Kept for the tracer's life: no room left over from the pushes.
    quads.shrink_to_fit();
    (quads, runs)
}

/// The up to four nodes under inner node `n` that its quad holds: its children, the
/// largest inner one among them replaced by its own children while room is left.
fn grandchildren(nodes: &[Node], n: usize) -> Vec<usize> {
    let node = &nodes[n];
    if node.count > 0 {
        return vec![n];
    }
    let mut kids = vec![node.first as usize, node.first as usize + 1];
    while kids.len() < 4 {
        let area = |&&c: &&usize| half_area((nodes[c].lo, nodes[c].hi));
        let Some(&widest) = kids
            .iter()
            .filter(|&&c| nodes[c].count == 0)
            .max_by(|x, y| area(x).total_cmp(&area(y)))
        else {
            break;
        };
        kids.retain(|&c| c != widest);
        kids.extend([
            nodes[widest].first as usize,
            nodes[widest].first as usize + 1,
        ]);
    }
    kids
}

fn leaf(mesh: &Mesh, facets: &[u32], first: u32) -> Node {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for &f in facets {
        for p in mesh.corners(f as usize) {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    // Padding so that facets lying in a box face are never clipped away by rounding.
    let pad = DVec3::splat((hi - lo).max_element() * 1e-9 + 1e-300);
    Node {
        lo: lo - pad,
        hi: hi + pad,
        first,
        count: facets.len() as u32,
    }
}

/// Splits node `n` (a leaf over `facets[first..first+count]`, `depth` levels below the
/// root) until leaves are small.
fn split(mesh: &Mesh, nodes: &mut Vec<Node>, facets: &mut [u32], n: usize, depth: u32) {
    let Node { first, count, .. } = nodes[n];
    if count as usize <= LEAF_SIZE {
        return;
    }
    let run = &mut facets[first as usize..(first + count) as usize];
    let (axis, at) = if depth < SAH_DEPTH {
        sah_split(mesh, run)
    } else {
        median_split(mesh, run)
    };
    run.sort_unstable_by(|&x, &y| {
        mesh.centroids[x as usize][axis].total_cmp(&mesh.centroids[y as usize][axis])
    });
    let left = nodes.len();
    nodes.push(leaf(mesh, &run[..at], first));
    nodes.push(leaf(mesh, &run[at..], first + at as u32));
    nodes[n].first = left as u32;
    nodes[n].count = 0;
    split(mesh, nodes, facets, left, depth + 1);
    split(mesh, nodes, facets, left + 1, depth + 1);
}

/// Bins along each axis for the surface-area heuristic.
const BINS: usize = 16;

/// The axis and the count of facets (in centroid order along it) that go left, chosen by
/// the binned surface-area heuristic: the split minimising `area(left)·leaves(left) +
/// area(right)·leaves(right)`, the expected cost of a random ray through the node, with
/// each side costed by the leaves of [`LEAF_SIZE`] facets it will need (one screen
/// each), not by its facets. Counting leaves fills them: 3.8 facets per leaf instead of
/// 3.2 on Itokawa at 49k and 786k facets, and the tree 60 bytes a facet instead of 71,
/// for the same time per step and a bound's build 0–3 % longer (docs/performance.md).
fn sah_split(mesh: &Mesh, run: &[u32]) -> (usize, usize) {
    let (clo, chi) = centroid_bounds(mesh, run);
    let extent = chi - clo;
    let leaves = |n: usize| n.div_ceil(LEAF_SIZE) as f64;
    let mut best = (f64::INFINITY, 0, run.len() / 2);
    for axis in 0..3 {
        if extent[axis] <= 0.0 {
            continue;
        }
        let bin_of = |f: u32| {
            let x = (mesh.centroids[f as usize][axis] - clo[axis]) / extent[axis];
            ((x * BINS as f64) as usize).min(BINS - 1)
        };
        let mut boxes = [(DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)); BINS];
        let mut counts = [0usize; BINS];
        for &f in run {
            let b = bin_of(f);
            counts[b] += 1;
            for p in mesh.corners(f as usize) {
                boxes[b] = (boxes[b].0.min(p), boxes[b].1.max(p));
            }
        }
        // Sweep from the right to get every right-hand side's area, then from the left.
        let mut right_area = [0.0; BINS];
        let mut acc = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for b in (1..BINS).rev() {
            acc = (acc.0.min(boxes[b].0), acc.1.max(boxes[b].1));
            right_area[b] = half_area(acc);
        }
        let mut acc = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        let mut left_count = 0;
        for b in 0..BINS - 1 {
            acc = (acc.0.min(boxes[b].0), acc.1.max(boxes[b].1));
            left_count += counts[b];
            if left_count == 0 || left_count == run.len() {
                continue;
            }
            let cost = half_area(acc) * leaves(left_count)
                + right_area[b + 1] * leaves(run.len() - left_count);
            if cost < best.0 {
                best = (cost, axis, left_count);
            }
        }
    }
    (best.1, best.2)
}

/// The axis of the widest spread of centroids, and half the facets.
fn median_split(mesh: &Mesh, run: &[u32]) -> (usize, usize) {
    let (lo, hi) = centroid_bounds(mesh, run);
    ((hi - lo).max_position(), run.len() / 2)
}

fn centroid_bounds(mesh: &Mesh, run: &[u32]) -> (DVec3, DVec3) {
    run.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &f| {
            let c = mesh.centroids[f as usize];
            (lo.min(c), hi.max(c))
        },
    )
}

/// Half the surface area of a box (zero when empty).
fn half_area((lo, hi): (DVec3, DVec3)) -> f64 {
    let e = (hi - lo).max(DVec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::icosphere;
    use crate::mesh::{LengthUnit, RawMesh};

    #[test]
    fn chords_of_a_sphere_seen_from_outside_and_inside() {
        let mesh = Mesh::from_raw(icosphere(3, 1.0, DVec3::ZERO), LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let none = [u32::MAX; 2];
        // A segment through the sphere crosses its surface; one outside it does not.
        assert!(bvh.segment_blocked(
            DVec3::new(-2.0, 0.1, 0.0),
            DVec3::new(2.0, 0.1, 0.0),
            none,
            1e-9
        ));
        assert!(!bvh.segment_blocked(
            DVec3::new(-2.0, 1.5, 0.0),
            DVec3::new(2.0, 1.5, 0.0),
            none,
            1e-9
        ));
        // A chord between two facet centroids crosses nothing but its end facets.
        let (i, j) = (0usize, mesh.len() / 2 + 7);
        let (a, b) = (mesh.centroids[i], mesh.centroids[j]);
        assert!(!bvh.segment_blocked(a, b, [i as u32, j as u32], 1e-9));
        // Hits at the very ends fall within the margin; carried on past b, the segment
        // crosses facet j.
        assert!(!bvh.segment_blocked(a, b, [i as u32, u32::MAX], 1e-9));
        let beyond = a + (b - a) * 1.5;
        assert!(bvh.segment_blocked(a, beyond, [i as u32, u32::MAX], 1e-9));
        assert!(!bvh.segment_blocked(a, beyond, [i as u32, j as u32], 1e-9));
    }

    /// The any-hit answer of the exact predicate over every facet, with no boxes and no
    /// screen: what the tree must reproduce.
    fn brute_force(mesh: &Mesh, a: DVec3, b: DVec3, margin: f64) -> bool {
        crossed(mesh, a, b, margin).next().is_some()
    }

    /// Every facet the exact predicate finds the segment `a → b` crossing.
    fn crossed(mesh: &Mesh, a: DVec3, b: DVec3, margin: f64) -> impl Iterator<Item = usize> + '_ {
        let length = (b - a).length();
        let frame = RayFrame::new((b - a) / length);
        let q = frame.project(a);
        (0..mesh.len()).filter(move |&f| {
            let corners = mesh.corners(f).map(|p| frame.project(p));
            let t = DepthPlane::new(frame.project(mesh.normals[f]), corners[0]).distance(q);
            mesh.areas[f] > 0.0 && t > margin && t < length - margin && inside(&corners, q)
        })
    }

    #[test]
    fn a_cone_visits_every_facet_a_ray_within_it_crosses() {
        // Narrow cones (a Sun's) and wide ones, from surface points and above them, steep
        // and grazing, near the origin and 4,000 km from it: the boxes and the leaf
        // screen may pass more facets, never fewer, than the rays within the cone cross.
        for centre in [DVec3::ZERO, DVec3::new(4.0e6, -1.0e6, 2.5e6)] {
            let mesh = terrain(24, 1.0, centre);
            let bvh = Bvh::build(&mesh);
            let mut rng = crate::TestRng::new(0x9e37_79b9_7f4a_7c15);
            let mut next = || rng.unit();
            let (mut checked, mut skipped) = (0, 0);
            for k in 0..400 {
                let i = (next() * mesh.len() as f64) as usize;
                let apex = mesh.centroids[i] + DVec3::Z * [0.0, 0.05, 2.0][k % 3];
                let elevation = [0.02, 0.2, 1.2][k / 3 % 3] * next();
                let azimuth = std::f64::consts::TAU * next();
                let axis = DVec3::new(
                    elevation.cos() * azimuth.cos(),
                    elevation.cos() * azimuth.sin(),
                    elevation.sin(),
                );
                let half = [0.003, 0.05, 0.3][k % 3] * (0.2 + next());
                let mut visited = Vec::new();
                bvh.near_cone(apex, axis, half.tan(), |id, _| {
                    visited.push(id as usize);
                    false
                });
                let (e1, e2) = (
                    axis.any_orthonormal_vector(),
                    axis.cross(axis.any_orthonormal_vector()),
                );
                for ring in [0.0, 0.5, 0.9, 0.999] {
                    for step in 0..12 {
                        let a = step as f64 * std::f64::consts::TAU / 12.0;
                        let off = half.tan() * ring;
                        let dir = (axis + off * (a.cos() * e1 + a.sin() * e2)).normalize();
                        for f in crossed(&mesh, apex, apex + dir * 100.0, 1e-9) {
                            if f == i {
                                skipped += 1;
                                continue;
                            }
                            assert!(visited.contains(&f), "facet {f}, cone {k}, ring {ring}");
                            checked += 1;
                        }
                    }
                }
            }
            // Many crossings are checked (a facet's own is not its cone's business).
            assert!(checked > 2000, "{checked} crossings checked, {skipped} own");
        }
    }

    /// A bumpy square of `n × n` cells (two triangles each) of side `cell`, centred on
    /// `centre`, its heights a few cells high.
    fn terrain(n: u32, cell: f64, centre: DVec3) -> Mesh {
        let mut raw = RawMesh::default();
        for y in 0..=n {
            for x in 0..=n {
                let (u, v) = (x as f64, y as f64);
                let z =
                    cell * (3.0 * (0.7 * u).sin() * (0.5 * v).cos() + 0.4 * (1.3 * u * v).sin());
                raw.vertices
                    .push(centre + DVec3::new(u * cell, v * cell, z));
            }
        }
        for y in 0..n {
            for x in 0..n {
                let k = y * (n + 1) + x;
                raw.triangles.push([k, k + 1, k + n + 2]);
                raw.triangles.push([k, k + n + 2, k + n + 1]);
            }
        }
        Mesh::from_raw(raw, LengthUnit::M)
    }

    #[test]
    fn tree_answers_exactly_as_the_predicate_over_every_facet() {
        // Metre cells 4,000 km from the origin (an asteroid's terrain in a planet-centred
        // frame), segments between surface points, from far above, and grazing: the
        // f32 boxes and the screen may only pass more facets to the exact test.
        for centre in [DVec3::ZERO, DVec3::new(4.0e6, -1.0e6, 2.5e6)] {
            let mesh = terrain(24, 1.0, centre);
            let bvh = Bvh::build(&mesh);
            let mut rng = crate::TestRng::new(0x2545_f491_4f6c_dd1d);
            let mut next = || rng.unit();
            let mut blocked = 0;
            for k in 0..3000 {
                let (i, j) = (
                    (next() * mesh.len() as f64) as usize,
                    (next() * mesh.len() as f64) as usize,
                );
                let lift = |p: DVec3, h: f64| p + DVec3::Z * h;
                let (a, b) = match k % 3 {
                    0 => (mesh.centroids[i], mesh.centroids[j]),
                    1 => (lift(mesh.centroids[i], 1e4), mesh.centroids[j]),
                    _ => (
                        lift(mesh.centroids[i], 0.3 * next()),
                        lift(mesh.centroids[j], 0.3 * next()),
                    ),
                };
                if i == j {
                    continue;
                }
                let expected = brute_force(&mesh, a, b, 1e-9);
                let skip = [u32::MAX; 2];
                assert_eq!(bvh.segment_blocked(a, b, skip, 1e-9), expected, "{a} → {b}");
                blocked += usize::from(expected);
            }
            // Both answers occur often enough for the comparison to mean something.
            assert!(blocked > 300 && blocked < 2700, "{blocked} of 3000 blocked");
        }
    }

    #[test]
    fn rays_traced_together_find_the_blockers_each_finds_alone() {
        // Rays from every facet of rough terrain near and 4,000 km from the origin, toward
        // Suns along an axis and a diagonal in the terrain's plane (the box tests' NaN and
        // infinite slopes), grazing, and high: packets of neighbours must answer each ray,
        // and name its blocker, as a lone walk does.
        let suns = [
            DVec3::X,
            DVec3::new(1.0, 1.0, 0.0).normalize(),
            DVec3::new(0.3, -0.2, 0.05).normalize(),
            DVec3::new(-0.4, 0.1, 0.3).normalize(),
            DVec3::new(0.05, 0.02, 1.0).normalize(),
        ];
        for centre in [DVec3::ZERO, DVec3::new(4.0e6, -1.0e6, 2.5e6)] {
            let mesh = terrain(24, 1.0, centre);
            let bvh = Bvh::build(&mesh);
            let (mut blocked, mut clear) = (0, 0);
            for sun in suns {
                let rays: Vec<ShadowRay> = (0..mesh.len() as u32)
                    .map(|facet| ShadowRay {
                        facet,
                        origin: mesh.centroids[facet as usize],
                        t_min: 1e-6,
                    })
                    .collect();
                let query = BvhRays::new(&bvh, sun);
                for (r, together) in rays.iter().zip(query.blockers(&rays)) {
                    let alone = query.blocker(r.origin, r.t_min, Some(r.facet));
                    assert_eq!(together, alone, "facet {} toward {sun}", r.facet);
                    blocked += usize::from(alone != Blocker::Clear);
                    clear += usize::from(alone == Blocker::Clear);
                }
            }
            assert!(
                blocked > 500 && clear > 500,
                "{blocked} blocked, {clear} clear"
            );
        }
    }

    /// Each facet's distance in edges from the nearest of `sources` (`usize::MAX` where
    /// the surface does not connect).
    fn edges_from(neighbours: &[[u32; 3]], sources: &[usize]) -> Vec<usize> {
        let mut distance = vec![usize::MAX; neighbours.len()];
        let mut queue: std::collections::VecDeque<usize> = sources.iter().copied().collect();
        sources.iter().for_each(|&f| distance[f] = 0);
        while let Some(f) = queue.pop_front() {
            for n in neighbours[f].into_iter().filter(|&n| n != NO_NEIGHBOUR) {
                if distance[n as usize] == usize::MAX {
                    distance[n as usize] = distance[f] + 1;
                    queue.push_back(n as usize);
                }
            }
        }
        distance
    }

    #[test]
    fn a_walk_from_near_a_blocker_finds_one_the_ray_crosses_or_none() {
        // Grazing rays over rough terrain, near the origin and 4,000 km from it: a walk
        // started one or two edges from the facets a ray crosses must mostly find one of
        // them (over 4 in 5; it stops where the ray passes within a facet it does not cross,
        // mostly around its own origin) and may name no other; started farther than it
        // may walk, it finds none.
        for centre in [DVec3::ZERO, DVec3::new(4.0e6, -1.0e6, 2.5e6)] {
            let mesh = terrain(24, 1.0, centre);
            let bvh = Bvh::build(&mesh);
            let neighbours = crate::mesh::inspect::edge_neighbours(&mesh);
            let mut rng = crate::TestRng::new(0x6a09_e667_f3bc_c908);
            let mut next = || rng.unit();
            let (mut near, mut found, mut far) = (0, 0, 0);
            for _ in 0..3000 {
                let i = (next() * mesh.len() as f64) as usize;
                let (elevation, azimuth) = (0.3 * next(), std::f64::consts::TAU * next());
                let dir = DVec3::new(
                    elevation.cos() * azimuth.cos(),
                    elevation.cos() * azimuth.sin(),
                    elevation.sin(),
                );
                let origin = mesh.centroids[i];
                let hit: Vec<usize> = crossed(&mesh, origin, origin + dir * 100.0, 1e-6)
                    .filter(|&f| f != i)
                    .collect();
                if hit.is_empty() {
                    continue;
                }
                let rays = BvhRays::new(&bvh, dir);
                let (distance, facets) = (&edges_from(&neighbours, &hit), mesh.len());
                let walk = |start: usize| {
                    rays.blocker_near(origin, 1e-6, i as u32, start as u32, &neighbours)
                };
                let starts = |d: std::ops::RangeInclusive<usize>| {
                    (0..facets).filter(move |&f| f != i && d.contains(&distance[f]))
                };
                for start in starts(1..=2).step_by(3) {
                    near += 1;
                    if let Some(f) = walk(start) {
                        assert!(hit.contains(&(f as usize)), "{f} not crossed");
                        found += 1;
                    }
                }
                if let Some(start) = starts(WALK_FACETS..=usize::MAX - 1).next() {
                    assert_eq!(
                        walk(start),
                        None,
                        "from {start}, {} edges away",
                        distance[start]
                    );
                    far += 1;
                }
            }
            assert!(far > 100, "{far} walks from far away");
            assert!(
                near > 1000 && found * 5 > near * 4,
                "found {found} of {near}"
            );
        }
    }

    /// The facets below child `lane` of quad `q`.
    fn facets_below(bvh: &Bvh, q: usize, lane: usize) -> Vec<u32> {
        match bvh.quads[q].child(lane) {
            Child::Leaf(l) => bvh.leaves[l as usize]
                .ids
                .into_iter()
                .filter(|&id| id != u32::MAX)
                .collect(),
            Child::Node(n) => (0..4)
                .filter(|&k| bvh.quads[n as usize].lo[0][k].is_finite())
                .flat_map(|k| facets_below(bvh, n as usize, k))
                .collect(),
        }
    }

    #[test]
    fn search_bounds_hold_every_point_of_the_facets_below() {
        // Viewpoints on, above and inside the terrain and far off it, planes at any
        // tilt: no corner, edge midpoint or centroid below a child rises higher, seen
        // from the viewpoint, than the child's bound says, nor leaves its axial range
        // (elevation sines above the plane normal to z).
        for centre in [DVec3::ZERO, DVec3::new(4.0e6, -1.0e6, 2.5e6)] {
            let mesh = terrain(12, 1.0, centre);
            let bvh = Bvh::build(&mesh);
            let mut rng = crate::TestRng::new(0x5851_f42d_4c95_7f2d);
            let mut next = || rng.unit() - 0.5;
            let (mut tight, mut below_plane, mut axial_tight) = (0usize, 0usize, 0usize);
            for k in 0..200 {
                let i = ((next() + 0.5) * mesh.len() as f64) as usize;
                let lift = [0.0, 0.5, 30.0][k % 3];
                let c = mesh.centroids[i] + DVec3::new(next(), next(), lift);
                let n = DVec3::new(next(), next(), next() + 0.3).normalize();
                let view = bvh.viewpoint(c, n, 0.0).with_axial();
                for q in 0..bvh.quads.len() {
                    let (bounds, [lowest, highest]) = bvh.quads[q].elevation_bounds(&view);
                    for lane in (0..4).filter(|&l| bvh.quads[q].lo[0][l].is_finite()) {
                        let bound = bounds[lane] as f64;
                        let directions: Vec<DVec3> = facets_below(&bvh, q, lane)
                            .into_iter()
                            .flat_map(|id| {
                                let [a, b, d] = mesh.corners(id as usize);
                                [a, b, d, (a + b) / 2.0, (b + d) / 2.0, (a + b + d) / 3.0]
                            })
                            .map(|p| (p - c).normalize())
                            .collect();
                        let top = directions.iter().map(|s| n.dot(*s)).fold(-1.0, f64::max);
                        assert!(top <= bound + 1e-12, "{top} above {bound}");
                        tight += usize::from(bound < 1.0 && bound - top < 0.2);
                        below_plane += usize::from(bound < 0.0);
                        let (lowest, highest) = (lowest[lane] as f64, highest[lane] as f64);
                        for s in &directions {
                            assert!(
                                lowest - 1e-12 <= s.z && s.z <= highest + 1e-12,
                                "{} outside {lowest}..{highest}",
                                s.z
                            );
                        }
                        axial_tight += usize::from(lowest > -1.0 && highest < 1.0);
                    }
                }
            }
            // Bounds both above and below the plane, many of them close; axial ranges
            // short of every elevation.
            assert!(
                tight > 1000 && below_plane > 1000 && axial_tight > 1000,
                "{tight} close, {below_plane} below, {axial_tight} axial ranges"
            );
        }
    }

    /// Levels of quads below and including quad `q`.
    fn depth(bvh: &Bvh, q: usize) -> usize {
        let quad = &bvh.quads[q];
        1 + (0..4)
            .filter(|&k| quad.lo[0][k].is_finite())
            .filter_map(|k| match quad.child(k) {
                Child::Node(q) => Some(depth(bvh, q as usize)),
                Child::Leaf(_) => None,
            })
            .max()
            .unwrap_or(0)
    }

    #[test]
    fn strongly_clustered_facets_give_a_shallow_tree_that_still_answers_exactly() {
        // Facets at geometrically growing distances (ratio 1.03 over 32 decades, sizes in
        // proportion): the surface-area heuristic peels a few off the far end at each
        // split, so the tree is deeper than a balanced one (38 quad levels, 43 without the
        // depth cap, against ~6), which the cap bounds for any input; the f32 boxes must stay
        // conservative at every scale.
        let mut raw = RawMesh::default();
        for k in 0..2500 {
            let x = 1.03f64.powi(k);
            let n = raw.vertices.len() as u32;
            raw.vertices.extend([
                DVec3::new(x, 0.0, -0.01 * x),
                DVec3::new(x, 0.01 * x, 0.01 * x),
                DVec3::new(x, -0.01 * x, 0.01 * x),
            ]);
            raw.triangles.push([n, n + 1, n + 2]);
        }
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let levels = depth(&bvh, 0);
        assert!(levels <= SAH_DEPTH as usize + 31, "{levels} levels");
        let none = [u32::MAX; 2];
        for k in [3, 50, 300, 2499] {
            let x = 1.03f64.powi(k);
            for (a, b) in [
                (
                    DVec3::new(0.5 * x, 1e-3 * x, 0.0),
                    DVec3::new(2.0 * x, 0.0, 0.0),
                ),
                (
                    DVec3::new(0.5 * x, 0.05 * x, 0.0),
                    DVec3::new(2.0 * x, 0.05 * x, 0.0),
                ),
            ] {
                assert_eq!(
                    bvh.segment_blocked(a, b, none, 1e-9),
                    brute_force(&mesh, a, b, 1e-9),
                    "{a} → {b}"
                );
            }
        }
    }

    #[test]
    fn leaves_are_filled_to_nearly_four_facets() {
        // Costing each side of a split by the leaves it needs packs the facets into about
        // N/3.8 leaves (N/3.2 when costed by facets, as before): on a sphere of 20,480
        // facets, fewer than N/3.6, and never fewer than N/4 (each holds four at most).
        let mesh = Mesh::from_raw(icosphere(5, 1.0, DVec3::ZERO), LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let leaves = bvh.leaves.len() as f64;
        let facets = mesh.len() as f64;
        assert!(
            leaves >= facets / 4.0 && leaves < facets / 3.6,
            "{leaves} leaves"
        );
    }

    /// The facets whose lanes the leaf screen passes for the segment `a → b`, every leaf
    /// of the tree visited.
    fn screen_passes(bvh: &Bvh, a: DVec3, b: DVec3) -> Vec<usize> {
        let screened = Screened::new(a, b, bvh.centre, bvh.reach);
        let mut passed = Vec::new();
        bvh.walk(
            |quad| quad.lo[0].cmpne(Vec4::INFINITY).bitmask(),
            |_, leaf, frame| {
                let mut lanes = leaf.may_cross(&screened, frame);
                while lanes != 0 {
                    passed.push(leaf.ids[lanes.trailing_zeros() as usize] as usize);
                    lanes &= lanes - 1;
                }
                false
            },
        );
        passed
    }

    #[test]
    fn the_screen_passes_every_crossing_at_an_edge_and_clears_near_misses() {
        // Segments through points on facets' edges and corners, crossing at angles from
        // just above the screen's 0.01 rad to square, short ones and ones reaching far past
        // the tree, on metre terrain, on slivers 100 times longer than wide, and 4,000 km
        // from the origin: every facet the exact predicate finds crossed must pass the
        // screen. And passing a facet's edge 1e-4 of the segment's scale (its ends' or the
        // tree's reach from the centre) outside at a steep angle, the segment must be
        // screened out of it: the tolerance is that tight (it was 3e-4 of the scale).
        let far = DVec3::new(4.0e6, -1.0e6, 2.5e6);
        let sliver = |m: Mesh| {
            let vertices = m.vertices.iter().map(|v| DVec3::new(v.x, 0.01 * v.y, v.z));
            crate::mesh::in_metres(vertices.collect(), m.triangles)
        };
        for mesh in [
            terrain(24, 1.0, DVec3::ZERO),
            terrain(24, 1.0, far),
            sliver(terrain(24, 1.0, far)),
        ] {
            let bvh = Bvh::build(&mesh);
            let mut rng = crate::TestRng::new(0x5851_f42d_4c95_7f2d);
            let mut next = || rng.unit();
            let (mut crossings, mut misses) = (0, 0);
            for k in 0..1500 {
                let f = (next() * mesh.len() as f64) as usize;
                let c = mesh.corners(f);
                let edge = k % 3;
                let along = [0.0, 1.0, next()][k / 3 % 3];
                let target = c[edge] + (c[(edge + 1) % 3] - c[edge]) * along;
                let n = mesh.normals[f];
                let sine = [0.0101, 0.03, 0.2, 0.7, 1.0][k / 9 % 5];
                let azimuth = std::f64::consts::TAU * next();
                let (e1, e2) = (
                    n.any_orthonormal_vector(),
                    n.cross(n.any_orthonormal_vector()),
                );
                let level = e1 * azimuth.cos() + e2 * azimuth.sin();
                let dir = (n * sine + level * (1.0 - sine * sine).sqrt()).normalize();
                let (back, ahead) = [(0.3, 0.3), (5.0, 40.0), (0.5, 1e4)][k / 45 % 3];
                let (a, b) = (target - dir * back, target + dir * ahead);
                let passed = screen_passes(&bvh, a, b);
                for g in crossed(&mesh, a, b, 0.0) {
                    assert!(
                        passed.contains(&g),
                        "facet {g} crossed but screened out, {a} → {b}"
                    );
                    crossings += 1;
                }
                // The same steep segment moved off the edge, out of the facet in its plane.
                if sine >= 0.7 {
                    let e = c[(edge + 1) % 3] - c[edge];
                    let outward = e.cross(n).normalize();
                    let scale = [a, b].map(|p| (p - bvh.centre).abs().max_element());
                    let off = outward * 1e-4 * bvh.reach.max(scale[0]).max(scale[1]);
                    let (a, b) = (a + off, b + off);
                    if !crossed(&mesh, a, b, 0.0).any(|g| g == f) {
                        assert!(
                            !screen_passes(&bvh, a, b).contains(&f),
                            "{a} → {b} passes facet {f}"
                        );
                        misses += 1;
                    }
                }
            }
            assert!(
                crossings > 1500 && misses > 200,
                "{crossings} crossings, {misses} misses"
            );
        }
    }

    #[test]
    fn quantised_edge_planes_stay_within_their_stated_error() {
        // Heights from the i16 rows against f64 ones, for planes through corners within
        // `half` of the frame's origin and points up to 6.9 halves out: the error must
        // stay under the bound of `EdgeRows` (2.7e-5·|p| + 3.1e-5·half), with 1e-6 for the
        // f32 arithmetic, or the screen could clear a facet the segment crosses.
        let half = 1234.5;
        let mut rng = crate::TestRng::new(0x9e37_79b9_7f4a_7c15);
        let mut cube = || DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 2.0 - 1.0;
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            let mut rows = EdgeRows([[0; 4]; 4]);
            let planes: Vec<(DVec3, DVec3)> = (0..4)
                .map(|_| (cube().normalize(), cube() * half))
                .collect();
            for (lane, &(n, corner)) in planes.iter().enumerate() {
                rows.put(lane, n, corner, half);
            }
            let p = cube() * 4.0 * half;
            let p32 = p.as_vec3().to_array().map(Vec4::splat);
            let heights =
                rows.scaled_height(&p32, Vec4::splat((2.0 * half) as f32)) / EDGE_UNITS as f32;
            for (lane, &(n, corner)) in planes.iter().enumerate() {
                let error = (heights[lane] as f64 - n.dot(p - corner)).abs();
                let bound = 2.7e-5 * p.length() + 3.1e-5 * half + 1e-6 * (p.length() + half);
                assert!(
                    error <= bound,
                    "{error} m above {bound} m at {p}, plane {n} through {corner}"
                );
                worst = worst.max(error / bound);
            }
        }
        // The rows are quantised, not exact: the error takes a visible share of the bound.
        assert!(worst > 0.1, "worst error only {worst} of the bound");
    }

    #[test]
    fn a_walk_leaves_a_facet_across_the_edge_the_ray_passes_farthest_beyond() {
        // Seen along +z (whose frame keeps x and y): a long edge on y = 0, a short one on
        // x = 0. A ray 0.3 below the long edge and 0.5 left of the short one passes
        // farther beyond the short edge, although its edge function (the distance times
        // the edge's length) is six times larger on the long one.
        let seen = [
            DVec3::ZERO,
            DVec3::new(10.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ];
        let ray_at = |x, y| {
            let origin = DVec3::new(x, y, -1.0);
            Exact::new(origin, RayFrame::new(DVec3::Z), (0.0, 2.0), [u32::MAX; 2])
        };
        assert_eq!(Bvh::edge_passed(&ray_at(-0.5, -0.3), &seen), Some(2));
        assert_eq!(Bvh::edge_passed(&ray_at(-0.2, -0.3), &seen), Some(0));
        // Beyond the long slanted edge from (10, 0) to (0, 1) alone.
        assert_eq!(Bvh::edge_passed(&ray_at(6.0, 0.5), &seen), Some(1));
        assert_eq!(Bvh::edge_passed(&ray_at(0.5, 0.2), &seen), None);
        // Wound the other way round, the same edges by their new numbers.
        let reversed = [seen[0], seen[2], seen[1]];
        assert_eq!(Bvh::edge_passed(&ray_at(-0.5, -0.3), &reversed), Some(0));
        assert_eq!(Bvh::edge_passed(&ray_at(-0.2, -0.3), &reversed), Some(2));
        // Seen edge-on: no way on.
        let edge_on = [DVec3::ZERO, DVec3::X, DVec3::new(2.0, 0.0, 1.0)];
        assert_eq!(Bvh::edge_passed(&ray_at(0.5, -1.0), &edge_on), None);
    }

    #[test]
    fn a_single_facet_tree_blocks_only_what_crosses_it() {
        // The root is a leaf; the pair's other child must never be entered.
        let raw = RawMesh {
            vertices: vec![DVec3::ZERO, DVec3::X, DVec3::Y],
            triangles: vec![[0, 1, 2]],
        };
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let none = [u32::MAX; 2];
        let (above, below) = (DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, -1.0));
        assert!(bvh.segment_blocked(above, below, none, 1e-9));
        assert!(!bvh.segment_blocked(above + DVec3::X, below + DVec3::X, none, 1e-9));
        for d in [DVec3::X, DVec3::Y, DVec3::Z, DVec3::NEG_Z] {
            assert!(!bvh.segment_blocked(DVec3::splat(5.0), DVec3::splat(5.0) + d, none, 1e-9));
        }
    }

    #[test]
    fn segments_through_shared_edges_and_vertices_are_blocked() {
        // A flat grid at z = 0: vertical and oblique segments through grid lines, shared
        // diagonals and vertices must hit (the predicate is watertight).
        let mut raw = RawMesh::default();
        let n = 8u32;
        for y in 0..=n {
            for x in 0..=n {
                raw.vertices.push(DVec3::new(x as f64, y as f64, 0.0));
            }
        }
        for y in 0..n {
            for x in 0..n {
                let k = y * (n + 1) + x;
                raw.triangles.push([k, k + 1, k + n + 2]);
                raw.triangles.push([k, k + n + 2, k + n + 1]);
            }
        }
        let mesh = Mesh::from_raw(raw, LengthUnit::M);
        let bvh = Bvh::build(&mesh);
        let none = [u32::MAX; 2];
        for (x, y) in [(3.0, 4.0), (3.5, 4.0), (3.0, 4.5), (3.5, 3.5), (1.25, 1.25)] {
            let through = DVec3::new(x, y, 0.0);
            for tilt in [
                DVec3::ZERO,
                DVec3::new(0.3, -0.2, 0.0),
                DVec3::new(1.0, 1.0, 0.0),
            ] {
                let a = through + tilt + DVec3::Z;
                let b = through - tilt - DVec3::Z;
                assert!(
                    bvh.segment_blocked(a, b, none, 1e-9),
                    "through ({x}, {y}), tilt {tilt}"
                );
            }
        }
        // Parallel to the grid just above it: nothing.
        let (a, b) = (DVec3::new(0.5, 4.0, 1e-6), DVec3::new(7.5, 4.0, 1e-6));
        assert!(!bvh.segment_blocked(a, b, none, 1e-9));
        // Along grid lines and axes, in the grid's plane and across it: as the exact
        // predicate over every facet says (axis-parallel directions give 0·∞ in the box
        // tests).
        for (a, b) in [
            (DVec3::new(0.0, 4.0, 0.0), DVec3::new(8.0, 4.0, 0.0)),
            (DVec3::new(3.0, -1.0, 0.0), DVec3::new(3.0, 9.0, 0.0)),
            (DVec3::new(0.0, 0.0, 0.0), DVec3::new(8.0, 8.0, 0.0)),
            (DVec3::new(2.0, 2.0, -1.0), DVec3::new(2.0, 2.0, 1.0)),
            (DVec3::new(8.0, 0.0, -1.0), DVec3::new(8.0, 0.0, 1.0)),
            (DVec3::new(8.0, 3.0, 0.5), DVec3::new(8.0, 3.0, -0.5)),
        ] {
            assert_eq!(
                bvh.segment_blocked(a, b, none, 1e-9),
                brute_force(&mesh, a, b, 1e-9),
                "{a} → {b}"
            );
        }
    }
}
