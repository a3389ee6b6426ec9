//! Fit job: `slim fit` — observed images matched to a scene's steps and bands, modelled
//! with the scene's camera, fitted, and the residuals written.
//!
//! In: a validated scene with `[camera]` and materials (the starting values), observed
//! images (FITS or PNG) whose `STEP` and `BAND` header keywords say which scene step and
//! band each shows, the parameter names to fit and the body. Out: the [`FitResult`] and
//! one residual image per input, `NAME_residual_K.fits`, in the output folder.

use super::{fit, FitResult, Observation};
use crate::error::{Error, Result};
use crate::image::{fits, read_image, Value};
use crate::render::job::{bands, camera, camera_section, materials, View};
use crate::render::Renderer;
use crate::scene::Scene;
use std::path::{Path, PathBuf};

/// Fits parameters `names` of body `body_name` (default: the first body) to the observed
/// `images`; writes the residual images into `out_dir`.
pub fn fit_scene(
    scene: &Scene,
    images: &[PathBuf],
    names: &[String],
    body_name: Option<&str>,
    out_dir: &Path,
) -> Result<(FitResult, Vec<PathBuf>)> {
    let section = camera_section(scene)?;
    let body = match body_name {
        None => 0,
        Some(n) => scene
            .bodies
            .iter()
            .position(|b| b.name == n)
            .ok_or_else(|| Error::Usage(format!("--body: no body is named '{n}'")))?,
    };
    let view = View::load(scene)?;
    let renderer = Renderer::new(&view.world, scene.run.tracer);
    let all_bands = bands(scene);
    let mut observed = Vec::new();
    let mut geometries = Vec::new();
    let mut setups = Vec::new();
    for path in images {
        let image = read_image(path)?;
        let step = image
            .number("STEP")
            .filter(|s| *s >= 0.0 && s.fract() == 0.0)
            .ok_or_else(|| {
                Error::file(
                    path,
                    "no STEP keyword: say which scene step the image shows",
                )
            })? as usize;
        let band_name = image.text("BAND").unwrap_or("all").to_string();
        let band = all_bands
            .iter()
            .find(|b| b.name == band_name)
            .ok_or_else(|| {
                Error::file(
                    path,
                    format!("BAND '{band_name}' is not a band of the scene"),
                )
            })?
            .clone();
        let state = view.state(scene, step)?;
        let camera = camera(scene, section, &view, &state)?;
        geometries.push(renderer.geometry(&state, &camera)?);
        setups.push((band.flux_scale, materials(scene, &band)?));
        observed.push(image);
    }
    let observations: Vec<Observation<'_>> = geometries
        .iter()
        .zip(&observed)
        .zip(&setups)
        .map(
            |((geometry, observed), (flux_scale, materials))| Observation {
                geometry,
                observed,
                flux_scale: *flux_scale,
                materials,
            },
        )
        .collect();
    let start = &setups
        .first()
        .ok_or_else(|| Error::Usage("give at least one image".into()))?
        .1[body];
    let result = fit(&observations, body, start, names)?;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut files = Vec::new();
    for (k, residual) in result.residuals.iter().enumerate() {
        let path = out_dir.join(format!("{}_residual_{k}.fits", scene.name));
        let mut image = residual.clone();
        image.set(
            "FITTED",
            Value::Text(result.material.describe()),
            "fitted material",
        );
        fits::write(&path, &image)?;
        files.push(path);
    }
    Ok((result, files))
}
