//! SPICE-driven geometry: the Sun and the bodies' poses from kernels, through anise.
//!
//! In: kernel files (SPK `.bsp`, binary PCK `.bpc`, text PCK `.tpc`, frame `.tf` and
//! leapseconds `.tls`; anything else is refused by name), the bodies' NAIF ids, the epochs
//! and an aberration correction. Out, per epoch: for every body, the unit vector toward
//! the Sun and its distance in the body-fixed frame (`spkpos("SUN", et, frame, abcorr,
//! body)`), the flux S₀/r², and the pose of every body relative to the first one (J2000
//! axes, geometric positions; scene frame = J2000 centred on the first body).
//!
//! Translations and aberration corrections come from anise; body-fixed rotations of text
//! PCK frames from [`pck::RotationModel`]. Errors name body, frame and epoch, and for an
//! epoch outside the kernels, the covered window.

mod daf;
pub mod frames;
pub mod pck;
pub mod text_kernel;

use super::synthetic::SyntheticMotion;
use super::{flux_at, BodyState, Ephemeris, EpochState};
use crate::error::{Error, Result};
use crate::world::Pose;
use anise::constants::frames::SUN_J2000;
use anise::prelude::{Aberration, Almanac, Frame};
use frames::BodyFrame;
use glam::{DMat3, DVec3};
use hifitime::Epoch;
use pck::RotationModel;
use std::path::{Path, PathBuf};
use text_kernel::TextKernel;

/// NAIF id of the Sun.
const SUN: i32 = 10;

/// Kernel kinds slim reads, by file extension.
const SUPPORTED: &str = "SPK (.bsp), binary PCK (.bpc), text PCK (.tpc), frame kernels (.tf) and \
                         leapseconds (.tls)";

/// The loaded kernels.
pub struct Kernels {
    almanac: Almanac,
    text: TextKernel,
    files: Vec<PathBuf>,
}

impl Kernels {
    /// Loads `paths` in order. Nothing is ever downloaded.
    pub fn load(paths: &[PathBuf]) -> Result<Kernels> {
        let mut kernels = Kernels {
            almanac: Almanac::default(),
            text: TextKernel::default(),
            files: Vec::new(),
        };
        for path in paths {
            kernels.load_one(path)?;
        }
        Ok(kernels)
    }

    fn load_one(&mut self, path: &Path) -> Result<()> {
        let ext = crate::lowercase_extension(path);
        match ext.as_str() {
            "bsp" | "bpc" => {
                let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
                check_daf(path, &bytes, &ext)?;
                let bytes = daf::to_little_endian(path, &bytes)?;
                let almanac = std::mem::take(&mut self.almanac);
                self.almanac = almanac
                    .load_from_bytes(bytes.as_slice().into())
                    .map_err(|e| {
                        // anise's message may quote the file's bytes: escaped, shortened.
                        let e = crate::error::printable(&e.to_string(), 400);
                        Error::file(path, format!("not a readable {}: {e}", kind_name(&ext)))
                    })?;
            }
            "tpc" | "tf" | "tls" => {
                let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
                let text = String::from_utf8_lossy(crate::without_bom(&bytes));
                self.text.parse_into(path, &text)?;
                pck::check_phase_degrees(&self.text, path)?;
            }
            other => {
                let kind = match other {
                    "bc" => "a CK (pointing) kernel",
                    "bds" => "a DSK (shape) kernel",
                    "ti" => "an IK (instrument) kernel",
                    "tsc" => "an SCLK (clock) kernel",
                    "tm" => "a meta-kernel: list its kernels in the scene instead",
                    _ => "not a kernel kind slim knows",
                };
                return Err(Error::file(path, format!("{kind}; slim reads {SUPPORTED}")));
            }
        }
        self.files.push(path.to_path_buf());
        Ok(())
    }

    /// The loaded files, in load order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// The loaded binary kernels (SPK, binary PCK), for evaluating frames.
    pub fn almanac(&self) -> &Almanac {
        &self.almanac
    }

    /// The IAU rotation model of body `id` from the loaded text PCKs.
    pub fn rotation_model(&self, id: i32) -> Option<RotationModel> {
        RotationModel::from_kernel(&self.text, id)
    }

    /// Radii of body `id` from the loaded text PCKs, km.
    pub fn radii_km(&self, id: i32) -> Option<DVec3> {
        pck::radii_km(&self.text, id)
    }

    /// Bodies with a rotation model in the loaded text PCKs.
    pub fn bodies_with_rotation(&self) -> Vec<i32> {
        let mut ids: Vec<i32> = self
            .text
            .names()
            .filter_map(|n| n.strip_prefix("BODY")?.strip_suffix("_PM")?.parse().ok())
            .collect();
        ids.sort_unstable();
        ids
    }

    /// Bodies the loaded SPKs provide, with their covered windows.
    pub fn ephemeris_coverage(&self) -> Vec<(i32, Epoch, Epoch)> {
        let mut cover: Vec<(i32, Epoch, Epoch)> = self
            .almanac
            .spk_domains()
            .map(|d| d.into_iter().map(|(id, (a, b))| (id, a, b)).collect())
            .unwrap_or_default();
        cover.sort_by_key(|c| c.0);
        cover
    }

    /// Vector from `observer` to `target` (km, J2000) at `epoch`, with aberration
    /// correction `ab`; the error is anise's message.
    pub fn vector_km(
        &self,
        target: i32,
        observer: i32,
        epoch: Epoch,
        ab: Option<Aberration>,
    ) -> std::result::Result<DVec3, String> {
        let target_frame = if target == SUN {
            SUN_J2000
        } else {
            Frame::from_ephem_j2000(target)
        };
        self.almanac
            .translate(target_frame, Frame::from_ephem_j2000(observer), epoch, ab)
            .map(|s| DVec3::new(s.radius_km.x, s.radius_km.y, s.radius_km.z))
            .map_err(|e| e.to_string())
    }
}

fn kind_name(ext: &str) -> &'static str {
    if ext == "bsp" {
        "SPK"
    } else {
        "binary PCK"
    }
}

/// A DAF file starts with "DAF/SPK", "DAF/PCK" or the legacy "NAIF/DAF".
fn check_daf(path: &Path, bytes: &[u8], ext: &str) -> Result<()> {
    let id = bytes
        .get(..8)
        .map(String::from_utf8_lossy)
        .unwrap_or_default();
    if ["DAF/SPK", "DAF/PCK", "NAIF/DAF"]
        .iter()
        .any(|p| id.starts_with(p))
    {
        Ok(())
    } else {
        Err(Error::file(
            path,
            format!(
                "not a {} file (it does not start with a DAF identification word)",
                kind_name(ext)
            ),
        ))
    }
}

/// One body of a SPICE scene.
#[derive(Debug, Clone)]
pub struct SpiceBody {
    /// Name used in outputs and errors.
    pub name: String,
    /// NAIF id.
    pub naif_id: i32,
    /// The body-fixed frame.
    pub frame: BodyFrame,
    /// Sidereal rotation period from the body's IAU model, if it has one, s.
    pub rotation_period_s: Option<f64>,
}

impl SpiceBody {
    /// The body `naif_id` in its IAU frame (rotation model from the loaded text PCKs), or
    /// an error that lists the bodies the kernels do provide.
    pub fn new(kernels: &Kernels, name: &str, naif_id: i32) -> Result<SpiceBody> {
        let model = kernels
            .rotation_model(naif_id)
            .ok_or_else(|| Error::Spice {
                body: name.to_string(),
                naif_id,
                frame: iau_frame_name(naif_id),
                epoch: "(any)".into(),
                msg: format!(
                "no rotation model (BODY{naif_id}_POLE_RA/_POLE_DEC/_PM) in the loaded text PCKs; \
                 they define: {}",
                list_ids(&kernels.bodies_with_rotation())
            ),
            })?;
        Ok(SpiceBody {
            name: name.to_string(),
            naif_id,
            rotation_period_s: model.rotation_period_s(),
            frame: BodyFrame::iau(iau_frame_name(naif_id), model),
        })
    }

    /// The body `naif_id` in the frame named `frame` (an `IAU_...` frame, or one defined by
    /// the loaded frame kernels, e.g. `MOON_ME`).
    pub fn with_frame(
        kernels: &Kernels,
        name: &str,
        naif_id: i32,
        frame: &str,
    ) -> Result<SpiceBody> {
        let resolved = BodyFrame::resolve(&kernels.text, frame, naif_id, |id| {
            kernels.rotation_model(id)
        })
        .map_err(|msg| Error::Spice {
            body: name.to_string(),
            naif_id,
            frame: frame.to_string(),
            epoch: "(any)".into(),
            msg,
        })?;
        Ok(SpiceBody {
            name: name.to_string(),
            naif_id,
            rotation_period_s: kernels
                .rotation_model(naif_id)
                .and_then(|m| m.rotation_period_s()),
            frame: resolved,
        })
    }
}

/// The name of body `naif_id`'s IAU frame in messages.
fn iau_frame_name(naif_id: i32) -> String {
    format!("IAU body-fixed frame of NAIF {naif_id}")
}

fn list_ids(ids: &[i32]) -> String {
    if ids.is_empty() {
        "nothing".into()
    } else {
        ids.iter()
            .map(i32::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// A body of a SPICE scene: placed by the kernels, or synthetically relative to the first.
#[derive(Debug, Clone)]
pub enum SpiceMember {
    Kernel(Box<SpiceBody>),
    Synthetic {
        name: String,
        motion: SyntheticMotion,
    },
}

impl From<SpiceBody> for SpiceMember {
    fn from(body: SpiceBody) -> SpiceMember {
        SpiceMember::Kernel(Box::new(body))
    }
}

/// The SPICE-driven ephemeris.
pub struct SpiceEphemeris {
    kernels: Kernels,
    /// The first body: the kernels must cover it; the scene frame is centred on it.
    primary: SpiceBody,
    /// All bodies in scene order, the first included.
    members: Vec<SpiceMember>,
    epochs: Vec<Epoch>,
    step_s: f64,
    aberration: Option<Aberration>,
    solar_constant_w_m2: f64,
}

/// Parses an aberration flag: NONE, LT, LT+S, CN or CN+S.
pub fn parse_aberration(flag: &str) -> Option<Option<Aberration>> {
    matches!(flag, "NONE" | "LT" | "LT+S" | "CN" | "CN+S")
        .then(|| Aberration::new(flag).ok())
        .flatten()
}

impl SpiceEphemeris {
    /// An ephemeris of `members` over `epochs` (each standing for `step_s` seconds). The
    /// first member must be placed by the kernels: synthetic ones are placed relative to it.
    pub fn new(
        kernels: Kernels,
        members: Vec<SpiceMember>,
        epochs: Vec<Epoch>,
        step_s: f64,
        aberration: Option<Aberration>,
        solar_constant_w_m2: f64,
    ) -> Result<SpiceEphemeris> {
        let primary = match members.first() {
            Some(SpiceMember::Kernel(body)) => body.as_ref().clone(),
            _ => {
                return Err(Error::Usage(
                    "the first body of a SPICE scene must have a naif_id the kernels cover; \
                     synthetic bodies are placed relative to it"
                        .into(),
                ))
            }
        };
        Ok(SpiceEphemeris {
            kernels,
            primary,
            members,
            epochs,
            step_s,
            aberration,
            solar_constant_w_m2,
        })
    }

    fn error(&self, body: &SpiceBody, epoch: Epoch, what: &str, cause: String) -> Error {
        let coverage = self.kernels.ephemeris_coverage();
        let window = |id: i32| {
            coverage
                .iter()
                .find(|c| c.0 == id)
                .map(|c| format!("{} .. {}", c.1, c.2))
        };
        let covered = match (window(body.naif_id), window(SUN)) {
            (Some(b), Some(s)) => format!(
                "the loaded SPKs cover NAIF {} over {b} and the Sun over {s}",
                body.naif_id
            ),
            (None, _) => format!(
                "no loaded SPK has NAIF {}; they provide: {}",
                body.naif_id,
                list_ids(&coverage.iter().map(|c| c.0).collect::<Vec<_>>())
            ),
            (Some(b), None) => format!(
                "the loaded SPKs cover NAIF {} over {b} but not the Sun",
                body.naif_id
            ),
        };
        Error::Spice {
            body: body.name.clone(),
            naif_id: body.naif_id,
            frame: body.frame.name.clone(),
            epoch: format!("{epoch} ({} TDB s)", epoch.to_tdb_seconds()),
            msg: format!("{what}: {cause}; {covered}"),
        }
    }
}

impl SpiceEphemeris {
    /// The Sun seen from `body` (km, J2000, with the scene's aberration correction).
    fn sun_km(&self, body: &SpiceBody, epoch: Epoch) -> Result<DVec3> {
        self.kernels
            .vector_km(SUN, body.naif_id, epoch, self.aberration)
            .map_err(|e| self.error(body, epoch, "Sun position", e))
    }

    /// For a kernel-placed body: the Sun (km, J2000), its offset from the first body (km,
    /// J2000, geometric) and the J2000 → body-fixed rotation.
    fn kernel_geometry(&self, body: &SpiceBody, epoch: Epoch) -> Result<(DVec3, DVec3, DMat3)> {
        let sun_km = self.sun_km(body, epoch)?;
        let offset_km = if body.naif_id == self.primary.naif_id {
            DVec3::ZERO
        } else {
            self.kernels
                .vector_km(body.naif_id, self.primary.naif_id, epoch, None)
                .map_err(|e| self.error(body, epoch, "position relative to the first body", e))?
        };
        let to_body = body
            .frame
            .j2000_to_frame(self.kernels.almanac(), epoch)
            .map_err(|e| self.error(body, epoch, "body-fixed orientation", e))?;
        Ok((sun_km, offset_km, to_body))
    }
}

impl Ephemeris for SpiceEphemeris {
    fn steps(&self) -> usize {
        self.epochs.len()
    }

    fn duration_s(&self) -> f64 {
        self.step_s * self.epochs.len() as f64
    }

    fn kernels(&self) -> Option<&Kernels> {
        Some(&self.kernels)
    }

    fn state(&self, step: usize) -> Result<EpochState> {
        let epoch = self.epochs[step];
        let primary_sun_km = self.sun_km(&self.primary, epoch)?;
        let bodies = self
            .members
            .iter()
            .map(|member| {
                let (sun_km, offset_km, to_body) = match member {
                    SpiceMember::Kernel(body) => self.kernel_geometry(body, epoch)?,
                    SpiceMember::Synthetic { motion, .. } => {
                        let t_s = (epoch - self.epochs[0]).to_seconds();
                        let (offset_km, body_to_j2000) = motion.pose_at(t_s);
                        (
                            primary_sun_km - offset_km,
                            offset_km,
                            body_to_j2000.transpose(),
                        )
                    }
                };
                let distance_m = sun_km.length() * 1000.0;
                Ok(BodyState {
                    sun_dir: (to_body * sun_km).normalize(),
                    sun_distance_m: distance_m,
                    flux_w_m2: flux_at(self.solar_constant_w_m2, distance_m),
                    pose: Pose {
                        body_to_scene: to_body.transpose(),
                        position_m: offset_km * 1000.0,
                    },
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(EpochState {
            step,
            epoch,
            bodies,
        })
    }
}
