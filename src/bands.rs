//! Spectral bands: irradiance and its statistics per `[[band]]` and summed over bands
//! (the paper's multispectral irradiance, Figs. 5–6).
//!
//! In, per step: the broadband direct irradiance `D` (W/m², global facet ids, for the
//! scene's whole solar constant S₀) and, with scattering, the scattered-light stage. Out:
//! per band b, `E_b = s_b D + S_b` with `s_b = S₀_b / S₀` the band's share of the flux and
//! `S_b` the light scattered with the band's albedo (`albedo_bands`) and first bounce (the
//! band's material with `first_bounce = "material"`); and `Σ_b E_b`. Shadows do not depend
//! on the band, so `D` is traced once; the form factors are shared by every band.

use crate::ephemeris::EpochState;
use crate::error::Result;
use crate::photometry::Material;
use crate::scatter::photometric::Photometric;
use crate::scatter::{
    albedo::band_albedo, BandInput, FirstBounce, FirstScatter, Scatter, Settings,
};
use crate::scene::Scene;
use crate::stats::{Bins, FacetStats, Selection};
use crate::world::World;

/// One band's flux share, scattering inputs and statistics.
struct Band {
    name: String,
    share: f64,
    /// With scattering: the band's albedo (global ids) and first bounce.
    scatter: Option<(Vec<f64>, Box<dyn FirstScatter>)>,
    stats: FacetStats,
}

/// Every band of a run and the sum over bands.
pub struct Bands {
    bands: Vec<Band>,
    sum: FacetStats,
    /// The facets statistics are kept for (those of the bodies that get outputs).
    kept: Selection,
    kept_values: Vec<f64>,
    /// Per step of a batch: the band's direct and scattered irradiance, and the sum over
    /// bands so far.
    direct: Vec<Vec<f64>>,
    scattered: Vec<Vec<f64>>,
    summed: Vec<Vec<f64>>,
    total: Vec<f64>,
}

impl Bands {
    /// The scene's bands, or `None` when it has no `[[band]]`, keeping statistics of the
    /// facets `kept`.
    pub fn from_scene(
        scene: &Scene,
        world: &World,
        scatter: Option<&Settings>,
        bins: Bins,
        kept: Selection,
    ) -> Result<Option<Bands>> {
        if scene.bands.is_empty() {
            return Ok(None);
        }
        let n = world.facet_count();
        let total_flux = scene.solar_constant_w_m2();
        let bands = scene
            .bands
            .iter()
            .map(|b| {
                let scatter = match scatter {
                    Some(settings) => Some((
                        band_albedo(scene, world, &b.name, &settings.albedo),
                        band_first_bounce(scene, &settings.first_bounce, &b.name)?,
                    )),
                    None => None,
                };
                Ok(Band {
                    name: b.name.clone(),
                    share: b.solar_constant_w_m2 / total_flux,
                    scatter,
                    stats: FacetStats::new(kept.count(), bins),
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Some(Bands {
            bands,
            sum: FacetStats::new(kept.count(), bins),
            kept,
            kept_values: Vec::new(),
            direct: Vec::new(),
            scattered: Vec::new(),
            summed: Vec::new(),
            total: vec![0.0; n],
        }))
    }

    /// Adds consecutive steps: `directs[k]` is the broadband direct irradiance at
    /// `states[k]`. Each band's steps are scattered side by side
    /// ([`Scatter::step_many_band`]).
    pub fn add_steps(
        &mut self,
        states: &[EpochState],
        directs: &[&[f64]],
        mut scatter: Option<&mut Scatter>,
    ) {
        let lanes = states.len();
        let n = self.total.len();
        for buffers in [&mut self.direct, &mut self.scattered, &mut self.summed] {
            buffers.resize_with(lanes, || vec![0.0; n]);
        }
        self.summed.iter_mut().for_each(|s| s.fill(0.0));
        for band in &mut self.bands {
            for (mine, broadband) in self.direct.iter_mut().zip(directs) {
                mine.iter_mut()
                    .zip(*broadband)
                    .for_each(|(d, b)| *d = band.share * b);
            }
            match (&band.scatter, scatter.as_deref_mut()) {
                (Some((albedo, first)), Some(stage)) => {
                    let input = BandInput {
                        albedo,
                        first: first.as_ref(),
                        flux_share: band.share,
                    };
                    let d: Vec<&[f64]> = self.direct[..lanes].iter().map(Vec::as_slice).collect();
                    let mut out: Vec<&mut [f64]> = self.scattered[..lanes]
                        .iter_mut()
                        .map(Vec::as_mut_slice)
                        .collect();
                    stage.step_many_band(states, &d, Some(input), &mut out);
                }
                _ => self.scattered.iter_mut().for_each(|s| s.fill(0.0)),
            }
            for k in 0..lanes {
                let parts = self.direct[k].iter().zip(&self.scattered[k]);
                for (t, (d, s)) in self.total.iter_mut().zip(parts) {
                    *t = d + s;
                }
                band.stats
                    .add_step(self.kept.pick(&self.total, &mut self.kept_values));
                self.summed[k]
                    .iter_mut()
                    .zip(&self.total)
                    .for_each(|(sum, t)| *sum += t);
            }
        }
        for summed in &self.summed[..lanes] {
            self.sum
                .add_step(self.kept.pick(summed, &mut self.kept_values));
        }
    }

    /// Named statistics: `band_NAME` for each band, then `bands` for their sum.
    pub fn into_parts(self) -> Vec<(String, FacetStats)> {
        self.bands
            .into_iter()
            .map(|b| (format!("band_{}", b.name), b.stats))
            .chain(std::iter::once(("bands".to_string(), self.sum)))
            .collect()
    }
}

/// The first bounce in band `band`: Lambertian, or each body's material in that band.
fn band_first_bounce(
    scene: &Scene,
    broadband: &FirstBounce,
    band: &str,
) -> Result<Box<dyn FirstScatter>> {
    Ok(match broadband {
        FirstBounce::Lambertian => FirstBounce::Lambertian.scatterer(),
        FirstBounce::Materials(_) => Box::new(Photometric {
            materials: (0..scene.bodies.len())
                .map(|i| scene.material(i, Some(band)))
                .collect::<Result<Vec<Material>>>()?,
        }),
    })
}
