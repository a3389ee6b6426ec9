//! Planning: the cheapest feasible route between two facets, waiting where it pays.
//!
//! In: a [`Model`], the start and goal facets and the departure quantum. Out: the
//! actions of the cheapest route (by [`Model::apply`]'s cost) that enters no facet
//! steeper than the rover's limit and keeps the charge at or above its minimum, or why
//! there is none.
//!
//! The search is A* over labels (facet, quantum, charge, cost): states are
//! (facet, quantum), so waiting and driving at different times are different states and
//! the light of each quantum is exact. The heuristic is the cheapest cost to the goal
//! over the facet graph with every move at its least cost over the window (each facet at
//! its brightest step; slope, roughness and distance do not change in time), found once
//! by Dijkstra from the goal. It never exceeds the cost left and is consistent, so labels
//! leave the queue in order of cost at each state, and facets that cannot reach the goal
//! are never entered. A label is dropped when one already taken
//! at its state holds at least as much charge: from the same facet at the same time,
//! more charge can do everything less charge can (the battery's update is monotone in
//! the charge, and costs do not depend on it). The first goal label taken is therefore
//! the cheapest feasible route; the tests check this against exhaustive search.

use super::model::{Action, Model, State};
use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};

/// How far the search may go, and how close to the cheapest route it must come.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchLimits {
    /// Most labels taken from the queue before giving up.
    pub max_labels: usize,
    /// The route found may cost up to `1 + gap` times the cheapest (0: the cheapest).
    /// The heuristic is weighted by `1 + gap` (weighted A*): far fewer labels on long
    /// routes, where light changes often.
    pub gap: f64,
}

impl Default for SearchLimits {
    fn default() -> SearchLimits {
        SearchLimits {
            max_labels: 4_000_000,
            gap: 0.0,
        }
    }
}

/// Bytes per label at most: the taken record (12 B), its map slot (about 24 B) and up
/// to four queued successors (48 B each). About 35 B were measured on Eros, where most
/// successors are dropped before they are queued.
pub const BYTES_PER_LABEL: u64 = 240;

/// A label waiting in the queue.
#[derive(Debug, Clone, Copy)]
struct Queued {
    /// Cost so far plus the heuristic.
    key: f64,
    state: State,
    /// Index of the taken label it came from (`u32::MAX`: the start).
    parent: u32,
    action: Action,
}

impl PartialEq for Queued {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Queued {
    /// Reversed for the max-heap: least key first; on ties more charge, then earlier,
    /// then the lower facet, so the route does not depend on the queue's history.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .key
            .total_cmp(&self.key)
            .then(self.state.charge_wh.total_cmp(&other.state.charge_wh))
            .then(other.state.quantum.cmp(&self.state.quantum))
            .then(other.state.facet.cmp(&self.state.facet))
    }
}

/// A plan found: its actions and the labels the search took.
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    pub actions: Vec<Action>,
    pub labels: usize,
}

/// A label taken from the queue.
struct Taken {
    parent: u32,
    action: Action,
}

/// The cheapest feasible route from `from` to `to` departing at quantum
/// `depart`, or why there is none.
pub fn plan(
    model: &Model,
    from: u32,
    to: u32,
    depart: u32,
    limits: SearchLimits,
) -> Result<Found, String> {
    let terrain = model.terrain;
    let bound = least_costs_to(model, to);
    let weight = 1.0 + limits.gap;
    let heuristic = |f: u32| bound[f as usize];
    if heuristic(from).is_infinite() {
        return Err(format!(
            "no chain of facets from facet {from} to facet {to} avoids slopes steeper than \
             {}°: allow steeper slopes or choose other places",
            model.rover.max_slope_deg
        ));
    }
    let mut queue = BinaryHeap::new();
    let start = model.start(from, depart);
    queue.push(Queued {
        key: weight * heuristic(from),
        state: start,
        parent: u32::MAX,
        action: Action::Wait,
    });
    // The most charge taken at each (facet, quantum).
    let mut best: HashMap<u64, f64> = HashMap::new();
    let mut taken: Vec<Taken> = Vec::new();
    let mut dropped = Dropped::default();
    while let Some(label) = queue.pop() {
        let s = label.state;
        let slot = best.entry(state_key(&s)).or_insert(f64::NEG_INFINITY);
        if s.charge_wh <= *slot {
            continue;
        }
        *slot = s.charge_wh;
        if taken.len() >= limits.max_labels {
            return Err(format!(
                "the search took {} labels without reaching the goal: allow an optimality \
                 gap (0.3 or more takes orders of magnitude fewer labels on long routes), \
                 raise max_labels, or use fewer substeps",
                limits.max_labels
            ));
        }
        let index = taken.len() as u32;
        taken.push(Taken {
            parent: label.parent,
            action: label.action,
        });
        if s.facet == to {
            return Ok(Found {
                actions: actions_to(&taken, index),
                labels: taken.len(),
            });
        }
        let moves = terrain.neighbours[s.facet as usize]
            .iter()
            .filter(|&&g| model.allowed(g))
            .map(|&g| Action::Move(g));
        for action in std::iter::once(Action::Wait).chain(moves) {
            let Some(outcome) = model.apply(&s, action) else {
                dropped.past_window += 1;
                continue;
            };
            if !model.keeps_charge(&outcome) {
                dropped.low_charge += 1;
                continue;
            }
            let next = outcome.state;
            if heuristic(next.facet).is_infinite() {
                continue;
            }
            if best
                .get(&state_key(&next))
                .is_some_and(|&c| next.charge_wh <= c)
            {
                continue;
            }
            queue.push(Queued {
                key: next.cost + weight * heuristic(next.facet),
                state: next,
                parent: index,
                action,
            });
        }
    }
    Err(no_route_message(model, &dropped))
}

/// Actions the search could not take, for the message when no route is found.
#[derive(Debug, Default)]
struct Dropped {
    /// Would have ended after the window's last step.
    past_window: u64,
    /// Would have taken the charge below the minimum.
    low_charge: u64,
}

/// Per facet, the least cost from it to `goal` with every move at its least cost over
/// the window (infinite where the goal cannot be reached): moves into facets the rover
/// may enter, each at the light of both facets' brightest steps.
fn least_costs_to(model: &Model, goal: u32) -> Vec<f64> {
    let brightest: Vec<f64> = (0..model.terrain.len() as u32)
        .map(|f| model.brightest(f))
        .collect();
    // From the goal backwards: settled `g`, a move from neighbour `f` into it.
    let (cost, _) = model.terrain.dijkstra(goal, |g, f| {
        let light = 0.5 * (brightest[f as usize] + brightest[g as usize]);
        model
            .allowed(g)
            .then(|| model.move_cost(f, g, (1.0 - light).max(0.0)).total())
    });
    cost
}

fn state_key(s: &State) -> u64 {
    (u64::from(s.facet) << 32) | u64::from(s.quantum)
}

/// The actions from the start to taken label `last`, in order.
fn actions_to(taken: &[Taken], last: u32) -> Vec<Action> {
    let mut actions = Vec::new();
    let mut at = last;
    while taken[at as usize].parent != u32::MAX {
        actions.push(taken[at as usize].action);
        at = taken[at as usize].parent;
    }
    actions.reverse();
    actions
}

fn no_route_message(model: &Model, dropped: &Dropped) -> String {
    let r = &model.rover;
    format!(
        "no route reaches the goal by the window's end that enters no facet steeper than \
         {}° and keeps the charge at or above {} Wh ({} actions would have taken the charge \
         below it, {} would have ended after the window): depart earlier, allow steeper \
         slopes, or give the rover more battery, panel or speed",
        r.max_slope_deg, r.min_charge_wh, dropped.low_charge, dropped.past_window
    )
}

#[cfg(test)]
mod tests {
    use super::super::model::{Rover, Weights};
    use super::super::{Light, Terrain};
    use super::*;
    use crate::mesh::generate::height_field;
    use crate::mesh::{LengthUnit, Mesh};
    use crate::panel::Battery;

    /// A small bumpy patch far out along +z (so "up" is +z), 2 × 3 cells of 10 m.
    fn patch() -> Terrain {
        let raw = height_field((3, 2), (0.0, 30.0), (0.0, 20.0), |x, y| {
            1.0e6 + 0.3 * x + 2.0 * ((x * 0.7).sin() * (y * 0.5).cos())
        });
        Terrain::new(&Mesh::from_raw(raw, LengthUnit::M))
    }

    /// A pseudo-random light table: some facets dark at some steps.
    fn light(facets: usize, steps: usize, seed: u64) -> Light {
        let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut next = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 33) as f64 / (1u64 << 31) as f64
        };
        let values = (0..facets * steps)
            .map(|_| {
                let u = next();
                if u < 0.35 {
                    0.0
                } else {
                    (1000.0 * u) as f32
                }
            })
            .collect();
        let epochs = (0..steps).map(|k| 100.0 * k as f64).collect();
        Light::new(facets, 0, 100.0, epochs, vec![1000.0; steps], values).unwrap()
    }

    fn rover(capacity_wh: f64, min_charge_wh: f64) -> Rover {
        Rover {
            speed_m_s: 0.12,
            max_slope_deg: 25.0,
            panel_area_m2: 1.0,
            panel_efficiency: 0.3,
            battery: Battery::checked(capacity_wh, Some(0.7 * capacity_wh), 0.9, 0.95).unwrap(),
            min_charge_wh,
            idle_load_w: 40.0,
            drive_load_w: 150.0,
        }
    }

    /// The least cost of any feasible action sequence from `s` that reaches `to`, by
    /// trying every one (the same rules as the planner: no facet over the slope limit,
    /// no quantum below the minimum charge, the window's end).
    fn exhaustive(model: &Model, s: State, to: u32) -> f64 {
        if s.facet == to {
            return s.cost;
        }
        let mut best = f64::INFINITY;
        let moves = model.terrain.neighbours[s.facet as usize]
            .iter()
            .filter(|&&g| model.allowed(g))
            .map(|&g| Action::Move(g));
        for action in std::iter::once(Action::Wait).chain(moves) {
            if let Some(o) = model.apply(&s, action) {
                if model.keeps_charge(&o) {
                    best = best.min(exhaustive(model, o.state, to));
                }
            }
        }
        best
    }

    /// The cost and feasibility of `actions` replayed from the start.
    fn replay(model: &Model, from: u32, actions: &[Action]) -> (State, bool) {
        let mut s = model.start(from, 0);
        let mut ok = true;
        for &a in actions {
            let o = model.apply(&s, a).expect("within the window");
            ok &= model.keeps_charge(&o);
            if let Action::Move(g) = a {
                ok &= model.allowed(g) && model.terrain.neighbours[s.facet as usize].contains(&g);
            }
            s = o.state;
        }
        (s, ok)
    }

    #[test]
    fn planned_routes_cost_what_exhaustive_search_finds() {
        let terrain = patch();
        let n = terrain.len() as u32;
        let mut feasible = 0;
        let mut infeasible = 0;
        for seed in 0..24u64 {
            let light = light(terrain.len(), 5, seed);
            // Tight batteries make the charge limit bind in some cases.
            let capacity = [2.0, 4.0, 8.0][seed as usize % 3];
            let model = Model::new(
                &terrain,
                &light,
                rover(capacity, 0.25 * capacity),
                Weights::default(),
                Some(3),
            )
            .unwrap();
            // From one end of the patch to the other, so that routes take several moves.
            let (from, to) = (seed as u32 % 4, n - 1 - (seed as u32 / 4) % 4);
            let best = exhaustive(&model, model.start(from, 0), to);
            match plan(&model, from, to, 0, SearchLimits::default()) {
                Ok(Found { actions, .. }) => {
                    let (end, ok) = replay(&model, from, &actions);
                    assert!(ok, "seed {seed}: the plan breaks a limit");
                    assert_eq!(end.facet, to);
                    let rel = (end.cost - best).abs() / best.max(1.0);
                    assert!(
                        rel < 1e-12,
                        "seed {seed}: planned {} vs best {best}",
                        end.cost
                    );
                    // With a gap, the route is feasible and within its bound.
                    let loose = SearchLimits {
                        gap: 0.5,
                        ..SearchLimits::default()
                    };
                    let found = plan(&model, from, to, 0, loose).unwrap();
                    let (end, ok) = replay(&model, from, &found.actions);
                    assert!(ok && end.facet == to && end.cost <= 1.5 * best * (1.0 + 1e-12));
                    feasible += 1;
                }
                Err(why) => {
                    assert!(best.is_infinite(), "seed {seed}: {why}, but {best} exists");
                    infeasible += 1;
                }
            }
        }
        // Both kinds of case were exercised.
        assert!(feasible >= 5 && infeasible >= 1, "{feasible} {infeasible}");
    }

    /// A goal reachable only after waiting for light: the planner waits, and the route it
    /// finds keeps the charge (without the wait the battery runs out).
    #[test]
    fn waits_to_recharge_when_driving_on_would_empty_the_battery() {
        let raw = height_field((4, 1), (0.0, 40.0), (0.0, 10.0), |_, _| 1.0e6);
        let terrain = Terrain::new(&Mesh::from_raw(raw, LengthUnit::M));
        let facets = terrain.len();
        // Dark for the first two steps, then bright everywhere.
        let steps = 8;
        let values = (0..steps * facets)
            .map(|i| if i / facets < 2 { 0.0 } else { 1000.0 })
            .collect();
        let epochs = (0..steps).map(|k| 600.0 * k as f64).collect();
        let light = Light::new(facets, 0, 600.0, epochs, vec![1000.0; steps], values).unwrap();
        let mut r = rover(10.0, 1.0);
        r.battery.initial_wh = 2.0;
        r.idle_load_w = 0.0;
        let model = Model::new(&terrain, &light, r, Weights::default(), Some(4)).unwrap();
        let actions = plan(&model, 0, (facets - 1) as u32, 0, SearchLimits::default())
            .unwrap()
            .actions;
        assert!(actions.contains(&Action::Wait), "{actions:?}");
        let (end, ok) = replay(&model, 0, &actions);
        assert!(ok && end.facet == (facets - 1) as u32);
    }

    #[test]
    fn refuses_when_the_label_limit_is_reached() {
        let terrain = patch();
        let light = light(terrain.len(), 4, 3);
        let model = Model::new(
            &terrain,
            &light,
            rover(8.0, 0.0),
            Weights::default(),
            Some(3),
        )
        .unwrap();
        let err = plan(
            &model,
            0,
            11,
            0,
            SearchLimits {
                max_labels: 2,
                gap: 0.0,
            },
        )
        .unwrap_err();
        assert!(err.contains("max_labels"), "{err}");
    }
}
