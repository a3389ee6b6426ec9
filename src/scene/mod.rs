//! Scene: the TOML file that describes a run, parsed and validated.
//!
//! In: a scene file path (or scene text and the path it stands for). Out: a [`Scene`]
//! with every path resolved relative to the scene file and every number checked. Unknown
//! keys are rejected with their dotted path (`body[0].spin_period`), as are missing,
//! out-of-range and inconsistent values; TOML syntax errors name the line.
//! `docs/scene.md` documents every key with a complete example.
//!
//! - [`schema`]: the sections and keys, as typed values with their defaults;
//! - `validate`: the checks a scene passes before anything is built;
//! - `materials`: a body's reflectance model, with per-band overrides merged.
//!
//! The scene depends on no stage that runs: it is read before anything is built, and
//! every stage reads it.

mod materials;
pub mod schema;
mod validate;

pub use schema::*;
pub use validate::{camera_size_problem, MAX_BODIES, MAX_SPAN_S, MAX_STEPS};

use crate::ephemeris::SunReturn;
use crate::error::{printable, Error, Result};
use crate::horizon::bound::BoundDetail;
use crate::horizon::disk::SolarDisk;
use crate::horizon::{Shadows, SunShape};
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
    /// `[camera]`: what `slim render` and `slim fit` see.
    pub camera: Option<CameraSection>,
    /// `[[band]]`: spectral bands (none: one band with the whole solar flux).
    pub bands: Vec<BandSection>,
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
        let folder = path.parent().unwrap_or(Path::new("."));
        let (ephemeris, start) = ephemeris_section(path, folder, file.ephemeris)?;
        let mut bodies = file.body;
        for b in &mut bodies {
            b.mesh = b.mesh.as_ref().map(|m| folder.join(m));
            b.albedo_file = b.albedo_file.as_ref().map(|m| folder.join(m));
            if let Some(s) = &mut b.surroundings {
                s.mesh = folder.join(&s.mesh);
            }
        }
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
            camera: file.camera,
            bands: file.band,
        };
        scene.validate()?;
        Ok(scene)
    }

    /// The scene's shadow settings, the cache folder resolved.
    pub fn shadows(&self) -> Shadows {
        Shadows {
            method: self.run.shadows,
            mode: self.run.horizon_mode,
            azimuths: self.run.horizon_azimuths,
            sun: self.sun(),
            disk: SolarDisk {
                limb_darkening: self.run.limb_darkening,
            },
            sun_samples: self.run.sun_samples,
            cache_dir: self.cache_dir(),
            // The plan decides these, from the run's steps (`crate::prepare`).
            bound_detail: BoundDetail::Whole,
            recall: SunReturn::UNKNOWN,
            sweeps: false,
            bands: Vec::new(),
        }
    }

    /// The Sun's shape: `[run] sun`, else a disk wherever the Sun's distance, and with
    /// it its angular size, is known at every step (spin and SPICE scenes, fixed Suns
    /// given by their distance), else a point.
    pub fn sun(&self) -> SunShape {
        self.run.sun.unwrap_or(match &self.ephemeris {
            EphemerisSection::Fixed(f) if f.sun.iter().any(|s| s.distance_au.is_none()) => {
                SunShape::Point
            }
            _ => SunShape::Disk,
        })
    }

    /// The folder cached horizon maps and form factors go to ([`crate::cache::dir_for`]).
    pub fn cache_dir(&self) -> Option<PathBuf> {
        let folder = self.path.parent().unwrap_or(Path::new("."));
        crate::cache::dir_for(folder, self.run.cache_dir.as_deref())
    }

    /// An error at `key` of this scene ([`Error::scene`]: shown printable and bounded).
    pub(crate) fn err(&self, key: impl Into<String>, msg: impl Into<String>) -> Error {
        Error::scene(&self.path, key, msg)
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
            if let Some(s) = &b.surroundings {
                files.push((format!("body[{i}].surroundings.mesh"), s.mesh.as_path()));
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

    /// How many steps the scene asks for, counted from the scene alone, before any file
    /// is read. A float, so that absurd requests (`periods = 1e30`) are told apart before
    /// anything is allocated.
    pub fn step_count(&self) -> f64 {
        match &self.ephemeris {
            EphemerisSection::Spin(s) => (s.steps_per_period as f64 * s.periods).round().max(1.0),
            EphemerisSection::Fixed(f) => f.sun.len() as f64,
            EphemerisSection::Spice(s) => s.steps.count(self.start),
        }
    }

    /// The time the run spans (seconds) where the scene alone gives it, with the key that
    /// sets it: spin mode and SPICE spins of a given period, and fixed Suns. (A SPICE
    /// window is two epochs, bounded by their format; a period from a PCK is checked when
    /// the kernels are read.)
    pub fn span_s(&self) -> Option<(f64, &'static str)> {
        let period_s = self.bodies.first()?.spin_period_h.map(|h| h * 3600.0);
        // The period is to blame when it alone is too long, else the count of periods.
        let periods = |count: f64, key: &'static str| {
            let period_s = period_s?;
            let blamed = if period_s > MAX_SPAN_S {
                "body[0].spin_period_h"
            } else {
                key
            };
            Some((period_s * count, blamed))
        };
        match &self.ephemeris {
            EphemerisSection::Spin(s) => periods(s.periods, "ephemeris.periods"),
            EphemerisSection::Fixed(f) => Some((f.step_s * f.sun.len() as f64, "ephemeris.step_s")),
            EphemerisSection::Spice(s) => match s.steps {
                SpiceSteps::Window { .. } => None,
                SpiceSteps::Spins { spins, .. } => periods(spins, "ephemeris.spins"),
            },
        }
    }

    /// The key that sets the number of steps, for errors that ask for fewer.
    pub fn step_key(&self) -> &'static str {
        match &self.ephemeris {
            EphemerisSection::Spin(_) => "ephemeris.steps_per_period",
            EphemerisSection::Fixed(_) => "ephemeris.sun",
            EphemerisSection::Spice(s) => match s.steps {
                SpiceSteps::Window { .. } => "ephemeris.step_s",
                SpiceSteps::Spins { .. } => "ephemeris.spins",
            },
        }
    }

    /// The scene's solar constant (W/m² at 1 AU).
    pub fn solar_constant_w_m2(&self) -> f64 {
        match &self.ephemeris {
            EphemerisSection::Spin(s) => s.solar_constant_w_m2,
            EphemerisSection::Fixed(f) => f.solar_constant_w_m2,
            EphemerisSection::Spice(s) => s.solar_constant_w_m2,
        }
    }
}

fn parse_epoch(path: &Path, key: &str, text: &str) -> Result<Epoch> {
    Epoch::from_str(text).map_err(|e| {
        let shown = printable(text, 80);
        let msg =
            format!("'{shown}' is not an epoch ({e}); write e.g. \"2018-06-10T00:00:00 UTC\"");
        Error::scene(path, key, msg)
    })
}

/// Reads `[ephemeris]` by its `mode`, with the epoch of the first step; kernel paths are
/// resolved relative to `folder`.
fn ephemeris_section(
    path: &Path,
    folder: &Path,
    mut table: toml::Table,
) -> Result<(EphemerisSection, Epoch)> {
    let err = |msg: String| Error::scene(path, "ephemeris.mode", msg);
    const MODES: &str = "\"spin\", \"fixed\" or \"spice\"";
    let mode = match table.remove("mode") {
        Some(toml::Value::String(mode)) => mode,
        Some(other) => return Err(err(format!("must be {MODES}, not a {}", other.type_str()))),
        None => return Err(err(format!("missing: write mode = one of {MODES}"))),
    };
    let table = toml::Value::Table(table);
    let start =
        |text: Option<&str>| parse_epoch(path, "ephemeris.start", text.unwrap_or(DEFAULT_START));
    match mode.as_str() {
        "spin" => {
            let s: SpinSection = deserialize_at(path, None, "ephemeris", table)?;
            let start = start(s.start.as_deref())?;
            Ok((EphemerisSection::Spin(s), start))
        }
        "fixed" => {
            let f: FixedSection = deserialize_at(path, None, "ephemeris", table)?;
            let start = start(f.start.as_deref())?;
            Ok((EphemerisSection::Fixed(f), start))
        }
        "spice" => {
            let keys: SpiceKeys = deserialize_at(path, None, "ephemeris", table)?;
            let spice = SpiceSection {
                kernels: keys.kernels.iter().map(|k| folder.join(k)).collect(),
                steps: spice_steps(path, &keys)?,
                aberration: keys.aberration,
                solar_constant_w_m2: keys.solar_constant_w_m2,
            };
            Ok((EphemerisSection::Spice(spice), start(Some(&keys.start))?))
        }
        other => Err(err(format!("unknown mode '{other}': use {MODES}"))),
    }
}

/// The steps of a SPICE scene: a window (`stop` and `step_s`) or a number of `spins`
/// (and `steps_per_spin`, default 360), never a mix.
fn spice_steps(path: &Path, keys: &SpiceKeys) -> Result<SpiceSteps> {
    match (&keys.stop, keys.step_s, keys.spins, keys.steps_per_spin) {
        (Some(stop), Some(step_s), None, None) => Ok(SpiceSteps::Window {
            stop: parse_epoch(path, "ephemeris.stop", stop)?,
            step_s,
        }),
        (None, None, Some(spins), steps_per_spin) => Ok(SpiceSteps::Spins {
            spins,
            steps_per_spin: steps_per_spin.unwrap_or(360),
        }),
        _ => Err(Error::Scene {
            path: path.to_path_buf(),
            key: "ephemeris".into(),
            msg: "give either stop and step_s, or spins (and steps_per_spin)".into(),
        }),
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
        // Both quote the file (a misspelt key, a bad value): shown escaped and shortened.
        let key = printable(&key, 200);
        let msg = printable(inner.message().trim(), 500);
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
