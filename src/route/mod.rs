//! Route: a rover's traverse over a body's facets in time — evaluated, or planned.
//!
//! In: a body's [`Mesh`] (metres, body frame, centre at the origin), the irradiance of
//! each of its facets at each step of a window ([`Light`], W/m², the same values `slim
//! run` computes), a [`Rover`] (speed m/s, slope limit, a panel on its deck, a battery
//! and its loads) and [`Weights`]. Out: a [`Route`] — the facets visited with arrival
//! times, the battery's charge (Wh), energy collected (Wh), darkness met (s) and the cost
//! split by its terms; [`plan`] finds the cheapest route between two facets, [`evaluate`]
//! follows one given by waypoints.
//!
//! ## The model (shared by planning and evaluation)
//! Time runs in *quanta* of `τ = Δt / m` seconds, `Δt` the scene's step and `m` the
//! substeps per step; a quantum's light is its step's. The rover stands on a facet; in
//! each quantum it either *waits* there or is part of a *move* across an edge to a
//! neighbouring facet (facets sharing an edge, [`facet_neighbours`]). A move of length
//! `d` (centroid to centroid) takes `n = ⌈d / (v τ)⌉` quanta, so the rover never goes
//! faster than `v`; during a move its panel gets the mean of the two facets' light.
//!
//! The panel lies on the deck, parallel to the ground: its power is `η A E_f`, with
//! `E_f` the facet's irradiance (direct, and scattered light when the scene has it).
//! The battery follows [`crate::panel::Battery::after`] quantum by quantum with the idle load while
//! waiting and the drive load while moving; a route is feasible when the charge never
//! falls below the rover's `min_charge_wh` at the end of any quantum.
//!
//! Cost, in metres-equivalent (the paper's Fig. 1 weighs illumination, slope and
//! roughness equally, the default here):
//! - a move costs `d · (1 + w_i·D + w_s·S + w_r·R)`: `D` the mean darkness `1 − E/F`
//!   over the move's quanta (F the flux on a surface facing the Sun), `S` the two facets'
//!   mean slope over the slope limit, `R` their mean roughness over the slope limit
//!   (at most 1);
//! - a wait costs `w_wait · v · τ`: an hour of waiting costs what an hour of driving
//!   over flat, smooth, sunlit ground does, at the default weight 1.
//!
//! Slope is the angle between a facet's normal and the vertical: the radial direction
//! through its centroid ([`Terrain::new`]), or the local vertical of the body's gravity
//! and spin ([`gravity::up_vectors`], [`Terrain::with_up`]), which on an elongated body
//! such as Eros differs from the radial by tens of degrees. Roughness is the mean angle
//! between a facet's normal and its neighbours'. A facet steeper than the limit is never
//! entered.

pub mod gravity;
mod light;
mod model;
mod search;
mod walk;

pub use light::Light;
pub use model::{Action, Model, Rover, Weights};
pub use search::{plan, Found, SearchLimits, BYTES_PER_LABEL};
pub use walk::{evaluate, Leg, Route, Waypoint};

use crate::mesh::inspect::facet_neighbours;
use crate::mesh::Mesh;
use glam::DVec3;
use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

/// The facet graph a rover drives on, with each facet's slope and roughness.
#[derive(Debug, Clone)]
pub struct Terrain {
    /// Facet centroids, metres, body frame.
    pub centroids: Vec<DVec3>,
    /// Each facet's neighbours across its edges.
    pub neighbours: Vec<Vec<u32>>,
    /// Angle between each facet's normal and the radial direction, degrees.
    pub slope_deg: Vec<f64>,
    /// Mean angle between each facet's normal and its neighbours' normals, degrees.
    pub roughness_deg: Vec<f64>,
}

impl Terrain {
    /// The terrain of `mesh`, its slopes measured from the radial direction.
    pub fn new(mesh: &Mesh) -> Terrain {
        let radial: Vec<DVec3> = mesh
            .centroids
            .iter()
            .map(|c| c.normalize_or_zero())
            .collect();
        Terrain::with_up(mesh, &radial)
    }

    /// The terrain of `mesh`, its slopes measured from `up` (one unit vector per facet,
    /// e.g. [`gravity::up_vectors`]).
    pub fn with_up(mesh: &Mesh, up: &[DVec3]) -> Terrain {
        let neighbours = facet_neighbours(mesh);
        let angle = |a: DVec3, b: DVec3| a.dot(b).clamp(-1.0, 1.0).acos().to_degrees();
        let slope_deg = up
            .iter()
            .zip(&mesh.normals)
            .map(|(u, n)| angle(*u, *n))
            .collect();
        let roughness_deg = neighbours
            .iter()
            .zip(&mesh.normals)
            .map(|(list, n)| {
                let sum: f64 = list
                    .iter()
                    .map(|&j| angle(*n, mesh.normals[j as usize]))
                    .sum();
                if list.is_empty() {
                    0.0
                } else {
                    sum / list.len() as f64
                }
            })
            .collect();
        Terrain {
            centroids: mesh.centroids.clone(),
            neighbours,
            slope_deg,
            roughness_deg,
        }
    }

    /// Number of facets.
    pub fn len(&self) -> usize {
        self.centroids.len()
    }

    /// True when there are no facets.
    pub fn is_empty(&self) -> bool {
        self.centroids.is_empty()
    }

    /// Distance between the centroids of facets `a` and `b`, metres.
    pub fn distance_m(&self, a: u32, b: u32) -> f64 {
        self.centroids[a as usize].distance(self.centroids[b as usize])
    }

    /// Dijkstra from `source`: per facet the least sum of `cost(settled, neighbour)` over
    /// a chain to it (`None`: that step is not allowed), and the facet before it on that
    /// chain (`u32::MAX` for the source and unreached facets).
    pub fn dijkstra(
        &self,
        source: u32,
        cost: impl Fn(u32, u32) -> Option<f64>,
    ) -> (Vec<f64>, Vec<u32>) {
        let mut best = vec![f64::INFINITY; self.len()];
        let mut parent = vec![u32::MAX; self.len()];
        let mut queue = BinaryHeap::new();
        best[source as usize] = 0.0;
        queue.push(Reverse(Ordered(0.0, source)));
        while let Some(Reverse(Ordered(c, f))) = queue.pop() {
            if c > best[f as usize] {
                continue;
            }
            for &g in &self.neighbours[f as usize] {
                let Some(step) = cost(f, g) else { continue };
                if c + step < best[g as usize] {
                    best[g as usize] = c + step;
                    parent[g as usize] = f;
                    queue.push(Reverse(Ordered(c + step, g)));
                }
            }
        }
        (best, parent)
    }

    /// The median distance between neighbouring centroids, metres (0 without edges).
    pub fn median_edge_m(&self) -> f64 {
        let mut d: Vec<f64> = self
            .neighbours
            .iter()
            .enumerate()
            .flat_map(|(a, list)| list.iter().map(move |&b| (a as u32, b)))
            .filter(|(a, b)| a < b)
            .map(|(a, b)| self.distance_m(a, b))
            .collect();
        if d.is_empty() {
            return 0.0;
        }
        let mid = d.len() / 2;
        *d.select_nth_unstable_by(mid, f64::total_cmp).1
    }
}

/// A cost and a facet, ordered by the cost (`total_cmp`), then the facet.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ordered(f64, u32);
impl Eq for Ordered {}
impl PartialOrd for Ordered {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Ordered {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0).then(self.1.cmp(&other.1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::{height_field, icosphere};
    use crate::mesh::LengthUnit;

    #[test]
    fn every_facet_of_a_closed_sphere_has_three_neighbours() {
        let mesh = Mesh::from_raw(icosphere(2, 1000.0, DVec3::ZERO), LengthUnit::M);
        let terrain = Terrain::new(&mesh);
        assert!(terrain.neighbours.iter().all(|n| n.len() == 3));
        // A neighbour's neighbour list names the facet back.
        for (a, list) in terrain.neighbours.iter().enumerate() {
            for &b in list {
                assert!(terrain.neighbours[b as usize].contains(&(a as u32)));
            }
        }
    }

    /// A plane tilted by 30° about x, lifted far along +z so that the radial direction is
    /// almost +z everywhere: every facet's slope is 30° (to the radial's spread) and its
    /// roughness 0.
    #[test]
    fn slope_and_roughness_of_a_tilted_plane() {
        let tilt = 30f64.to_radians();
        let raw = height_field((4, 4), (-10.0, 10.0), (-10.0, 10.0), |_, y| {
            1.0e7 + y * tilt.tan()
        });
        let terrain = Terrain::new(&Mesh::from_raw(raw, LengthUnit::M));
        for (s, r) in terrain.slope_deg.iter().zip(&terrain.roughness_deg) {
            assert!((s - 30.0).abs() < 1e-3, "slope {s}");
            assert!(r.abs() < 1e-6, "roughness {r}");
        }
        // Interior facets of a grid have 3 neighbours, corner ones fewer.
        assert_eq!(terrain.neighbours.iter().map(Vec::len).max(), Some(3));
    }
}
