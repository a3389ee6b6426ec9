//! Which facets see each other, and the exchange-area blocks built from them.
//!
//! In: the facets of one body (its own block) or of two bodies with the transform between
//! their frames (an inter-body block), and every body's [`Bvh`] as occluders. Out: [`Csr`]
//! blocks of exchange areas `G_ij = A_i F_ij` (m²).
//!
//! A pair is a candidate when each centroid lies strictly in front of the other facet's
//! plane. It is visible when the segment between the two centroids crosses no other
//! facet of any body (the shared exact ray predicate; the two end facets are skipped and
//! hits closer than a rounding margin to either end are ignored). Visibility is thus
//! all-or-nothing per pair, decided at the centroids: a pair half hidden behind a third
//! facet counts fully or not at all, an error that shrinks with the facet size. Each
//! unordered pair is evaluated once, so a body's block is symmetric by construction.

use super::csr::Csr;
use super::form_factor::{exchange_area, Facet, NearField};
use crate::mesh::Mesh;
use crate::trace::bvh::Bvh;
use crate::world::FrameTransform;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// A body that can hide one facet from another: its tree and the transform from the
/// frame the pairs are computed in to its own frame.
pub struct Occluder<'a> {
    pub bvh: &'a Bvh<'a>,
    pub to_own: FrameTransform,
    /// This body holds the pair's row facet (skipped as an occluder of its own pair).
    pub holds_rows: bool,
    /// This body holds the pair's column facet.
    pub holds_cols: bool,
}

/// The facets of a mesh, mapped by `transform` into the frame of the computation.
pub fn facets(mesh: &Mesh, transform: &FrameTransform) -> Vec<Facet> {
    (0..mesh.len())
        .map(|i| Facet::new(mesh.corners(i).map(|p| transform.point(p))))
        .collect()
}

/// The identity transform.
pub const SAME_FRAME: FrameTransform = FrameTransform {
    rotation: DMat3::IDENTITY,
    offset_m: DVec3::ZERO,
};

/// A body's own block: symmetric, zero diagonal.
pub fn own_block(mesh: &Mesh, bvh: &Bvh, near: &NearField) -> Csr {
    let f = facets(mesh, &SAME_FRAME);
    let occluders = [Occluder {
        bvh,
        to_own: SAME_FRAME,
        holds_rows: true,
        holds_cols: true,
    }];
    let margin = rounding_margin(&f);
    let planes = planes(&f);
    let upper: Vec<Vec<(u32, f32)>> = (0..f.len())
        .into_par_iter()
        .map(|i| {
            let others = Partners {
                facets: &f[i + 1..],
                planes: &planes[i + 1..],
                first: i + 1,
            };
            visible_row(&f[i], i, &others, &occluders, margin, near)
        })
        .collect();
    Csr::symmetric_from_upper(&upper)
}

/// The block between body `rows` (facets in the computation frame) and body `cols`
/// (facets already mapped into the same frame).
pub fn cross_block(
    rows: &[Facet],
    cols: &[Facet],
    occluders: &[Occluder],
    near: &NearField,
) -> Csr {
    let margin = rounding_margin(rows).max(rounding_margin(cols));
    let others = Partners {
        facets: cols,
        planes: &planes(cols),
        first: 0,
    };
    let lists: Vec<Vec<(u32, f32)>> = (0..rows.len())
        .into_par_iter()
        .map(|i| visible_row(&rows[i], i, &others, occluders, margin, near))
        .collect();
    Csr::from_rows(&lists, cols.len())
}

/// A facet's plane as the mutual-facing test reads it, packed apart from the rest of
/// [`Facet`] because every row scans all of them.
#[derive(Clone, Copy)]
struct Plane {
    centroid: DVec3,
    normal: DVec3,
    /// `normal · centroid` (m); zero-area facets get +∞, so nothing is in front of them.
    offset: f64,
}

fn planes(facets: &[Facet]) -> Vec<Plane> {
    facets
        .iter()
        .map(|f| Plane {
            centroid: f.centroid,
            normal: f.normal,
            offset: if f.area > 0.0 {
                f.normal.dot(f.centroid)
            } else {
                f64::INFINITY
            },
        })
        .collect()
}

/// The candidate partners of a row: facets with their planes, ids from `first`.
struct Partners<'a> {
    facets: &'a [Facet],
    planes: &'a [Plane],
    first: usize,
}

/// The visible partners of facet `a` (id `ia` in the row body) among `others`, with
/// their exchange areas.
fn visible_row(
    a: &Facet,
    ia: usize,
    others: &Partners,
    occluders: &[Occluder],
    margin: f64,
    near: &NearField,
) -> Vec<(u32, f32)> {
    if a.area <= 0.0 {
        return Vec::new();
    }
    let front = a.normal.dot(a.centroid);
    let mut row = Vec::new();
    for (k, p) in others.planes.iter().enumerate() {
        if !face_each_other(a, front, p) {
            continue;
        }
        let (ib, b) = (others.first + k, &others.facets[k]);
        if occluders
            .iter()
            .any(|o| hides(o, a.centroid, b.centroid, [ia, ib], margin))
        {
            continue;
        }
        let g = exchange_area(a, b, near);
        if g > 0.0 {
            row.push((ib as u32, g as f32));
        }
    }
    // Rows wait for the whole block before they are packed: drop the growth slack.
    row.shrink_to_fit();
    row
}

/// Whether facet `a` (`front` = its `normal · centroid`) and the facet of plane `p` each
/// have the other's centroid strictly in front: the candidates for a visible pair.
fn face_each_other(a: &Facet, front: f64, p: &Plane) -> bool {
    a.normal.dot(p.centroid) > front && p.normal.dot(a.centroid) > p.offset
}

/// Rows sampled by [`facing_pairs`]: enough for a mean within a few per cent on the
/// shipped shapes, few enough that the estimate costs far less than the block.
const SAMPLE_ROWS: usize = 128;

/// The pairs of `rows` × `cols` (facets in one frame) that face each other, estimated from
/// at most `SAMPLE_ROWS` (128) evenly spaced rows. Occlusion only removes pairs, so this
/// bounds the entries of the block from above (up to the sampling). With `own`, rows and
/// columns are one body's facets and each unordered pair counts once.
pub fn facing_pairs(rows: &[Facet], cols: &[Facet], own: bool) -> f64 {
    if rows.is_empty() {
        return 0.0;
    }
    let planes = planes(cols);
    let sampled: Vec<&Facet> = rows
        .iter()
        .step_by(rows.len().div_ceil(SAMPLE_ROWS))
        .collect();
    let facing: usize = sampled
        .par_iter()
        .filter(|a| a.area > 0.0)
        .map(|a| {
            let front = a.normal.dot(a.centroid);
            planes
                .iter()
                .filter(|p| face_each_other(a, front, p))
                .count()
        })
        .sum();
    let pairs = facing as f64 / sampled.len() as f64 * rows.len() as f64;
    if own {
        pairs / 2.0
    } else {
        pairs
    }
}

fn hides(o: &Occluder, a: DVec3, b: DVec3, ends: [usize; 2], margin: f64) -> bool {
    let skip = [
        if o.holds_rows {
            ends[0] as u32
        } else {
            u32::MAX
        },
        if o.holds_cols {
            ends[1] as u32
        } else {
            u32::MAX
        },
    ];
    o.bvh
        .segment_blocked(o.to_own.point(a), o.to_own.point(b), skip, margin)
}

/// Hits closer than this to a segment's ends are the end facets' own neighbours meeting
/// them at a shared edge, not occluders: `1e-9 ×` the largest facet plus the rounding of
/// coordinates of the facets' magnitude.
pub(super) fn rounding_margin(facets: &[Facet]) -> f64 {
    let size = facets.iter().map(|f| f.size).fold(0.0, f64::max);
    let extent = facets
        .iter()
        .map(|f| f.centroid.abs().max_element())
        .fold(0.0, f64::max);
    1e-9 * size + 256.0 * f64::EPSILON * extent
}
