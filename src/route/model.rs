//! One action of a rover and what it does: time, energy, charge, darkness and cost.
//!
//! In: the [`Terrain`], the [`Light`] table, a [`Rover`] and [`Weights`]; a [`State`]
//! (facet, quantum, charge Wh, cost) and an [`Action`]. Out: an [`Outcome`] — the state
//! after it, the energy the panel gave (Wh), the time spent in darkness (s), the least
//! charge at the end of any of its quanta (Wh, unbounded below) and its cost by term.
//! The accounting is the module doc's model ([`super`]); planning, evaluation and the
//! tests' exhaustive search all go through [`Model::apply`].

use super::{Light, Terrain};
use crate::panel::Battery;

/// A rover: how it drives, what it carries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rover {
    /// Driving speed, m/s.
    pub speed_m_s: f64,
    /// Steepest facet it may enter, degrees.
    pub max_slope_deg: f64,
    /// Deck panel area, m².
    pub panel_area_m2: f64,
    /// Share of the panel's irradiance turned into power, 0 to 1.
    pub panel_efficiency: f64,
    pub battery: Battery,
    /// Least charge allowed at the end of any quantum, Wh.
    pub min_charge_wh: f64,
    /// Load while standing, W.
    pub idle_load_w: f64,
    /// Load while driving, W.
    pub drive_load_w: f64,
}

/// Weights of the cost terms besides distance (each metre of a move costs 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weights {
    pub illumination: f64,
    pub slope: f64,
    pub roughness: f64,
    /// Per unit of `v · τ` waited.
    pub waiting: f64,
}

impl Default for Weights {
    /// Illumination, slope and roughness weighed equally, as in the paper's Fig. 1;
    /// waiting an hour costs what driving an hour does.
    fn default() -> Weights {
        Weights {
            illumination: 1.0,
            slope: 1.0,
            roughness: 1.0,
            waiting: 1.0,
        }
    }
}

/// What the rover does for a while.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Stand on its facet for one quantum.
    Wait,
    /// Drive to this neighbouring facet.
    Move(u32),
}

/// Where the rover is, when, with what charge, at what cost so far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    pub facet: u32,
    /// Quanta since the window's first step.
    pub quantum: u32,
    /// Energy held, Wh.
    pub charge_wh: f64,
    /// Cost so far, metres-equivalent.
    pub cost: f64,
}

/// A cost split by its terms, metres-equivalent.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct CostParts {
    pub distance: f64,
    pub illumination: f64,
    pub slope: f64,
    pub roughness: f64,
    pub waiting: f64,
}

impl CostParts {
    /// The sum of the terms.
    pub fn total(&self) -> f64 {
        self.distance + self.illumination + self.slope + self.roughness + self.waiting
    }

    /// Adds `other` term by term.
    pub fn add(&mut self, other: &CostParts) {
        self.distance += other.distance;
        self.illumination += other.illumination;
        self.slope += other.slope;
        self.roughness += other.roughness;
        self.waiting += other.waiting;
    }
}

/// What one action did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    pub state: State,
    /// Quanta it took.
    pub quanta: u32,
    /// Energy the panel gave, Wh.
    pub energy_wh: f64,
    /// Time with no light on the panel, s.
    pub dark_s: f64,
    /// The least charge at the end of any of its quanta before clamping at empty, Wh.
    pub lowest_wh: f64,
    pub cost: CostParts,
}

/// The model a route lives in.
pub struct Model<'a> {
    pub terrain: &'a Terrain,
    pub light: &'a Light,
    pub rover: Rover,
    pub weights: Weights,
    /// Quanta per step.
    pub substeps: u32,
    quantum_s: f64,
    quanta: u32,
}

/// Quanta a median edge takes at least, when the substeps are chosen for the user: the
/// rounding up of a move's time then slows the rover by at most a quarter.
const QUANTA_PER_EDGE: f64 = 4.0;

/// Most quanta per step.
pub const MAX_SUBSTEPS: u32 = 3600;

impl<'a> Model<'a> {
    /// The model, with `substeps` quanta per step (default: a median edge takes at least
    /// four), or the first bad setting and why.
    pub fn new(
        terrain: &'a Terrain,
        light: &'a Light,
        rover: Rover,
        weights: Weights,
        substeps: Option<u32>,
    ) -> Result<Model<'a>, String> {
        rover.check()?;
        weights.check()?;
        let substeps = match substeps {
            Some(m) if (1..=MAX_SUBSTEPS).contains(&m) => m,
            Some(m) => return Err(format!("substeps {m}: give 1 to {MAX_SUBSTEPS}")),
            None => default_substeps(terrain.median_edge_m(), rover.speed_m_s, light.step_s),
        };
        let quanta = light.steps() as u64 * u64::from(substeps);
        let quanta = u32::try_from(quanta)
            .map_err(|_| format!("{quanta} quanta in the window: give fewer substeps"))?;
        Ok(Model {
            terrain,
            light,
            rover,
            weights,
            substeps,
            quantum_s: light.step_s / f64::from(substeps),
            quanta,
        })
    }

    /// Quanta in the window.
    pub fn quanta(&self) -> u32 {
        self.quanta
    }

    /// Length of a quantum, s.
    pub fn quantum_s(&self) -> f64 {
        self.quantum_s
    }

    /// Epoch of the start of `quantum`, TDB s.
    pub fn epoch(&self, quantum: u32) -> f64 {
        self.light.epochs_tdb_s[0] + f64::from(quantum) * self.quantum_s
    }

    /// The rover on `facet` at `quantum` with the battery's initial charge.
    pub fn start(&self, facet: u32, quantum: u32) -> State {
        State {
            facet,
            quantum,
            charge_wh: self.rover.battery.initial_wh,
            cost: 0.0,
        }
    }

    /// Whether the rover may enter `facet` (no steeper than its limit).
    pub fn allowed(&self, facet: u32) -> bool {
        self.terrain.slope_deg[facet as usize] <= self.rover.max_slope_deg
    }

    /// Quanta a move from `a` to `b` takes.
    pub fn move_quanta(&self, a: u32, b: u32) -> u32 {
        let d = self.terrain.distance_m(a, b);
        let n = (d / (self.rover.speed_m_s * self.quantum_s)).ceil();
        n.clamp(1.0, f64::from(u32::MAX)) as u32
    }

    /// `action` from `from`, or `None` when it would end after the window.
    pub fn apply(&self, from: &State, action: Action) -> Option<Outcome> {
        self.apply_seeing(from, action, |_| {})
    }

    /// [`Model::apply`], telling `lit` for each quantum whether the panel had light.
    pub fn apply_seeing(
        &self,
        from: &State,
        action: Action,
        mut lit: impl FnMut(bool),
    ) -> Option<Outcome> {
        let (to, quanta, load_w) = match action {
            Action::Wait => (from.facet, 1, self.rover.idle_load_w),
            Action::Move(to) => (
                to,
                self.move_quanta(from.facet, to),
                self.rover.drive_load_w,
            ),
        };
        let end = from.quantum.checked_add(quanta)?;
        if end > self.quanta {
            return None;
        }
        let rover = &self.rover;
        let (mut held, mut lowest) = (from.charge_wh, f64::INFINITY);
        let (mut energy_wh, mut dark_s, mut darkness) = (0.0, 0.0, 0.0);
        for q in from.quantum..end {
            let step = (q / self.substeps) as usize;
            let e =
                0.5 * (self.light.irradiance(step, from.facet) + self.light.irradiance(step, to));
            let power = rover.panel_efficiency * rover.panel_area_m2 * e;
            let (free, kept) = rover.battery.after(held, power, load_w, self.quantum_s);
            lowest = lowest.min(free);
            held = kept;
            energy_wh += power * self.quantum_s / 3600.0;
            let flux = self.light.flux(step);
            darkness += if flux > 0.0 {
                (1.0 - e / flux).clamp(0.0, 1.0)
            } else {
                1.0
            };
            if e == 0.0 {
                dark_s += self.quantum_s;
            }
            lit(e > 0.0);
        }
        let cost = match action {
            Action::Wait => CostParts {
                waiting: self.weights.waiting * rover.speed_m_s * self.quantum_s,
                ..CostParts::default()
            },
            Action::Move(_) => self.move_cost(from.facet, to, darkness / f64::from(quanta)),
        };
        Some(Outcome {
            state: State {
                facet: to,
                quantum: end,
                charge_wh: held,
                cost: from.cost + cost.total(),
            },
            quanta,
            energy_wh,
            dark_s,
            lowest_wh: lowest,
            cost,
        })
    }

    /// The cost of a move from `a` to `b` in mean darkness `darkness` (0 to 1).
    pub(super) fn move_cost(&self, a: u32, b: u32, darkness: f64) -> CostParts {
        let t = self.terrain;
        let d = t.distance_m(a, b);
        let limit = self.rover.max_slope_deg;
        let mean = |v: &[f64]| 0.5 * (v[a as usize] + v[b as usize]);
        CostParts {
            distance: d,
            illumination: d * self.weights.illumination * darkness,
            slope: d * self.weights.slope * (mean(&t.slope_deg) / limit),
            roughness: d * self.weights.roughness * (mean(&t.roughness_deg) / limit).min(1.0),
            waiting: 0.0,
        }
    }

    /// The most light `facet` gets at any step of the window, as a share of the flux
    /// on a surface facing the Sun (0 to 1).
    pub fn brightest(&self, facet: u32) -> f64 {
        (0..self.light.steps())
            .map(|k| match self.light.flux(k) {
                f if f > 0.0 => (self.light.irradiance(k, facet) / f).clamp(0.0, 1.0),
                _ => 0.0,
            })
            .fold(0.0, f64::max)
    }

    /// Whether an outcome keeps the charge at or above the rover's minimum.
    pub fn keeps_charge(&self, outcome: &Outcome) -> bool {
        outcome.lowest_wh >= self.rover.min_charge_wh
    }
}

/// Substeps so that a median edge of `edge_m` takes at least [`QUANTA_PER_EDGE`] quanta
/// at `speed_m_s`, with steps of `step_s`.
fn default_substeps(edge_m: f64, speed_m_s: f64, step_s: f64) -> u32 {
    if edge_m <= 0.0 {
        return 1;
    }
    let m = (QUANTA_PER_EDGE * speed_m_s * step_s / edge_m).ceil();
    m.clamp(1.0, f64::from(MAX_SUBSTEPS)) as u32
}

impl Rover {
    /// `Ok`, or the first bad field and why.
    pub fn check(&self) -> Result<(), String> {
        let r = self;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let at_least_0 = |v: f64| v.is_finite() && v >= 0.0;
        if !positive(r.speed_m_s) {
            return Err("speed_m_s must be above 0".into());
        }
        if !(r.max_slope_deg > 0.0 && r.max_slope_deg <= 90.0) {
            return Err("max_slope_deg must be above 0 and at most 90".into());
        }
        if !positive(r.panel_area_m2) {
            return Err("panel.area_m2 must be above 0".into());
        }
        if !(0.0..=1.0).contains(&r.panel_efficiency) {
            return Err("panel.efficiency must be 0 to 1".into());
        }
        if !(at_least_0(r.min_charge_wh) && r.min_charge_wh <= r.battery.capacity_wh) {
            return Err("battery.min_charge_wh must be 0 to capacity_wh".into());
        }
        if r.battery.initial_wh < r.min_charge_wh {
            return Err("battery.initial_wh must be at least min_charge_wh".into());
        }
        if !(at_least_0(r.idle_load_w) && at_least_0(r.drive_load_w)) {
            return Err("idle_load_w and drive_load_w must be finite and ≥ 0".into());
        }
        Ok(())
    }
}

impl Weights {
    /// `Ok`, or why not: every weight finite and ≥ 0.
    pub fn check(&self) -> Result<(), String> {
        let w = self;
        let all = [w.illumination, w.slope, w.roughness, w.waiting];
        if all.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err("weights must be finite and ≥ 0".into());
        }
        Ok(())
    }
}
