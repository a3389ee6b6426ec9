//! The light a route is planned in: each facet's irradiance at each step of a window.
//!
//! In: a prepared scene ([`Prepared`]), the body driven on and the first step. Out: a
//! [`Light`] table — per step and facet the irradiance (W/m², what `slim run` computes
//! for that facet, scattered light included when the scene has it), per step the flux
//! on a surface facing the Sun (W/m²) and the epoch (TDB s). Stored as `f32`: 4 bytes
//! per facet and step, checked against the memory budget before it is computed.

use crate::budget::{Budget, Estimate, Item};
use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::prepare::Prepared;
use crate::progress::{Progress, Timings};
use crate::simulate::{simulate, Options, StepIrradiance};

/// Irradiance of one body's facets over a window of evenly spaced steps.
#[derive(Debug, Clone)]
pub struct Light {
    facets: usize,
    /// Step-major: step `k`'s facets at `k * facets ..`.
    irradiance: Vec<f32>,
    flux_w_m2: Vec<f64>,
    /// Epoch of each step, TDB seconds past J2000.
    pub epochs_tdb_s: Vec<f64>,
    /// Time between steps, s.
    pub step_s: f64,
    /// The scene's index of the window's first step.
    pub first_step: usize,
}

/// Bytes per facet and step of the table.
const BYTES_PER_VALUE: f64 = 4.0;

impl Light {
    /// A table from its parts (`irradiance` step-major, `facets` per step), or why not.
    pub fn new(
        facets: usize,
        first_step: usize,
        step_s: f64,
        epochs_tdb_s: Vec<f64>,
        flux_w_m2: Vec<f64>,
        irradiance: Vec<f32>,
    ) -> std::result::Result<Light, String> {
        let steps = epochs_tdb_s.len();
        if steps == 0 || flux_w_m2.len() != steps || irradiance.len() != steps * facets {
            return Err(format!(
                "{steps} epochs, {} fluxes and {} values for {facets} facets",
                flux_w_m2.len(),
                irradiance.len()
            ));
        }
        if !(step_s.is_finite() && step_s > 0.0) {
            return Err(format!("step {step_s} s: the steps must be evenly spaced"));
        }
        Ok(Light {
            facets,
            irradiance,
            flux_w_m2,
            epochs_tdb_s,
            step_s,
            first_step,
        })
    }

    /// Runs the scene's step loop from `first_step` to its end and keeps the irradiance
    /// of body `body`'s facets (a body with outputs). Refused when the table would not
    /// fit in `budget`, naming what shrinks it.
    pub fn compute(
        prepared: Prepared,
        body: usize,
        first_step: usize,
        budget: &Budget,
        progress: &dyn Progress,
    ) -> Result<Light> {
        let Prepared {
            assembly,
            states,
            scatter,
            bins,
            tracer,
            shadows,
            horizon_maps,
            ..
        } = prepared;
        let world = &assembly.world;
        let target = &world.bodies[body];
        if !target.outputs {
            return Err(Error::Usage(format!(
                "body '{}' has outputs = false: a route needs its light",
                target.name
            )));
        }
        let states = &states[first_step.min(states.len())..];
        let step_s = window_step_s(states)?;
        let facets = target.mesh.len();
        let bytes = facets as f64 * states.len() as f64 * BYTES_PER_VALUE;
        let mut estimate = Estimate::default();
        estimate.items.push(Item {
            what: "route light table (facets × steps)".into(),
            bytes: bytes.min(u64::MAX as f64) as u64,
            shrink: "depart later, or use a scene with fewer steps or a coarser mesh".into(),
        });
        budget.check(&estimate)?;
        let offset = world.output_offsets()[body];
        let mut irradiance = Vec::with_capacity(facets * states.len());
        let options = Options {
            tracer,
            bins,
            shadows,
            horizon_maps,
            scatter,
            bands: None,
            slice: Default::default(),
        };
        let mut timings = Timings::default();
        let mut keep = |_: &EpochState, e: StepIrradiance| {
            let own = &e.total[offset..offset + facets];
            irradiance.extend(own.iter().map(|&v| v as f32));
            Ok(())
        };
        simulate(
            world,
            states,
            options,
            &mut timings,
            progress,
            Some(&mut keep),
        )?;
        let flux = states.iter().map(|s| s.bodies[body].flux_w_m2).collect();
        let epochs = states.iter().map(|s| s.epoch.to_tdb_seconds()).collect();
        Light::new(facets, first_step, step_s, epochs, flux, irradiance).map_err(Error::Usage)
    }

    /// Number of steps.
    pub fn steps(&self) -> usize {
        self.epochs_tdb_s.len()
    }

    /// Irradiance of `facet` at window step `step`, W/m².
    pub fn irradiance(&self, step: usize, facet: u32) -> f64 {
        f64::from(self.irradiance[step * self.facets + facet as usize])
    }

    /// Flux on a surface facing the Sun at window step `step`, W/m².
    pub fn flux(&self, step: usize) -> f64 {
        self.flux_w_m2[step]
    }
}

/// The window's step, s: a route needs evenly spaced steps, at least two.
fn window_step_s(states: &[EpochState]) -> Result<f64> {
    crate::run::even_step_s(states).ok_or_else(|| {
        Error::Usage(format!(
            "a route needs two or more evenly spaced steps after its departure; the \
             scene has {} there",
            states.len()
        ))
    })
}
