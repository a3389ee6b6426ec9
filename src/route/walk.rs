//! A route walked: the actions of a plan, or waypoints given by a user, turned into legs
//! with their times, energy, charge, darkness and cost.
//!
//! In: a [`Model`], the start facet and quantum, and the actions ([`Route::walk`]) or
//! waypoints ([`evaluate`]: between two waypoints the rover drives the shortest chain of
//! neighbouring facets, then waits until the next waypoint's departure, if it has one).
//! Out: a [`Route`]: legs (drives merged per facet pair, waits merged per stay), the
//! facets visited with arrival epochs (TDB s), and totals. Evaluation never refuses a
//! route for breaking the rover's limits: it reports them (`feasible`, the steepest
//! facet, the least charge).

use super::model::{Action, CostParts, Model, State};

/// A stop on a given route: a facet, and optionally the quantum before which the rover
/// does not leave it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Waypoint {
    pub facet: u32,
    pub depart_quantum: Option<u32>,
}

/// What the rover does between two epochs.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Leg {
    /// "drive" or "wait".
    pub kind: &'static str,
    pub from_facet: u32,
    pub to_facet: u32,
    /// Epochs at its start and end, TDB s.
    pub start_tdb_s: f64,
    pub end_tdb_s: f64,
    /// Energy the panel gave, Wh.
    pub energy_wh: f64,
    /// Charge at its end, Wh.
    pub charge_wh: f64,
    /// Time with no light on the panel, s.
    pub dark_s: f64,
}

/// A route with its totals.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Route {
    /// The facets in the order visited (the start first).
    pub facets: Vec<u32>,
    /// When the rover reaches each of them (the departure for the first), TDB s.
    pub arrive_tdb_s: Vec<f64>,
    /// Charge on arrival at each of them, Wh.
    pub charge_wh: Vec<f64>,
    pub legs: Vec<Leg>,
    pub distance_m: f64,
    pub driving_s: f64,
    pub waiting_s: f64,
    pub energy_wh: f64,
    /// Time with no light on the panel, s, and its longest stretch.
    pub dark_s: f64,
    pub longest_dark_s: f64,
    /// The least charge at the end of any quantum, Wh (below 0: load not served).
    pub min_charge_wh: f64,
    /// The steepest facet entered, degrees.
    pub steepest_deg: f64,
    /// No facet steeper than the limit entered and the charge never below the minimum.
    pub feasible: bool,
    pub cost: CostParts,
    /// Quanta per step and their length, s.
    pub substeps: u32,
    pub quantum_s: f64,
}

impl Route {
    /// The route of `actions` from `from` at quantum `depart`, or why it cannot be walked
    /// (an action after the window's end, a move to a facet that is not a neighbour).
    pub fn walk(
        model: &Model,
        from: u32,
        depart: u32,
        actions: impl IntoIterator<Item = Action>,
    ) -> Result<Route, String> {
        let mut state = model.start(from, depart);
        let mut route = Route::starting(model, &state);
        let (mut dark_run, mut longest) = (0.0f64, 0.0f64);
        for action in actions {
            if let Action::Move(g) = action {
                if !model.terrain.neighbours[state.facet as usize].contains(&g) {
                    return Err(format!("facet {g} is not a neighbour of {}", state.facet));
                }
            }
            let outcome = model
                .apply_seeing(&state, action, |lit| {
                    dark_run = if lit {
                        0.0
                    } else {
                        dark_run + model.quantum_s()
                    };
                    longest = longest.max(dark_run);
                })
                .ok_or_else(|| {
                    format!(
                        "the route runs past the window's end (at {:.0} s after its start)",
                        f64::from(state.quantum) * model.quantum_s()
                    )
                })?;
            route.add(model, &state, action, &outcome);
            state = outcome.state;
        }
        route.longest_dark_s = longest;
        Ok(route)
    }

    fn starting(model: &Model, s: &State) -> Route {
        Route {
            facets: vec![s.facet],
            arrive_tdb_s: vec![model.epoch(s.quantum)],
            charge_wh: vec![s.charge_wh],
            legs: Vec::new(),
            distance_m: 0.0,
            driving_s: 0.0,
            waiting_s: 0.0,
            energy_wh: 0.0,
            dark_s: 0.0,
            longest_dark_s: 0.0,
            min_charge_wh: s.charge_wh,
            steepest_deg: model.terrain.slope_deg[s.facet as usize],
            feasible: model.allowed(s.facet),
            cost: CostParts::default(),
            substeps: model.substeps,
            quantum_s: model.quantum_s(),
        }
    }

    /// Adds what `action` from `from` did (`o`).
    fn add(&mut self, model: &Model, from: &State, action: Action, o: &super::model::Outcome) {
        let seconds = f64::from(o.quanta) * model.quantum_s();
        let kind = match action {
            Action::Wait => {
                self.waiting_s += seconds;
                "wait"
            }
            Action::Move(g) => {
                self.driving_s += seconds;
                self.distance_m += model.terrain.distance_m(from.facet, g);
                self.facets.push(g);
                self.arrive_tdb_s.push(model.epoch(o.state.quantum));
                self.charge_wh.push(o.state.charge_wh);
                self.steepest_deg = self.steepest_deg.max(model.terrain.slope_deg[g as usize]);
                self.feasible &= model.allowed(g);
                "drive"
            }
        };
        self.energy_wh += o.energy_wh;
        self.dark_s += o.dark_s;
        self.min_charge_wh = self.min_charge_wh.min(o.lowest_wh);
        self.feasible &= model.keeps_charge(o);
        self.cost.add(&o.cost);
        let end = model.epoch(o.state.quantum);
        match self.legs.last_mut() {
            // Waits in a row are one stay.
            Some(last) if kind == "wait" && last.kind == "wait" => {
                last.end_tdb_s = end;
                last.energy_wh += o.energy_wh;
                last.charge_wh = o.state.charge_wh;
                last.dark_s += o.dark_s;
            }
            _ => self.legs.push(Leg {
                kind,
                from_facet: from.facet,
                to_facet: o.state.facet,
                start_tdb_s: model.epoch(from.quantum),
                end_tdb_s: end,
                energy_wh: o.energy_wh,
                charge_wh: o.state.charge_wh,
                dark_s: o.dark_s,
            }),
        }
    }
}

/// The route through `waypoints` (at least two) departing at quantum `depart`: between
/// two of them the shortest chain of neighbouring facets, whatever their slope; then a
/// wait until the next one's departure quantum, when it has one.
pub fn evaluate(model: &Model, waypoints: &[Waypoint], depart: u32) -> Result<Route, String> {
    let Some((first, rest)) = waypoints.split_first().filter(|(_, rest)| !rest.is_empty()) else {
        return Err("give at least two waypoints".into());
    };
    // Runs of one action: a long wait is one entry, not one per quantum.
    let mut runs: Vec<(Action, u32)> = Vec::new();
    let mut quantum = depart;
    let mut at = first.facet;
    let mut hold = first.depart_quantum;
    for (i, w) in rest.iter().enumerate() {
        runs.push((Action::Wait, hold.unwrap_or(0).saturating_sub(quantum)));
        quantum = quantum.max(hold.unwrap_or(0));
        let chain = shortest_chain(model, at, w.facet).ok_or_else(|| {
            format!(
                "waypoint {} (facet {}) cannot be reached from facet {at} over the mesh",
                i + 1,
                w.facet
            )
        })?;
        for pair in chain.windows(2) {
            quantum = quantum.saturating_add(model.move_quanta(pair[0], pair[1]));
            runs.push((Action::Move(pair[1]), 1));
        }
        at = w.facet;
        hold = w.depart_quantum;
    }
    let actions = runs
        .into_iter()
        .flat_map(|(action, n)| std::iter::repeat_n(action, n as usize));
    Route::walk(model, first.facet, depart, actions)
}

/// The shortest chain of neighbouring facets from `a` to `b` by centroid distance,
/// both ends included.
fn shortest_chain(model: &Model, a: u32, b: u32) -> Option<Vec<u32>> {
    let t = model.terrain;
    let (distance, parent) = t.dijkstra(a, |f, g| Some(t.distance_m(f, g)));
    if distance[b as usize].is_infinite() {
        return None;
    }
    let mut chain = vec![b];
    while *chain.last()? != a {
        chain.push(parent[*chain.last()? as usize]);
    }
    chain.reverse();
    Some(chain)
}

#[cfg(test)]
mod tests {
    use super::super::model::{Rover, Weights};
    use super::super::{Light, Terrain};
    use super::*;
    use crate::mesh::generate::height_field;
    use crate::mesh::{LengthUnit, Mesh};
    use crate::panel::Battery;

    /// A flat strip of 10 m cells, lit at `e` W/m² everywhere and always.
    fn strip(cells: usize, steps: usize, e: f32) -> (Terrain, Light) {
        let raw = height_field(
            (cells, 1),
            (0.0, 10.0 * cells as f64),
            (0.0, 10.0),
            |_, _| 1.0e6,
        );
        let terrain = Terrain::new(&Mesh::from_raw(raw, LengthUnit::M));
        let n = terrain.len();
        let epochs = (0..steps).map(|k| 3600.0 * k as f64).collect();
        let light = Light::new(
            n,
            0,
            3600.0,
            epochs,
            vec![1361.0; steps],
            vec![e; n * steps],
        )
        .unwrap();
        (terrain, light)
    }

    fn rover() -> Rover {
        Rover {
            speed_m_s: 0.01,
            max_slope_deg: 20.0,
            panel_area_m2: 2.0,
            panel_efficiency: 0.25,
            battery: Battery::checked(500.0, Some(250.0), 0.9, 1.0).unwrap(),
            min_charge_wh: 50.0,
            idle_load_w: 10.0,
            drive_load_w: 60.0,
        }
    }

    /// On flat, evenly lit ground the totals follow from the speed and loads by hand:
    /// the energy is η·A·E times the time, the charge changes at the net rate.
    #[test]
    fn evaluated_totals_match_the_hand_computation() {
        let (terrain, light) = strip(6, 48, 400.0);
        let model = Model::new(&terrain, &light, rover(), Weights::default(), Some(12)).unwrap();
        let (a, b) = (0u32, (terrain.len() - 1) as u32);
        let route = evaluate(
            &model,
            &[
                Waypoint {
                    facet: a,
                    depart_quantum: Some(24),
                },
                Waypoint {
                    facet: b,
                    depart_quantum: None,
                },
            ],
            0,
        )
        .unwrap();
        let power = 0.25 * 2.0 * 400.0; // 200 W
        let total_s = route.driving_s + route.waiting_s;
        assert!((route.waiting_s - 24.0 * 300.0).abs() < 1e-9);
        assert!((route.energy_wh - power * total_s / 3600.0).abs() < 1e-9);
        // Surplus while waiting (190 W × 0.9) fills the battery to its capacity; then it
        // gains (200 − 60) × 0.9 W while driving, still full.
        assert!((route.charge_wh.last().unwrap() - 500.0).abs() < 1e-9);
        assert_eq!(route.dark_s, 0.0);
        assert!(route.feasible);
        // Each drive takes whole quanta at no more than the speed.
        assert!(route.distance_m / route.driving_s <= 0.01 + 1e-12);
        // The chain is the straight one along the strip: its length is at most the
        // strip's centroid span plus the zigzag of the two-triangle cells.
        assert!(route.distance_m >= terrain.distance_m(a, b) - 1e-9);
        assert_eq!(
            route.cost.illumination,
            route.distance_m * (1.0 - 400.0 / 1361.0)
        );
    }

    /// In the dark the battery drains at the drive load and the route reports the
    /// charge falling below the minimum instead of refusing.
    #[test]
    fn a_route_in_darkness_reports_the_drained_battery() {
        let (terrain, light) = strip(6, 48, 0.0);
        let model = Model::new(&terrain, &light, rover(), Weights::default(), Some(12)).unwrap();
        let route = evaluate(
            &model,
            &[
                Waypoint {
                    facet: 0,
                    depart_quantum: Some(30),
                },
                Waypoint {
                    facet: 11,
                    depart_quantum: None,
                },
            ],
            0,
        )
        .unwrap();
        // 30 quanta of 300 s idle at 10 W: 25 Wh; then driving at 60 W.
        let expected = 250.0 - 25.0 - 60.0 * route.driving_s / 3600.0;
        assert!((route.min_charge_wh - expected).abs() < 1e-9);
        assert_eq!(route.dark_s, route.driving_s + route.waiting_s);
        assert_eq!(route.longest_dark_s, route.dark_s);
        assert_eq!(route.feasible, expected >= 50.0);
    }

    #[test]
    fn a_route_past_the_window_is_an_error() {
        let (terrain, light) = strip(6, 2, 100.0);
        let model = Model::new(&terrain, &light, rover(), Weights::default(), Some(1)).unwrap();
        let waypoints = [0, 11].map(|facet| Waypoint {
            facet,
            depart_quantum: None,
        });
        let err = evaluate(&model, &waypoints, 0).unwrap_err();
        assert!(err.contains("window"), "{err}");
    }
}
