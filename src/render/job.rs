//! Render job: a scene's `[camera]` turned into image files (`slim render`).
//!
//! In: a validated scene with a `[camera]` section and a material per body, and an output
//! folder. Out, per rendered step and band: `NAME_sSTEP_BAND_radiance.fits` (W m⁻² sr⁻¹),
//! `NAME_sSTEP_BAND_iof.fits` (I/F) and `NAME_sSTEP_BAND_iof.png` (linear stretch from 0
//! to `png_white_i_over_f` or the image maximum, stated in the file); with several bands
//! also `NAME_sSTEP_total_radiance.fits`, the sum over bands. Each FITS header holds the
//! geometry: epoch, step, band and its flux share, camera position and axes, focal length,
//! Sun direction and flux per body.
//!
//! `slim fit` models its images with the same view, bands and cameras (see
//! `crate::fit::job`).

use super::camera::Camera;
use super::{GeometryImage, Renderer};
use crate::budget::Budget;
use crate::ephemeris::{Ephemeris, EpochState};
use crate::error::{Error, Result};
use crate::image::png::Stretch;
use crate::image::{fits, png, Image, Value};
use crate::photometry::{Material, Reflectance};
use crate::prepare::assemble;
use crate::progress::Timings;
use crate::scene::{CameraSection, Scene};
use crate::world::World;
use glam::DVec3;
use std::path::{Path, PathBuf};

/// A spectral band: its name and its share of the solar flux.
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    pub name: String,
    pub flux_scale: f64,
}

/// The scene's bands; without `[[band]]`, one band "all" with the whole flux.
pub fn bands(scene: &Scene) -> Vec<Band> {
    if scene.bands.is_empty() {
        return vec![Band {
            name: "all".into(),
            flux_scale: 1.0,
        }];
    }
    let total = scene.solar_constant_w_m2();
    scene
        .bands
        .iter()
        .map(|b| Band {
            name: b.name.clone(),
            flux_scale: b.solar_constant_w_m2 / total,
        })
        .collect()
}

/// Every body's material in `band` (scene band names; "all" for the base parameters).
pub fn materials(scene: &Scene, band: &Band) -> Result<Vec<Material>> {
    let name = (!scene.bands.is_empty()).then_some(band.name.as_str());
    (0..scene.bodies.len())
        .map(|i| scene.material(i, name))
        .collect()
}

/// The loaded geometry of a scene: bodies, ephemeris, and where the camera is.
pub struct View {
    pub world: World,
    pub ephemeris: Box<dyn Ephemeris>,
    pub warnings: Vec<String>,
    camera_site: CameraSite,
}

/// Where the camera is.
enum CameraSite {
    /// A fixed position, scene frame, metres.
    Fixed(DVec3),
    /// A NAIF body or spacecraft placed by the ephemeris' kernels, relative to the first
    /// body.
    Spice { observer: i32, first_body: i32 },
}

impl View {
    /// Loads the scene's bodies and ephemeris.
    pub fn load(scene: &Scene) -> Result<View> {
        let assembly = assemble(scene, &Budget::machine(), &mut Timings::default())?;
        let camera_site = match scene.camera.as_ref().and_then(|c| c.observer_naif_id) {
            Some(observer) => CameraSite::Spice {
                observer,
                first_body: scene.bodies[0].naif_id.unwrap_or_default(),
            },
            None => CameraSite::Fixed(
                DVec3::from_array(
                    scene
                        .camera
                        .as_ref()
                        .and_then(|c| c.position_km)
                        .unwrap_or_default(),
                ) * 1000.0,
            ),
        };
        Ok(View {
            world: assembly.world,
            ephemeris: assembly.ephemeris,
            warnings: assembly.warnings,
            camera_site,
        })
    }

    /// The camera's position at `state`, scene frame, metres.
    pub fn camera_position_m(&self, scene: &Scene, state: &EpochState) -> Result<DVec3> {
        let (observer, first_body) = match self.camera_site {
            CameraSite::Fixed(p) => return Ok(p),
            CameraSite::Spice {
                observer,
                first_body,
            } => (observer, first_body),
        };
        let kernels = self
            .ephemeris
            .kernels()
            .ok_or_else(|| Error::Usage("camera.observer_naif_id needs spice mode".into()))?;
        kernels
            .vector_km(observer, first_body, state.epoch, None)
            .map(|v| v * 1000.0)
            .map_err(|msg| Error::Spice {
                body: format!("camera observer of {}", scene.bodies[0].name),
                naif_id: observer,
                frame: "J2000".into(),
                epoch: format!("{} ({} TDB s)", state.epoch, state.epoch.to_tdb_seconds()),
                msg: format!(
                    "camera position relative to NAIF {first_body}: {msg}; the loaded SPKs provide: {}",
                    kernels
                        .ephemeris_coverage()
                        .iter()
                        .map(|c| c.0.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
    }

    /// The state at `step`, checked against the number of steps.
    pub fn state(&self, scene: &Scene, step: usize) -> Result<EpochState> {
        let steps = self.ephemeris.steps();
        if step >= steps {
            return Err(Error::Scene {
                path: scene.path.clone(),
                key: "camera.steps".into(),
                msg: format!("step {step} does not exist: the ephemeris has {steps} steps"),
            });
        }
        self.ephemeris.state(step)
    }
}

/// The scene's `[camera]` section, or an error naming it.
pub fn camera_section(scene: &Scene) -> Result<&CameraSection> {
    scene.camera.as_ref().ok_or_else(|| Error::Scene {
        path: scene.path.clone(),
        key: "camera".into(),
        msg: "missing: rendering needs a [camera] section".into(),
    })
}

/// The camera of `section` at `state` (it follows its target body).
pub fn camera(
    scene: &Scene,
    section: &CameraSection,
    view: &View,
    state: &EpochState,
) -> Result<Camera> {
    let optics = match (section.width, section.height, section.fov_deg) {
        (Some(w), Some(h), Some(fov)) => Camera::with_fov(w, h, fov)?,
        _ => Camera::dawn_fc(),
    };
    let km = |v: [f64; 3]| DVec3::from_array(v) * 1000.0;
    let target = match (&section.look_at_km, &section.target) {
        (Some(p), _) => km(*p),
        (None, Some(name)) => {
            let i = scene
                .bodies
                .iter()
                .position(|b| &b.name == name)
                .unwrap_or(0);
            state.bodies[i].pose.position_m
        }
        (None, None) => state.bodies[0].pose.position_m,
    };
    optics
        .looking_at(
            view.camera_position_m(scene, state)?,
            target,
            DVec3::from_array(section.up),
        )
        .map_err(|e| Error::Scene {
            path: scene.path.clone(),
            key: "camera".into(),
            msg: e.to_string(),
        })
}

/// The steps `[camera] steps` lists, or all.
pub fn steps(section: &CameraSection, view: &View) -> Vec<usize> {
    section
        .steps
        .clone()
        .unwrap_or_else(|| (0..view.ephemeris.steps()).collect())
}

/// Renders every listed step and band of `scene` into `out_dir`; returns the files.
pub fn render_scene(scene: &Scene, out_dir: &Path) -> Result<Vec<PathBuf>> {
    let section = camera_section(scene)?;
    let view = View::load(scene)?;
    let renderer = Renderer::new(&view.world, scene.run.tracer);
    let bands = bands(scene);
    let materials: Vec<Vec<Material>> = bands
        .iter()
        .map(|b| materials(scene, b))
        .collect::<Result<_>>()?;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut files = Vec::new();
    for step in steps(section, &view) {
        let state = view.state(scene, step)?;
        let camera = camera(scene, section, &view, &state)?;
        let geometry = renderer.geometry(&state, &camera)?;
        let mut total: Option<Image> = None;
        for (band, mats) in bands.iter().zip(&materials) {
            let refs: Vec<&dyn Reflectance> = mats.iter().map(|m| m as &dyn Reflectance).collect();
            let mut radiance = geometry.radiance(&refs, band.flux_scale);
            let mut iof = geometry.i_over_f(&refs);
            for (image, unit) in [(&mut radiance, "W/m2/sr"), (&mut iof, "I/F")] {
                describe(image, scene, &state, &camera, &geometry, band, mats, unit);
            }
            let stem = out_dir.join(format!("{}_s{step:04}_{}", scene.name, band.name));
            files.push(write_fits(&stem, "radiance", &radiance)?);
            files.push(write_fits(&stem, "iof", &iof)?);
            let stretch = match section.png_white_i_over_f {
                Some(hi) => Stretch { lo: 0.0, hi },
                None => Stretch::zero_to_max(&iof),
            };
            let png_path = with_suffix(&stem, "iof.png");
            png::write(&png_path, &iof, section.png_bits, stretch)?;
            files.push(png_path);
            total = Some(match total {
                None => radiance,
                Some(mut t) => {
                    t.pixels
                        .iter_mut()
                        .zip(&radiance.pixels)
                        .for_each(|(a, b)| *a += b);
                    t
                }
            });
        }
        if let (Some(mut t), true) = (total, bands.len() > 1) {
            t.set("BAND", Value::Text("total".into()), "sum over all bands");
            t.set(
                "FLUXFRAC",
                Value::Number(bands.iter().map(|b| b.flux_scale).sum()),
                "",
            );
            let stem = out_dir.join(format!("{}_s{step:04}_total", scene.name));
            files.push(write_fits(&stem, "radiance", &t)?);
        }
    }
    Ok(files)
}

fn with_suffix(stem: &Path, suffix: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push("_");
    s.push(suffix);
    PathBuf::from(s)
}

fn write_fits(stem: &Path, what: &str, image: &Image) -> Result<PathBuf> {
    let path = with_suffix(stem, &format!("{what}.fits"));
    fits::write(&path, image)?;
    Ok(path)
}

/// Writes the geometry of a rendered image into its header.
#[allow(clippy::too_many_arguments)]
fn describe(
    image: &mut Image,
    scene: &Scene,
    state: &EpochState,
    camera: &Camera,
    geometry: &GeometryImage,
    band: &Band,
    materials: &[Material],
    unit: &str,
) {
    let text = |s: &str| Value::Text(s.to_string());
    image.set("BUNIT", text(unit), "pixel unit");
    image.set("ORIGIN", text("slim"), "simulated image");
    image.set("SCENE", text(&scene.name), "scene name");
    image.set("STEP", Value::Integer(state.step as i64), "ephemeris step");
    image.set(
        "EPOCH",
        text(&format!("{}", state.epoch)),
        "epoch of the step",
    );
    image.set(
        "ET_TDB",
        Value::Number(state.epoch.to_tdb_seconds()),
        "TDB s past J2000",
    );
    image.set("BAND", text(&band.name), "spectral band");
    image.set(
        "FLUXFRAC",
        Value::Number(band.flux_scale),
        "share of the solar flux",
    );
    image.set(
        "FOCALPX",
        Value::Number(camera.focal_px),
        "focal length, pixels",
    );
    image.set(
        "FOV_DEG",
        Value::Number(camera.fov_deg()),
        "field across the width, deg",
    );
    let axes = camera.pose.body_to_scene;
    let position_km = camera.pose.position_m / 1000.0;
    let vectors = [
        ("CAMPOS", position_km, "camera position, scene frame, km"),
        ("CAMX", axes.x_axis, "image +x (columns), scene frame"),
        ("CAMY", axes.y_axis, "image +y (rows, down), scene frame"),
        ("CAMZ", axes.z_axis, "boresight, scene frame"),
    ];
    for (key, v, comment) in vectors {
        for (axis, x) in ["1", "2", "3"].iter().zip(v.to_array()) {
            image.set(&format!("{key}{axis}"), Value::Number(x), comment);
        }
    }
    for (b, body) in state.bodies.iter().enumerate() {
        let sun_scene = body.pose.body_to_scene * body.sun_dir;
        let name = &scene.bodies[b].name;
        for (axis, x) in ["1", "2", "3"].iter().zip(sun_scene.to_array()) {
            image.set(
                &format!("SUN{b}_{axis}"),
                Value::Number(x),
                &format!("to Sun from {name}, scene frame"),
            );
        }
        image.set(
            &format!("FLUX{b}"),
            Value::Number(body.flux_w_m2 * band.flux_scale),
            &format!("solar flux at {name} in band, W/m2"),
        );
        image.set(
            &format!("MAT{b}"),
            text(&materials[b].describe()),
            &format!("material of {name}"),
        );
    }
    image.set(
        "CLIPPED",
        Value::Integer(geometry.clipped_facets as i64),
        "facets behind the camera plane",
    );
    image.set(
        "FITSORNT",
        text("row 1 = bottom"),
        "first stored row is the image bottom",
    );
}
