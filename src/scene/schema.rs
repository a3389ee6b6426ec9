//! Scene schema: every section and key a scene file may hold, as typed values.
//!
//! In: TOML tables (through serde). Out: the section types a [`super::Scene`] is made of.
//! Units are in the key names (`_km`, `_h`, `_deg`, `_w_m2`, `_au`); paths are resolved
//! relative to the scene file by [`super::Scene::parse`]. Defaults are stated beside each
//! key; `docs/scene.md` documents every key with a complete example.

use crate::horizon::shadows::{DEFAULT_AZIMUTHS, DEFAULT_SUN_SAMPLES};
use crate::horizon::{HorizonMode, ShadowMethod, SunShape};
use crate::mesh::projection::Pole;
use crate::mesh::{LengthUnit, MeshFormat};
use crate::trace::TracerKind;
use hifitime::Epoch;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

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
    /// Shadow tracer: "auto" (default: "bvh" when the run's steps pay for its horizon
    /// bound, else "sunview"), "sunview" (a grid per step, no setup), "bvh" (a tree and a
    /// horizon bound built once: faster per step) or "grid" (the paper's reference).
    pub tracer: TracerKind,
    /// Width of the CDF bins, W/m².
    pub bin_width_w_m2: f64,
    /// A body's own shadows: "auto" (default: a horizon map when cached or when the run
    /// is long enough to pay for it), "rays" or "horizon".
    pub shadows: ShadowMethod,
    /// How a horizon map decides: "exact" (default: rays where it is not certain, so a
    /// point Sun's shadows equal the tracers') or "approximate" (the map alone).
    pub horizon_mode: HorizonMode,
    /// Azimuth wedges of a horizon map (default 128, 2.8° each; 8 to 4096).
    pub horizon_azimuths: u32,
    /// The Sun as a "disk" (the visible share of the disk; the default wherever the
    /// Sun's distance is known) or a "point" (the default for a fixed Sun given by its
    /// flux alone, which has no angular size): [`super::Scene::sun`].
    pub sun: Option<SunShape>,
    /// Linear limb-darkening coefficient of the disk Sun, 0 (uniform, default) to 1.
    pub limb_darkening: f64,
    /// Rays per facet through a disk Sun toward another body's mesh (default 32, 1 to
    /// 1024); a generated ellipsoid's share is a closed form and needs none.
    pub sun_samples: u32,
    /// Folder of the horizon-map cache, relative to the scene file (default:
    /// `$SLIM_CACHE_DIR`, else `$XDG_CACHE_HOME/slim/horizon`, else
    /// `~/.cache/slim/horizon`).
    pub cache_dir: Option<PathBuf>,
}

impl Default for RunSection {
    fn default() -> Self {
        RunSection {
            name: None,
            tracer: TracerKind::default(),
            bin_width_w_m2: 10.0,
            shadows: ShadowMethod::default(),
            horizon_mode: HorizonMode::default(),
            horizon_azimuths: DEFAULT_AZIMUTHS,
            sun: None,
            limb_darkening: 0.0,
            sun_samples: DEFAULT_SUN_SAMPLES,
            cache_dir: None,
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
    pub solver: SolverKind,
    /// Jacobi: most scattering orders; CG: most iterations.
    #[serde(default = "default_max_orders")]
    pub max_orders: u32,
    /// Relative tolerance of each step's solve.
    #[serde(default = "default_scatter_tolerance")]
    pub tolerance: f64,
    /// Leave out light between two bodies when its bound is below this share of the flux.
    #[serde(default = "default_inter_body_tolerance")]
    pub inter_body_tolerance: f64,
    /// Keep an inter-body block while the bodies' motion since it was computed changes
    /// the light it carries by at most this share of the flux (0: recompute at any motion).
    #[serde(default)]
    pub inter_body_reuse: f64,
    /// Facet pairs closer than this many facet sizes get the exact near-field integral.
    #[serde(default = "default_near_field_ratio")]
    pub near_field_ratio: f64,
    /// The first bounce: "lambert" (default) or "material" (each body's
    /// `[body.material]` reflectance model; higher orders stay Lambertian).
    #[serde(default)]
    pub first_bounce: FirstBounceKind,
    /// Light from a generated ellipsoid without outputs (a planet beside a moon):
    /// "quadrature" (default: its visible cap, closed-form weights kept while it barely
    /// moves) or "facets" (its facets like any body's).
    #[serde(default)]
    pub planet_shine: PlanetShineKind,
    /// Gauss–Legendre nodes across a planet's visible cap (2n² points; default 8).
    #[serde(default = "default_planet_order")]
    pub planet_order: usize,
    /// Largest move of a planet (radians of direction, fraction of distance) before its
    /// weights are rebuilt (default 0.03).
    #[serde(default = "default_planet_reuse")]
    pub planet_reuse: f64,
}

/// `[scatter] planet_shine`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PlanetShineKind {
    #[default]
    Quadrature,
    Facets,
}

/// `[scatter] solver`: which method solves the multiple-scattering equation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SolverKind {
    /// Jacobi when every albedo is at most 0.5, conjugate gradients otherwise.
    #[default]
    Auto,
    /// The paper's iteration: iterate k holds scattering orders ≤ k.
    Jacobi,
    /// Conjugate gradients on the symmetric form (fast when albedo is near 1).
    Cg,
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

/// `[ephemeris] mode = "spice"`, validated: the steps are either a window or a number
/// of spins.
#[derive(Debug, Clone)]
pub struct SpiceSection {
    /// Kernel files, resolved relative to the scene file (SPK, binary PCK, text PCK, FK,
    /// LSK).
    pub kernels: Vec<PathBuf>,
    /// Which epochs the run steps through (from the scene's start).
    pub steps: SpiceSteps,
    /// Aberration correction of the Sun's position: NONE, LT, LT+S (default), CN, CN+S.
    pub aberration: String,
    /// Irradiance at 1 AU, W/m².
    pub solar_constant_w_m2: f64,
}

/// The two forms of a SPICE scene's steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpiceSteps {
    /// `stop` (exclusive) and `step_s`: a fixed window in steps of `step_s` seconds.
    Window { stop: Epoch, step_s: f64 },
    /// `spins` of the first body, `steps_per_spin` steps each (the spin period from the
    /// PCK or the body's `spin_period_h`).
    Spins { spins: f64, steps_per_spin: usize },
}

impl SpiceSteps {
    /// How many steps these are from `start`: the window rounded up, or the spins
    /// rounded to whole steps (at least one). A float, so that absurd requests can be
    /// told apart before anything is allocated.
    pub fn count(&self, start: Epoch) -> f64 {
        match *self {
            SpiceSteps::Window { stop, step_s } => ((stop - start).to_seconds() / step_s).ceil(),
            SpiceSteps::Spins {
                spins,
                steps_per_spin,
            } => (steps_per_spin as f64 * spins).round().max(1.0),
        }
    }
}

/// `[ephemeris] mode = "spice"` as written, before its steps are read into
/// [`SpiceSteps`].
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SpiceKeys {
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
    #[serde(default = "default_aberration")]
    pub aberration: String,
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default, Serialize)]
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

/// `surroundings = { ... }` of a body: a mesh file of terrain beyond the patch.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurroundingsSection {
    /// Mesh file, relative to the scene file.
    pub mesh: PathBuf,
    /// Its length unit: "km" or "m".
    pub units: LengthUnit,
    /// Mesh format (default: from the extension).
    pub format: Option<MeshFormat>,
}

/// One `[[body]]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySection {
    /// Unique name used in outputs.
    pub name: String,
    /// Whether the body gets statistics and output files (default true). With `false` it
    /// only casts shadows (and scatters light): no summary or CDF rows, no history, no
    /// PLY; its per-step geometry is still written.
    #[serde(default = "yes")]
    pub outputs: bool,
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
    /// Terrain around a patch that only casts shadows: it hides the Sun from the mesh's
    /// facets and enters their horizon maps, but gets no statistics and does not
    /// scatter. In the body's frame; projected like the mesh when `stereographic` is set.
    pub surroundings: Option<SurroundingsSection>,
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
    /// The body's shape source (valid after [`super::Scene::load`]).
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
pub(super) struct SceneFile {
    #[serde(default)]
    pub run: RunSection,
    #[serde(default)]
    pub output: OutputSection,
    pub scatter: Option<ScatterSection>,
    /// Read in a second pass, by `mode`, so errors inside keep their key paths.
    pub ephemeris: toml::Table,
    pub body: Vec<BodySection>,
    pub camera: Option<CameraSection>,
    #[serde(default)]
    pub band: Vec<BandSection>,
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
/// `[scatter] planet_order` unless the scene says otherwise: 8 nodes, 128 points (the
/// error against run time is in docs/scattered-light.md).
pub const DEFAULT_PLANET_ORDER: usize = 8;
/// `[scatter] planet_reuse` unless the scene says otherwise (radians of direction and
/// fraction of distance).
pub const DEFAULT_PLANET_REUSE: f64 = 0.03;

fn default_planet_order() -> usize {
    DEFAULT_PLANET_ORDER
}
fn default_planet_reuse() -> f64 {
    DEFAULT_PLANET_REUSE
}
/// `[scatter] near_field_ratio` when the scene gives none: facet pairs closer than 16
/// facet sizes get the exact near-field integral (why 16: `NearField::default` in
/// `scatter::form_factor`).
pub const DEFAULT_NEAR_FIELD_RATIO: f64 = 16.0;

fn default_near_field_ratio() -> f64 {
    DEFAULT_NEAR_FIELD_RATIO
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
pub(super) fn default_levels() -> u32 {
    4
}
fn default_steps() -> usize {
    360
}
fn one<T: From<u8>>() -> T {
    T::from(1)
}
