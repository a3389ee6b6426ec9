//! Albedo of every facet, from the scene: per body, or per facet from a column file.
//!
//! In: the scene's `[scatter]` section and bodies, and the facet count of each body. Out:
//! one Lambertian albedo in [0, 1) per facet (global ids). A per-facet file holds one
//! number per line in facet order; blank lines and `#` comments are skipped; errors name
//! the file and the line.

use crate::error::{Error, Result};
use crate::scene::Scene;
use crate::world::World;
use std::path::Path;

/// Every facet's albedo (global ids), or `None` when the scene has no scattering.
pub fn facet_albedo(scene: &Scene, world: &World) -> Result<Option<Vec<f64>>> {
    let Some(section) = scene.scatter.as_ref().filter(|s| s.enabled) else {
        return Ok(None);
    };
    let mut albedo = Vec::with_capacity(world.facet_count());
    for (i, (b, body)) in scene.bodies.iter().zip(&world.bodies).enumerate() {
        match (&b.albedo_file, b.albedo.or(section.albedo)) {
            (Some(path), _) => albedo.extend(read_albedo_file(path, body.mesh.len())?),
            (None, Some(a)) => albedo.extend(std::iter::repeat_n(a, body.mesh.len())),
            (None, None) => return Err(scene.err(format!("body[{i}].albedo"), "missing")),
        }
    }
    Ok(Some(albedo))
}

/// Every facet's albedo in band `band`: a body's `albedo_bands` entry where it has one,
/// else its broadband albedo from `broadband` (global ids).
pub fn band_albedo(scene: &Scene, world: &World, band: &str, broadband: &[f64]) -> Vec<f64> {
    let mut albedo = broadband.to_vec();
    for ((b, body), offset) in scene.bodies.iter().zip(&world.bodies).zip(world.offsets()) {
        if let Some(a) = b.albedo_bands.get(band) {
            albedo[offset..offset + body.mesh.len()].fill(*a);
        }
    }
    albedo
}

/// Reads a per-facet albedo file of exactly `facets` values.
pub fn read_albedo_file(path: &Path, facets: usize) -> Result<Vec<f64>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = std::str::from_utf8(crate::without_bom(&bytes))
        .map_err(|e| Error::file(path, format!("not UTF-8 text: {e}")))?;
    let mut values = Vec::with_capacity(facets);
    for (n, line) in text.lines().enumerate() {
        let content = line.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let value: f64 = content.parse().map_err(|_| {
            let shown = crate::error::printable(content, 80);
            Error::at_line(path, n + 1, format!("'{shown}' is not a number"))
        })?;
        if !(value.is_finite() && (0.0..1.0).contains(&value)) {
            return Err(Error::at_line(
                path,
                n + 1,
                format!("albedo {value} is not in [0, 1)"),
            ));
        }
        values.push(value);
    }
    if values.len() != facets {
        return Err(Error::file(
            path,
            format!(
                "holds {} albedo values for a mesh of {facets} facets",
                values.len()
            ),
        ));
    }
    Ok(values)
}
