//! Scene: the TOML file that describes a run, parsed and validated.
//!
//! In: a scene file path. Out: a [`Scene`] with every path resolved relative to the scene
//! file and every number checked. Unknown keys are rejected with their dotted path
//! (`body[0].spin_period`), as are missing, out-of-range and inconsistent values. The
//! README documents every key with a complete example.

use crate::error::{Error, Result};
use crate::mesh::projection::Pole;
use crate::mesh::{LengthUnit, MeshFormat};
use crate::photometry::hapke::HFunction;
use crate::photometry::Material;
use crate::trace::TracerKind;
use hifitime::Epoch;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// A validated scene.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The scene file.
    pub path: PathBuf,
    /// The scene file's bytes (for the run record's hash).
    pub source: Vec<u8>,
    /// Run name (defaults to the scene file's stem).
    pub name: String,
    pub run: RunSection,
    pub output: OutputSection,
    /// `[scatter]`: scattered light (none: direct sunlight only).
    pub scatter: Option<ScatterSection>,
    pub ephemeris: EphemerisSection,
    /// Bodies with mesh paths resolved.
    pub bodies: Vec<BodySection>,
    /// Epoch of the first step.
    pub start: Epoch,
    /// Epoch the run stops before (SPICE mode with `stop`).
    pub stop: Option<Epoch>,
    /// `[camera]`: what `slim render` and `slim fit` see.
    pub camera: Option<CameraSection>,
    /// `[[band]]`: spectral bands (none: one band with the whole solar flux).
    pub bands: Vec<BandSection>,
}

/// `[camera]`: a pinhole camera placed in the scene frame.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// A named camera: "dawn_fc" (1024 × 1024, 5.46°); or give width, height and fov_deg.
    pub preset: Option<String>,
    /// Image width, pixels.
    pub width: Option<usize>,
    /// Image height, pixels.
    pub height: Option<usize>,
    /// Field of view across the width, degrees.
    pub fov_deg: Option<f64>,
    /// Camera position in the scene frame, km (or give `observer_naif_id`).
    pub position_km: Option<[f64; 3]>,
    /// SPICE mode: the camera sits at this NAIF body or spacecraft (e.g. -203 for Dawn),
    /// placed by the loaded SPKs (geometric position relative to the first body).
    pub observer_naif_id: Option<i32>,
    /// Body whose centre the camera points at (default: the first body).
    pub target: Option<String>,
    /// A point to look at instead of a body centre, scene frame, km.
    pub look_at_km: Option<[f64; 3]>,
    /// Scene-frame direction shown "up" in the image (default +z).
    #[serde(default = "z_axis")]
    pub up: [f64; 3],
    /// Ephemeris steps to render (default: every step).
    pub steps: Option<Vec<usize>>,
    /// PNG depth: 8 or 16 bits.
    #[serde(default = "eight")]
    pub png_bits: u8,
    /// I/F shown white in the PNGs (default: each image's maximum).
    pub png_white_i_over_f: Option<f64>,
}

/// One `[[band]]`: a spectral band and the solar flux in it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BandSection {
    /// Band name (used in file names and in `material.bands`).
    pub name: String,
    /// Solar irradiance in the band at 1 AU, W/m² (a share of the scene's solar constant).
    pub solar_constant_w_m2: f64,
}

/// `[run]`: how to compute.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunSection {
    /// Name of the run (outputs, run.json).
    pub name: Option<String>,
    /// Shadow tracer: "sunview" (fast, default) or "grid" (the paper's reference).
    pub tracer: TracerKind,
    /// Width of the CDF bins, W/m².
    pub bin_width_w_m2: f64,
}

impl Default for RunSection {
    fn default() -> Self {
        RunSection {
            name: None,
            tracer: TracerKind::default(),
            bin_width_w_m2: 10.0,
        }
    }
}

/// `[output]`: what to write besides the Parquet summary, CDF and geometry tables.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputSection {
    /// Also write every table as CSV.
    pub csv: bool,
    /// Write one PLY per body with per-facet statistics.
    pub ply: bool,
    /// Write the full irradiance history (step, epoch, body, facet, irradiance).
    pub history: bool,
}

impl Default for OutputSection {
    fn default() -> Self {
        OutputSection {
            csv: true,
            ply: true,
            history: false,
        }
    }
}

/// `[scatter]`: sunlight scattered between facets (Lambertian, all orders). Present and
/// not `enabled = false`: on.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScatterSection {
    /// Set false to keep the section but switch scattering off.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Albedo of bodies that set none themselves.
    pub albedo: Option<f64>,
    /// "auto" (default), "jacobi" (iterate = scattering order) or "cg".
    #[serde(default)]
    pub solver: crate::scatter::solve::SolverKind,
    /// Jacobi: most scattering orders; CG: most iterations.
    #[serde(default = "default_max_orders")]
    pub max_orders: u32,
    /// Relative tolerance of each step's solve.
    #[serde(default = "default_scatter_tolerance")]
    pub tolerance: f64,
    /// Leave out light between two bodies when its bound is below this share of the flux.
    #[serde(default = "default_inter_body_tolerance")]
    pub inter_body_tolerance: f64,
    /// Facet pairs closer than this many facet sizes get the exact near-field integral.
    #[serde(default = "default_near_field_ratio")]
    pub near_field_ratio: f64,
    /// The first bounce: "lambert" (default) or "material" (each body's
    /// `[body.material]` reflectance model; higher orders stay Lambertian).
    #[serde(default)]
    pub first_bounce: FirstBounceKind,
}

/// `[scatter] first_bounce`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FirstBounceKind {
    #[default]
    Lambert,
    Material,
}

/// `[ephemeris]`: where the Sun is at each step, chosen by its `mode` key.
#[derive(Debug, Clone)]
pub enum EphemerisSection {
    /// Synthetic uniform rotation under a fixed Sun.
    Spin(SpinSection),
    /// Sun directions and fluxes listed in the scene.
    Fixed(FixedSection),
    /// Real geometry from SPICE kernels.
    Spice(SpiceSection),
}

/// `[ephemeris] mode = "spice"`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpiceSection {
    /// Kernel files, relative to the scene file (SPK, binary PCK, text PCK, FK, LSK).
    pub kernels: Vec<PathBuf>,
    /// Epoch of the first step ("2018-06-10T00:00:00 UTC" or "... TDB").
    pub start: String,
    /// End of the window (exclusive), with `step_s`.
    pub stop: Option<String>,
    /// Time between steps, seconds, with `stop`.
    pub step_s: Option<f64>,
    /// Number of spins of the first body (instead of stop/step_s).
    pub spins: Option<f64>,
    /// Steps per spin, with `spins` (default 360).
    pub steps_per_spin: Option<usize>,
    /// Aberration correction of the Sun's position: NONE, LT, LT+S (default), CN, CN+S.
    #[serde(default = "default_aberration")]
    pub aberration: String,
    /// Irradiance at 1 AU, W/m².
    #[serde(default = "default_solar_constant")]
    pub solar_constant_w_m2: f64,
}

/// `stereographic = { ... }` of a body: its mesh vertices are polar-stereographic `x`, `y`
/// and the height above a sphere, in the mesh's unit (see [`crate::mesh::projection`]).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereographicSection {
    /// "north" or "south".
    pub pole: Pole,
    /// Radius of the reference sphere, km.
    pub radius_km: f64,
}

/// `orbit = { ... }` of a body: a circular, tidally locked orbit about the first body,
/// for bodies no kernel covers.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OrbitSection {
    /// Orbit radius, km.
    pub radius_km: f64,
    /// Orbital period, hours (negative: retrograde).
    pub period_h: f64,
    /// Right ascension of the orbit pole, J2000, degrees (default 0).
    #[serde(default)]
    pub pole_ra_deg: f64,
    /// Declination of the orbit pole, J2000, degrees (default 90).
    #[serde(default = "default_pole_dec")]
    pub pole_dec_deg: f64,
    /// Angle from the ascending node at the first epoch, degrees.
    #[serde(default)]
    pub phase_deg: f64,
}

fn default_pole_dec() -> f64 {
    90.0
}

/// `ellipsoid = { ... }` of a body: a generated triaxial ellipsoid mesh.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EllipsoidSection {
    /// Semi-axes a, b, c in km (default: the body's radii from the loaded text PCK).
    pub radii_km: Option<[f64; 3]>,
    /// Geodesic subdivisions: 20·4^levels facets (default 4: 5,120 facets).
    #[serde(default = "default_levels")]
    pub levels: u32,
}

/// Where a body's shape comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape<'a> {
    /// A mesh file.
    File {
        path: &'a Path,
        units: LengthUnit,
        format: Option<MeshFormat>,
    },
    /// A generated ellipsoid.
    Ellipsoid {
        radii_km: Option<[f64; 3]>,
        levels: u32,
    },
}

/// `[ephemeris] mode = "spin"`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpinSection {
    /// Heliocentric distance, AU.
    pub distance_au: f64,
    /// Irradiance at 1 AU, W/m².
    #[serde(default = "default_solar_constant")]
    pub solar_constant_w_m2: f64,
    /// Latitude of the sub-solar point, degrees (default 0; or give obliquity and season).
    pub subsolar_latitude_deg: Option<f64>,
    /// Obliquity of the spin axis to the orbit, degrees (with `solar_longitude_deg`).
    pub obliquity_deg: Option<f64>,
    /// Season: the Sun's longitude from the body's vernal equinox, degrees.
    pub solar_longitude_deg: Option<f64>,
    /// Steps per spin period of the first body.
    #[serde(default = "default_steps")]
    pub steps_per_period: usize,
    /// Number of spin periods covered.
    #[serde(default = "one")]
    pub periods: f64,
    /// Epoch of the first step ("2018-06-10T00:00:00 UTC"; default J2000 TDB).
    pub start: Option<String>,
}

/// `[ephemeris] mode = "fixed"`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedSection {
    /// Irradiance at 1 AU, W/m², for suns given by distance.
    #[serde(default = "default_solar_constant")]
    pub solar_constant_w_m2: f64,
    /// Time each listed Sun stands for, seconds.
    #[serde(default = "one")]
    pub step_s: f64,
    /// Epoch of the first step.
    pub start: Option<String>,
    /// The listed Suns, one per step.
    pub sun: Vec<FixedSunSection>,
}

/// One `[[ephemeris.sun]]` entry.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedSunSection {
    /// Vector toward the Sun in the scene frame (normalised on load).
    pub direction: [f64; 3],
    /// Sun distance, AU (flux = solar constant / distance²).
    pub distance_au: Option<f64>,
    /// Irradiance, W/m² (instead of a distance).
    pub flux_w_m2: Option<f64>,
}

/// How to treat a mesh's facet orientation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Orient {
    /// Use the file's vertex order (warn if the mesh looks inside out).
    #[default]
    AsIs,
    /// Flip every facet if the signed volume is negative (closed meshes).
    Outward,
    /// Flip every facet.
    Flip,
}

/// One `[[body]]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySection {
    /// Unique name used in outputs.
    pub name: String,
    /// Mesh file, relative to the scene file (or give `ellipsoid`).
    pub mesh: Option<PathBuf>,
    /// Length unit of the mesh file: "km" or "m".
    pub units: Option<LengthUnit>,
    /// A generated ellipsoid instead of a mesh file.
    pub ellipsoid: Option<EllipsoidSection>,
    /// NAIF id (SPICE mode).
    pub naif_id: Option<i32>,
    /// Body-fixed frame (SPICE mode; default the IAU frame of `naif_id`), e.g. "MOON_ME".
    pub frame: Option<String>,
    /// A synthetic circular orbit about the first body (SPICE mode, instead of `naif_id`).
    pub orbit: Option<OrbitSection>,
    /// The mesh file holds polar-stereographic map coordinates and heights.
    pub stereographic: Option<StereographicSection>,
    /// Mesh format (default: from the extension).
    pub format: Option<MeshFormat>,
    /// Orientation handling.
    #[serde(default)]
    pub orient: Orient,
    /// Body centre in the scene frame, km.
    #[serde(default)]
    pub position_km: [f64; 3],
    /// Spin period, hours (spin mode; required for the first body; omit: not rotating).
    pub spin_period_h: Option<f64>,
    /// Rotation angle about the spin axis at the first step, degrees.
    #[serde(default)]
    pub initial_rotation_deg: f64,
    /// Reflectance model (`slim render`, `slim fit`): `model = "hapke"` and its
    /// parameters, optionally `bands.NAME = { ... }` overriding them per band.
    pub material: Option<toml::Table>,
    /// Lambertian albedo of every facet (with `[scatter]`).
    pub albedo: Option<f64>,
    /// Per-facet albedo: a text file with one value per line in facet order (`#` starts a
    /// comment), relative to the scene file.
    pub albedo_file: Option<PathBuf>,
    /// Albedo per `[[band]]` name (with `[scatter]`); bands left out use the albedo above.
    #[serde(default)]
    pub albedo_bands: std::collections::BTreeMap<String, f64>,
}

impl BodySection {
    /// The body's shape source (valid after [`Scene::load`]).
    pub fn shape(&self) -> Shape<'_> {
        match (&self.mesh, &self.ellipsoid) {
            (Some(path), _) => Shape::File {
                path,
                units: self.units.unwrap_or_default(),
                format: self.format,
            },
            (None, Some(e)) => Shape::Ellipsoid {
                radii_km: e.radii_km,
                levels: e.levels,
            },
            (None, None) => Shape::Ellipsoid {
                radii_km: None,
                levels: default_levels(),
            },
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    #[serde(default)]
    run: RunSection,
    #[serde(default)]
    output: OutputSection,
    scatter: Option<ScatterSection>,
    /// Read in a second pass, by `mode`, so errors inside keep their key paths.
    ephemeris: toml::Table,
    body: Vec<BodySection>,
    camera: Option<CameraSection>,
    #[serde(default)]
    band: Vec<BandSection>,
}

fn yes() -> bool {
    true
}
fn default_max_orders() -> u32 {
    1000
}
fn default_scatter_tolerance() -> f64 {
    1e-6
}
fn default_inter_body_tolerance() -> f64 {
    1e-4
}
fn default_near_field_ratio() -> f64 {
    crate::scatter::form_factor::NearField::default().far_ratio
}
fn default_solar_constant() -> f64 {
    crate::SOLAR_CONSTANT_W_M2
}
fn default_aberration() -> String {
    "LT+S".into()
}
fn z_axis() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn eight() -> u8 {
    8
}
fn default_levels() -> u32 {
    4
}
fn default_steps() -> usize {
    360
}
fn one<T: From<u8>>() -> T {
    T::from(1)
}

/// The epoch used when a scene gives none: J2000 (2000-01-01T12:00:00 TDB).
pub const DEFAULT_START: &str = "2000-01-01T12:00:00 TDB";

impl Scene {
    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene> {
        let source = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let text = std::str::from_utf8(&source)
            .map_err(|e| Error::file(path, format!("not UTF-8 text: {e}")))?;
        Scene::parse(path, text, source.clone())
    }

    /// Parses scene text as if read from `path` (paths resolve relative to its folder).
    pub fn parse(path: &Path, text: &str, source: Vec<u8>) -> Result<Scene> {
        let de = toml::Deserializer::parse(text).map_err(|e| toml_error(path, text, &e))?;
        let file: SceneFile = deserialize_at(path, Some(text), "", de)?;
        let ephemeris = ephemeris_section(path, file.ephemeris)?;
        let folder = path.parent().unwrap_or(Path::new("."));
        let mut bodies = file.body;
        for b in &mut bodies {
            b.mesh = b.mesh.as_ref().map(|m| folder.join(m));
            b.albedo_file = b.albedo_file.as_ref().map(|m| folder.join(m));
        }
        let mut ephemeris = ephemeris;
        if let EphemerisSection::Spice(s) = &mut ephemeris {
            s.kernels = s.kernels.iter().map(|k| folder.join(k)).collect();
        }
        let (start_text, stop_text) = match &ephemeris {
            EphemerisSection::Spin(s) => (s.start.clone(), None),
            EphemerisSection::Fixed(f) => (f.start.clone(), None),
            EphemerisSection::Spice(s) => (Some(s.start.clone()), s.stop.clone()),
        };
        let start_text = start_text.as_deref().unwrap_or(DEFAULT_START);
        let start = parse_epoch(path, "ephemeris.start", start_text)?;
        let stop = stop_text
            .map(|t| parse_epoch(path, "ephemeris.stop", &t))
            .transpose()?;
        let name = file.run.name.clone().unwrap_or_else(|| {
            path.file_stem()
                .map_or("run".into(), |s| s.to_string_lossy().into_owned())
        });
        let scene = Scene {
            path: path.to_path_buf(),
            source,
            name,
            run: file.run,
            output: file.output,
            scatter: file.scatter,
            ephemeris,
            bodies,
            start,
            stop,
            camera: file.camera,
            bands: file.band,
        };
        scene.validate()?;
        Ok(scene)
    }

    fn err(&self, key: impl Into<String>, msg: impl Into<String>) -> Error {
        Error::Scene {
            path: self.path.clone(),
            key: key.into(),
            msg: msg.into(),
        }
    }

    fn validate(&self) -> Result<()> {
        positive(self, "run.bin_width_w_m2", self.run.bin_width_w_m2)?;
        check_name(self, "run.name", &self.name)?;
        if self.bodies.is_empty() {
            return Err(self.err("body", "a scene needs at least one [[body]]"));
        }
        for (i, b) in self.bodies.iter().enumerate() {
            let key = |k: &str| format!("body[{i}].{k}");
            check_name(self, &key("name"), &b.name)?;
            if self.bodies[..i]
                .iter()
                .any(|o| o.name.eq_ignore_ascii_case(&b.name))
            {
                return Err(self.err(key("name"), format!("'{}' is used twice", b.name)));
            }
            if b.position_km.iter().any(|x| !x.is_finite()) {
                return Err(self.err(key("position_km"), "must be finite numbers"));
            }
            if let Some(p) = b.spin_period_h {
                positive(self, &key("spin_period_h"), p)?;
            }
            finite(self, &key("initial_rotation_deg"), b.initial_rotation_deg)?;
            let spice = matches!(self.ephemeris, EphemerisSection::Spice(_));
            for (given, what) in [(b.frame.is_some(), "frame"), (b.orbit.is_some(), "orbit")] {
                if given && !spice {
                    return Err(self.err(key(what), "only in spice mode"));
                }
            }
        }
        for (i, b) in self.bodies.iter().enumerate() {
            self.validate_shape(i, b)?;
            if b.material.is_some() {
                self.material(i, None)?;
                for band in &self.bands {
                    self.material(i, Some(&band.name))?;
                }
            }
        }
        self.validate_bands()?;
        if let Some(c) = &self.camera {
            self.validate_camera(c)?;
        }
        self.validate_scatter()?;
        match &self.ephemeris {
            EphemerisSection::Spin(s) => self.validate_spin(s),
            EphemerisSection::Fixed(f) => self.validate_fixed(f),
            EphemerisSection::Spice(s) => self.validate_spice(s),
        }
    }

    /// Every file the scene names, each with the key that names it: mesh files, SPICE
    /// kernels and per-facet albedo files, resolved relative to the scene file. Whatever
    /// reads input files for a scene reads only these; the service checks exactly these.
    pub fn input_files(&self) -> Vec<(String, &Path)> {
        let mut files = Vec::new();
        for (i, b) in self.bodies.iter().enumerate() {
            if let Some(mesh) = &b.mesh {
                files.push((format!("body[{i}].mesh"), mesh.as_path()));
            }
            if let Some(albedo) = &b.albedo_file {
                files.push((format!("body[{i}].albedo_file"), albedo.as_path()));
            }
        }
        if let EphemerisSection::Spice(s) = &self.ephemeris {
            for (i, k) in s.kernels.iter().enumerate() {
                files.push((format!("ephemeris.kernels[{i}]"), k.as_path()));
            }
        }
        files
    }

    /// The scene's solar constant (W/m² at 1 AU).
    pub fn solar_constant_w_m2(&self) -> f64 {
        match &self.ephemeris {
            EphemerisSection::Spin(s) => s.solar_constant_w_m2,
            EphemerisSection::Fixed(f) => f.solar_constant_w_m2,
            EphemerisSection::Spice(s) => s.solar_constant_w_m2,
        }
    }

    /// Body `i`'s material in `band` (None: the base parameters): its `[body.material]`
    /// table with the band's overrides applied. Errors name the key.
    pub fn material(&self, i: usize, band: Option<&str>) -> Result<Material> {
        let key = format!("body[{i}].material");
        let table = self.bodies[i]
            .material
            .as_ref()
            .ok_or_else(|| self.err(&key, "missing: give the body a reflectance model"))?;
        let mut merged = table.clone();
        let overrides = match merged.remove("bands") {
            Some(toml::Value::Table(t)) => t,
            Some(_) => return Err(self.err(format!("{key}.bands"), "must be a table of bands")),
            None => toml::Table::new(),
        };
        for name in overrides.keys() {
            if !self.bands.iter().any(|b| &b.name == name) {
                return Err(self.err(format!("{key}.bands.{name}"), "no [[band]] has this name"));
            }
        }
        // Each entry keeps the key path it came from, for error messages.
        let mut entries: Vec<(String, toml::Value, String)> = merged
            .into_iter()
            .map(|(k, v)| (k, v, key.clone()))
            .collect();
        if let Some(name) = band {
            let band_key = format!("{key}.bands.{name}");
            let band_table = match overrides.get(name) {
                Some(toml::Value::Table(t)) => t.clone(),
                Some(_) => return Err(self.err(band_key, "must be a table of parameters")),
                None => toml::Table::new(),
            };
            for (k, v) in band_table {
                if k == "model" || k == "bands" {
                    return Err(self.err(
                        format!("{band_key}.{k}"),
                        "a band may change parameters, not the model",
                    ));
                }
                entries.retain(|e| e.0 != k);
                entries.push((k, v, band_key.clone()));
            }
        }
        self.material_from_entries(&key, entries)
    }

    /// A material from `model`, `h_function` and numeric parameter entries.
    fn material_from_entries(
        &self,
        key: &str,
        entries: Vec<(String, toml::Value, String)>,
    ) -> Result<Material> {
        let mut model = None;
        let mut h_function = None;
        let mut params = Vec::new();
        for (k, v, from) in entries {
            let at = format!("{from}.{k}");
            match (k.as_str(), v) {
                ("model", toml::Value::String(m)) => model = Some(m),
                ("h_function", toml::Value::String(f)) => {
                    h_function = Some(match f.as_str() {
                        "1981" => HFunction::Hapke1981,
                        "2002" => HFunction::Hapke2002,
                        other => {
                            return Err(self.err(at, format!("'{other}': use \"1981\" or \"2002\"")))
                        }
                    })
                }
                (_, toml::Value::Float(x)) => params.push((k, x, at)),
                (_, toml::Value::Integer(x)) => params.push((k, x as f64, at)),
                (_, other) => {
                    return Err(
                        self.err(at, format!("must be a number, not a {}", other.type_str()))
                    )
                }
            }
        }
        let model = model.ok_or_else(|| {
            self.err(
                format!("{key}.model"),
                format!("missing: one of {}", Material::MODELS.join(", ")),
            )
        })?;
        let named: Vec<(String, f64)> = params.iter().map(|(k, x, _)| (k.clone(), *x)).collect();
        Material::from_params(&model, &named, h_function).map_err(|e| {
            // Point at the parameter the message names, else at the material.
            let at = params
                .iter()
                .find(|(k, _, _)| {
                    e.to_string().contains(&format!("'{k}'"))
                        || e.to_string().contains(&format!(" {k} ="))
                })
                .map_or(format!("{key}.model"), |(_, _, at)| at.clone());
            self.err(at, e.to_string())
        })
    }

    fn validate_bands(&self) -> Result<()> {
        for (i, band) in self.bands.iter().enumerate() {
            check_name(self, &format!("band[{i}].name"), &band.name)?;
            if self.bands[..i].iter().any(|o| o.name == band.name) {
                return Err(self.err(
                    format!("band[{i}].name"),
                    format!("'{}' is used twice", band.name),
                ));
            }
            positive(
                self,
                &format!("band[{i}].solar_constant_w_m2"),
                band.solar_constant_w_m2,
            )?;
        }
        Ok(())
    }

    fn validate_camera(&self, c: &CameraSection) -> Result<()> {
        match (&c.preset, c.width, c.height, c.fov_deg) {
            (Some(p), None, None, None) if p == "dawn_fc" => {}
            (Some(p), None, None, None) => {
                return Err(self.err(
                    "camera.preset",
                    format!("unknown preset '{p}': the presets are \"dawn_fc\""),
                ))
            }
            (None, Some(w), Some(h), Some(fov)) => {
                crate::render::camera::Camera::with_fov(w, h, fov)
                    .map_err(|e| self.err("camera", e.to_string()))?;
            }
            _ => {
                return Err(self.err(
                    "camera",
                    "give either preset = \"dawn_fc\", or width, height and fov_deg",
                ))
            }
        }
        match (c.position_km, c.observer_naif_id) {
            (Some(_), Some(_)) => {
                return Err(self.err(
                    "camera",
                    "give either position_km or observer_naif_id, not both",
                ))
            }
            (None, None) => {
                return Err(self.err(
                    "camera.position_km",
                    "missing: give the camera's position, or observer_naif_id in spice mode",
                ))
            }
            (None, Some(_)) if !matches!(self.ephemeris, EphemerisSection::Spice(_)) => {
                return Err(self.err("camera.observer_naif_id", "only in spice mode"))
            }
            _ => {}
        }
        let vectors = [("position_km", c.position_km), ("up", Some(c.up))];
        for (k, v) in vectors.into_iter().chain([("look_at_km", c.look_at_km)]) {
            if v.is_some_and(|v| v.iter().any(|x| !x.is_finite())) {
                return Err(self.err(format!("camera.{k}"), "must be finite numbers"));
            }
        }
        if let Some(t) = &c.target {
            if c.look_at_km.is_some() {
                return Err(self.err("camera", "give either target or look_at_km, not both"));
            }
            if !self.bodies.iter().any(|b| &b.name == t) {
                return Err(self.err("camera.target", format!("no body is named '{t}'")));
            }
        }
        if !matches!(c.png_bits, 8 | 16) {
            return Err(self.err("camera.png_bits", "must be 8 or 16"));
        }
        if let Some(w) = c.png_white_i_over_f {
            positive(self, "camera.png_white_i_over_f", w)?;
        }
        if c.steps.as_ref().is_some_and(|s| s.is_empty()) {
            return Err(self.err("camera.steps", "list at least one step (or leave it out)"));
        }
        Ok(())
    }

    fn validate_shape(&self, i: usize, b: &BodySection) -> Result<()> {
        let key = |k: &str| format!("body[{i}].{k}");
        match (&b.mesh, &b.ellipsoid, b.units) {
            (Some(_), None, Some(_)) => match &b.stereographic {
                Some(p) => positive(self, &key("stereographic.radius_km"), p.radius_km),
                None => Ok(()),
            },
            (Some(_), None, None) => Err(self.err(
                key("units"),
                "missing field `units`: the mesh file's length unit, \"km\" or \"m\"",
            )),
            (Some(_), Some(_), _) => Err(self.err(
                format!("body[{i}]"),
                "give either mesh or ellipsoid, not both",
            )),
            (None, None, _) => Err(self.err(
                format!("body[{i}]"),
                "give a mesh file (mesh = ..., units = ...) or ellipsoid = { ... }",
            )),
            (None, Some(_), _) if b.stereographic.is_some() => Err(self.err(
                key("stereographic"),
                "applies to mesh files only, not to a generated ellipsoid",
            )),
            (None, Some(e), _) => {
                if let Some(r) = e.radii_km {
                    if r.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
                        return Err(
                            self.err(key("ellipsoid.radii_km"), "must be three positive numbers")
                        );
                    }
                } else if b.naif_id.is_none()
                    || !matches!(self.ephemeris, EphemerisSection::Spice(_))
                {
                    return Err(self.err(key("ellipsoid.radii_km"), "missing: give the radii, or a naif_id in spice mode to take them from the PCK"));
                }
                if e.levels > 8 {
                    return Err(self.err(key("ellipsoid.levels"), "at most 8 (1,310,720 facets)"));
                }
                Ok(())
            }
        }
    }

    /// A SPICE body is placed by the kernels (`naif_id`), or, after the first, by a
    /// synthetic `orbit` or a fixed `position_km`.
    fn validate_spice_placement(&self, i: usize, b: &BodySection) -> Result<()> {
        let key = |k: &str| format!("body[{i}].{k}");
        let fixed = b.position_km != [0.0; 3];
        match (b.naif_id, &b.orbit) {
            (Some(_), Some(_)) => {
                Err(self.err(key("orbit"), "give either naif_id or orbit, not both"))
            }
            (Some(_), None) if fixed => Err(self.err(
                key("position_km"),
                "a body with a naif_id is placed by the kernels; drop position_km",
            )),
            (Some(_), None) => Ok(()),
            (None, _) if i == 0 => Err(self.err(
                key("naif_id"),
                "missing: the first body needs a NAIF id the kernels cover (e.g. 401 for Phobos)",
            )),
            (None, _) if b.frame.is_some() => Err(self.err(
                key("frame"),
                "only bodies with a naif_id have a kernel frame",
            )),
            (None, Some(_)) if fixed => Err(self.err(
                key("position_km"),
                "give either orbit or position_km, not both",
            )),
            (None, Some(o)) => {
                positive(self, &key("orbit.radius_km"), o.radius_km)?;
                finite(self, &key("orbit.period_h"), o.period_h)?;
                if o.period_h == 0.0 {
                    return Err(self.err(key("orbit.period_h"), "must not be zero"));
                }
                finite(self, &key("orbit.pole_ra_deg"), o.pole_ra_deg)?;
                finite(self, &key("orbit.pole_dec_deg"), o.pole_dec_deg)?;
                finite(self, &key("orbit.phase_deg"), o.phase_deg)
            }
            (None, None) if fixed => Ok(()),
            (None, None) => Err(self.err(
                key("naif_id"),
                "missing: give a naif_id the kernels cover, a synthetic orbit = { radius_km, \
                 period_h, ... }, or a fixed position_km relative to the first body",
            )),
        }
    }

    fn validate_scatter(&self) -> Result<()> {
        let albedo = |key: &str, a: Option<f64>| {
            match a {
            Some(a) if !(a.is_finite() && (0.0..1.0).contains(&a)) => Err(self.err(
                key,
                format!("must be at least 0 and below 1 (1 reflects everything and never converges), not {a}"),
            )),
            _ => Ok(()),
        }
        };
        for (i, b) in self.bodies.iter().enumerate() {
            albedo(&format!("body[{i}].albedo"), b.albedo)?;
            for (name, value) in &b.albedo_bands {
                let key = format!("body[{i}].albedo_bands.{name}");
                if !self.bands.iter().any(|band| &band.name == name) {
                    return Err(self.err(key, "no [[band]] has this name"));
                }
                albedo(&key, Some(*value))?;
            }
            if b.albedo.is_some() && b.albedo_file.is_some() {
                return Err(self.err(
                    format!("body[{i}]"),
                    "give either albedo or albedo_file, not both",
                ));
            }
        }
        let Some(s) = self.scatter.as_ref().filter(|s| s.enabled) else {
            return Ok(());
        };
        albedo("scatter.albedo", s.albedo)?;
        positive(self, "scatter.tolerance", s.tolerance)?;
        positive(self, "scatter.near_field_ratio", s.near_field_ratio)?;
        if !(s.inter_body_tolerance.is_finite() && s.inter_body_tolerance >= 0.0) {
            return Err(self.err(
                "scatter.inter_body_tolerance",
                "must be a finite number ≥ 0",
            ));
        }
        if s.max_orders == 0 {
            return Err(self.err("scatter.max_orders", "must be at least 1"));
        }
        if let Some(i) = self
            .bodies
            .iter()
            .position(|b| b.albedo.is_none() && b.albedo_file.is_none() && s.albedo.is_none())
        {
            return Err(self.err(
                format!("body[{i}].albedo"),
                "missing: scattering needs an albedo for every body (here, in albedo_file, or in [scatter])",
            ));
        }
        Ok(())
    }

    fn validate_spice(&self, s: &SpiceSection) -> Result<()> {
        if s.kernels.is_empty() {
            return Err(self.err("ephemeris.kernels", "list at least one kernel"));
        }
        positive(self, "ephemeris.solar_constant_w_m2", s.solar_constant_w_m2)?;
        if crate::ephemeris::spice::parse_aberration(&s.aberration).is_none() {
            return Err(self.err(
                "ephemeris.aberration",
                format!("'{}' is not one of NONE, LT, LT+S, CN, CN+S", s.aberration),
            ));
        }
        for (i, b) in self.bodies.iter().enumerate() {
            self.validate_spice_placement(i, b)?;
        }
        match (s.stop.is_some(), s.step_s, s.spins, s.steps_per_spin) {
            (true, Some(step), None, None) => {
                positive(self, "ephemeris.step_s", step)?;
                if self.stop.is_some_and(|stop| stop <= self.start) {
                    return Err(self.err("ephemeris.stop", "must be after start"));
                }
                Ok(())
            }
            (false, None, Some(spins), steps) => {
                positive(self, "ephemeris.spins", spins)?;
                if steps == Some(0) {
                    return Err(self.err("ephemeris.steps_per_spin", "must be at least 1"));
                }
                Ok(())
            }
            _ => Err(self.err(
                "ephemeris",
                "give either stop and step_s, or spins (and steps_per_spin)",
            )),
        }
    }

    fn validate_spin(&self, s: &SpinSection) -> Result<()> {
        positive(self, "ephemeris.distance_au", s.distance_au)?;
        positive(self, "ephemeris.solar_constant_w_m2", s.solar_constant_w_m2)?;
        positive(self, "ephemeris.periods", s.periods)?;
        if s.steps_per_period == 0 {
            return Err(self.err("ephemeris.steps_per_period", "must be at least 1"));
        }
        if self.bodies[0].spin_period_h.is_none() {
            return Err(self.err(
                "body[0].spin_period_h",
                "spin mode needs the first body's spin period (hours)",
            ));
        }
        match (
            s.subsolar_latitude_deg,
            s.obliquity_deg,
            s.solar_longitude_deg,
        ) {
            (Some(lat), None, None) if (-90.0..=90.0).contains(&lat) => Ok(()),
            (Some(_), None, None) => Err(self.err(
                "ephemeris.subsolar_latitude_deg",
                "must be between -90 and 90 degrees",
            )),
            (None, Some(o), Some(l)) if o.is_finite() && l.is_finite() => Ok(()),
            (None, None, None) => Ok(()),
            _ => Err(self.err(
                "ephemeris",
                "give either subsolar_latitude_deg, or both obliquity_deg and solar_longitude_deg \
                 (finite numbers)",
            )),
        }
    }

    fn validate_fixed(&self, f: &FixedSection) -> Result<()> {
        positive(self, "ephemeris.step_s", f.step_s)?;
        positive(self, "ephemeris.solar_constant_w_m2", f.solar_constant_w_m2)?;
        if f.sun.is_empty() {
            return Err(self.err(
                "ephemeris.sun",
                "fixed mode needs at least one [[ephemeris.sun]]",
            ));
        }
        for (i, s) in f.sun.iter().enumerate() {
            let key = |k: &str| format!("ephemeris.sun[{i}].{k}");
            if crate::ephemeris::fixed::normalized_direction(s.direction).is_none() {
                return Err(self.err(key("direction"), "must be a finite, non-zero vector"));
            }
            match (s.distance_au, s.flux_w_m2) {
                (Some(d), None) => positive(self, &key("distance_au"), d)?,
                (None, Some(w)) if w.is_finite() && w >= 0.0 => {}
                (None, Some(_)) => {
                    return Err(self.err(key("flux_w_m2"), "must be a finite number ≥ 0"))
                }
                _ => {
                    return Err(self.err(
                        format!("ephemeris.sun[{i}]"),
                        "give exactly one of distance_au and flux_w_m2",
                    ))
                }
            }
        }
        Ok(())
    }
}

fn positive(scene: &Scene, key: &str, x: f64) -> Result<()> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(scene.err(key, format!("must be a positive number, not {x}")))
    }
}

fn finite(scene: &Scene, key: &str, x: f64) -> Result<()> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(scene.err(key, format!("must be a finite number, not {x}")))
    }
}

fn parse_epoch(path: &Path, key: &str, text: &str) -> Result<Epoch> {
    Epoch::from_str(text).map_err(|e| Error::Scene {
        path: path.to_path_buf(),
        key: key.into(),
        msg: format!("'{text}' is not an epoch ({e}); write e.g. \"2018-06-10T00:00:00 UTC\""),
    })
}

/// Names become file names (`BODY.ply`, `results/NAME`): keep them to letters, digits,
/// `-`, `_` and `.`, not starting with a dot, so no name can reach outside a folder.
fn check_name(scene: &Scene, key: &str, name: &str) -> Result<()> {
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    if name.is_empty() || name.len() > 100 || name.starts_with('.') || !name.chars().all(allowed) {
        return Err(scene.err(
            key,
            format!(
                "'{name}' is not a usable name: use 1 to 100 letters, digits, '-', '_' or '.', \
                 not starting with '.'"
            ),
        ));
    }
    Ok(())
}

/// Reads `[ephemeris]` by its `mode`.
fn ephemeris_section(path: &Path, mut table: toml::Table) -> Result<EphemerisSection> {
    let err = |msg: String| Error::Scene {
        path: path.to_path_buf(),
        key: "ephemeris.mode".into(),
        msg,
    };
    const MODES: &str = "\"spin\", \"fixed\" or \"spice\"";
    let mode = match table.remove("mode") {
        Some(toml::Value::String(mode)) => mode,
        Some(other) => return Err(err(format!("must be {MODES}, not a {}", other.type_str()))),
        None => return Err(err(format!("missing: write mode = one of {MODES}"))),
    };
    let table = toml::Value::Table(table);
    match mode.as_str() {
        "spin" => Ok(EphemerisSection::Spin(deserialize_at(
            path,
            None,
            "ephemeris",
            table,
        )?)),
        "fixed" => Ok(EphemerisSection::Fixed(deserialize_at(
            path,
            None,
            "ephemeris",
            table,
        )?)),
        "spice" => Ok(EphemerisSection::Spice(deserialize_at(
            path,
            None,
            "ephemeris",
            table,
        )?)),
        other => Err(err(format!("unknown mode '{other}': use {MODES}"))),
    }
}

/// Deserialises `T`, reporting any error with its key path (below `prefix`), toml's own
/// message, and the line when the source `text` is at hand.
fn deserialize_at<'de, T, D>(path: &Path, text: Option<&str>, prefix: &str, de: D) -> Result<T>
where
    T: Deserialize<'de>,
    D: serde::Deserializer<'de, Error = toml::de::Error>,
{
    serde_path_to_error::deserialize(de).map_err(|e| {
        let inner = e.inner();
        let line = text.zip(inner.span()).map(|(t, s)| line_of(t, s.start));
        let below = e.path().to_string();
        let key = match (prefix, below.as_str()) {
            ("", ".") => "(top level)".to_string(),
            (p, ".") => p.to_string(),
            ("", b) => b.to_string(),
            (p, b) => format!("{p}.{b}"),
        };
        let msg = inner.message().trim().to_string();
        Error::Scene {
            path: path.to_path_buf(),
            key,
            msg: line.map_or(msg.clone(), |l| format!("{msg} (line {l})")),
        }
    })
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    text.get(..offset)
        .map_or(1, |before| before.matches('\n').count() + 1)
}

/// A TOML syntax error, located by line.
fn toml_error(path: &Path, text: &str, e: &toml::de::Error) -> Error {
    let line = e.span().map_or(1, |s| line_of(text, s.start));
    Error::at_line(path, line, e.message().trim())
}
