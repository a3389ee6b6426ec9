//! Body-fixed frames by name: IAU frames from text PCKs, binary-PCK frames, and text-kernel
//! (TK) frames defined relative to either — e.g. the Moon's `MOON_ME`, which the lunar
//! frame kernel defines as a fixed rotation of `MOON_ME_DE421`, itself a fixed rotation of
//! the binary-PCK frame `MOON_PA_DE421`.
//!
//! In: a frame name and the loaded text kernels (`FRAME_<name>`, `FRAME_<id>_CLASS`,
//! `FRAME_<id>_CLASS_ID`, `TKFRAME_<id>_RELATIVE`, `_SPEC` = `MATRIX` or `ANGLES`,
//! `_MATRIX`, `_ANGLES`, `_AXES`, `_UNITS`). Out: a [`BodyFrame`], a chain resolved once
//! into a time-varying base rotation (J2000, an IAU model, or a binary-PCK frame that anise
//! evaluates) followed by one constant matrix, so evaluating it per epoch costs one base
//! rotation and one matrix product. Rotations map J2000 vectors to the frame
//! (`v_frame = M · v_J2000`, CSPICE's `pxform("J2000", frame, et)`).

use super::pck::RotationModel;
use super::text_kernel::TextKernel;
use anise::prelude::{Almanac, Frame};
use glam::{DMat3, DVec3};
use hifitime::Epoch;

/// SPICE frame classes (frames.req).
const CLASS_INERTIAL: i64 = 1;
const CLASS_PCK: i64 = 2;
const CLASS_CK: i64 = 3;
const CLASS_TK: i64 = 4;
const CLASS_DYNAMIC: i64 = 5;

/// NAIF id of J2000 in anise's orientation ids.
const J2000_ORIENTATION: i32 = 1;

/// A TK chain longer than this is taken to be circular.
const MAX_CHAIN: usize = 16;

/// A named frame, resolved into a base rotation and a constant matrix.
#[derive(Debug, Clone)]
pub struct BodyFrame {
    /// The name as the scene gave it (upper case).
    pub name: String,
    base: Base,
    /// Base frame → this frame.
    fixed: DMat3,
}

/// The time-varying start of a frame chain.
#[derive(Debug, Clone)]
enum Base {
    J2000,
    /// An IAU rotation model from a text PCK.
    Iau(RotationModel),
    /// A binary-PCK frame: its class id and the body it is centred on.
    BinaryPck {
        class_id: i32,
        center: i32,
    },
}

impl BodyFrame {
    /// The IAU frame of body `naif_id` (`IAU_<BODY>`), from its text-PCK model.
    pub fn iau(name: String, model: RotationModel) -> BodyFrame {
        BodyFrame {
            name,
            base: Base::Iau(model),
            fixed: DMat3::IDENTITY,
        }
    }

    /// Resolves frame `name` through the text kernels. `iau_model` supplies the IAU model
    /// when the chain ends in `IAU_<...>` of the body with id `naif_id`. The error quotes
    /// names from the kernels (a parent frame, the frames they define): escaped and
    /// shortened, as a damaged kernel's names may hold control characters or be many.
    pub fn resolve(
        kernel: &TextKernel,
        name: &str,
        naif_id: i32,
        iau_model: impl Fn(i32) -> Option<RotationModel>,
    ) -> Result<BodyFrame, String> {
        Self::follow_chain(kernel, name, naif_id, iau_model)
            .map_err(|e| crate::error::printable(&e, 500))
    }

    fn follow_chain(
        kernel: &TextKernel,
        name: &str,
        naif_id: i32,
        iau_model: impl Fn(i32) -> Option<RotationModel>,
    ) -> Result<BodyFrame, String> {
        let name = name.trim().to_ascii_uppercase();
        let mut fixed = DMat3::IDENTITY;
        let mut current = name.clone();
        for _ in 0..MAX_CHAIN {
            let base = match step(kernel, &current, naif_id, &iau_model)? {
                Step::Base(base) => base,
                Step::Relative { parent, to_child } => {
                    fixed *= to_child;
                    current = parent;
                    continue;
                }
            };
            return Ok(BodyFrame { name, base, fixed });
        }
        Err(format!(
            "frame {name}: its TK chain is longer than {MAX_CHAIN} links (circular?)"
        ))
    }

    /// J2000 → this frame at `epoch`.
    pub fn j2000_to_frame(&self, almanac: &Almanac, epoch: Epoch) -> Result<DMat3, String> {
        let base = match &self.base {
            Base::J2000 => DMat3::IDENTITY,
            Base::Iau(model) => model.j2000_to_body(epoch.to_tdb_seconds()),
            Base::BinaryPck { class_id, center } => {
                let from = Frame::new(*center, J2000_ORIENTATION);
                let to = Frame::new(*center, *class_id);
                let dcm = almanac
                    .rotate(from, to, epoch)
                    .map_err(|e| format!("binary PCK frame {class_id}: {e}"))?;
                let m = dcm.rot_mat;
                DMat3::from_cols_array(&[
                    m[(0, 0)],
                    m[(1, 0)],
                    m[(2, 0)],
                    m[(0, 1)],
                    m[(1, 1)],
                    m[(2, 1)],
                    m[(0, 2)],
                    m[(1, 2)],
                    m[(2, 2)],
                ])
            }
        };
        Ok(self.fixed * base)
    }

    /// The binary-PCK frame the chain rests on, if any (for coverage messages).
    pub fn binary_pck_class(&self) -> Option<i32> {
        match self.base {
            Base::BinaryPck { class_id, .. } => Some(class_id),
            _ => None,
        }
    }
}

/// One link of a frame chain.
enum Step {
    Base(Base),
    /// `to_child` maps the parent frame to the current one.
    Relative {
        parent: String,
        to_child: DMat3,
    },
}

fn step(
    kernel: &TextKernel,
    name: &str,
    naif_id: i32,
    iau_model: &impl Fn(i32) -> Option<RotationModel>,
) -> Result<Step, String> {
    if matches!(name, "J2000" | "EME2000") {
        return Ok(Step::Base(Base::J2000));
    }
    let Some(id) = number(kernel, &format!("FRAME_{name}")) else {
        return match name.strip_prefix("IAU_") {
            Some(body) => {
                let id = body_id(kernel, body).ok_or_else(|| {
                    format!(
                        "frame {name}: slim knows no NAIF id for body {body} (the body of \
                         NAIF {naif_id} is named by its id; name others with \
                         NAIF_BODY_NAME/NAIF_BODY_CODE in a frame kernel)"
                    )
                })?;
                iau_model(id)
                    .map(|m| Step::Base(Base::Iau(m)))
                    .ok_or_else(|| {
                        format!(
                            "frame {name}: no rotation model for NAIF {id} in the loaded text PCKs"
                        )
                    })
            }
            None => Err(format!(
                "frame {name} is not defined by the loaded frame kernels (no FRAME_{name}); \
                 they define: {}",
                defined_frames(kernel)
            )),
        };
    };
    let id = id as i64;
    let class = number(kernel, &format!("FRAME_{id}_CLASS"))
        .ok_or_else(|| format!("frame {name}: FRAME_{id}_CLASS is missing"))?
        as i64;
    let class_id = number(kernel, &format!("FRAME_{id}_CLASS_ID")).unwrap_or(id as f64) as i32;
    let center = number(kernel, &format!("FRAME_{id}_CENTER")).unwrap_or(naif_id as f64) as i32;
    match class {
        CLASS_INERTIAL if class_id == J2000_ORIENTATION => Ok(Step::Base(Base::J2000)),
        CLASS_PCK => Ok(Step::Base(Base::BinaryPck { class_id, center })),
        CLASS_TK => tk_step(kernel, name, id),
        CLASS_CK => Err(format!(
            "frame {name} is a CK frame; slim reads no CK kernels"
        )),
        CLASS_DYNAMIC => Err(format!(
            "frame {name} is a dynamic frame, which slim does not support"
        )),
        other => Err(format!("frame {name}: class {other} is not supported")),
    }
}

/// A TK frame: its parent and the constant parent → frame rotation.
fn tk_step(kernel: &TextKernel, name: &str, id: i64) -> Result<Step, String> {
    // TK keywords may be keyed by id or by name (frames.req).
    let key = |what: &str| {
        let by_id = format!("TKFRAME_{id}_{what}");
        if kernel.names().any(|n| n == by_id) {
            by_id
        } else {
            format!("TKFRAME_{name}_{what}")
        }
    };
    let parent = kernel
        .text(&key("RELATIVE"))
        .ok_or_else(|| format!("frame {name}: {} is missing", key("RELATIVE")))?
        .to_ascii_uppercase();
    let spec = kernel.text(&key("SPEC")).unwrap_or("").to_ascii_uppercase();
    let frame_to_parent = match spec.as_str() {
        "MATRIX" => matrix(kernel, &key("MATRIX"), name)?,
        "ANGLES" => angles(kernel, &key, name)?,
        other => {
            return Err(format!(
                "frame {name}: TK specification {other:?} is not supported (MATRIX or ANGLES)"
            ))
        }
    };
    Ok(Step::Relative {
        parent,
        to_child: frame_to_parent.transpose(),
    })
}

/// `TKFRAME_<id>_MATRIX`: nine numbers, row by row, mapping frame vectors to the parent.
fn matrix(kernel: &TextKernel, key: &str, name: &str) -> Result<DMat3, String> {
    let m = kernel
        .numbers(key)
        .filter(|m| m.len() == 9)
        .ok_or_else(|| format!("frame {name}: {key} must hold 9 numbers"))?;
    Ok(DMat3::from_cols_array(&[
        m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8],
    ]))
}

/// `TKFRAME_<id>_ANGLES/_AXES/_UNITS`: the frame → parent matrix is
/// `[angle1]_axis1 [angle2]_axis2 [angle3]_axis3` in SPICE's frame-rotation convention.
fn angles(kernel: &TextKernel, key: &impl Fn(&str) -> String, name: &str) -> Result<DMat3, String> {
    let values = kernel
        .numbers(&key("ANGLES"))
        .filter(|a| a.len() == 3)
        .ok_or_else(|| format!("frame {name}: {} must hold 3 angles", key("ANGLES")))?;
    let axes = kernel
        .numbers(&key("AXES"))
        .filter(|a| a.len() == 3 && a.iter().all(|&x| matches!(x as i64, 1..=3)))
        .ok_or_else(|| format!("frame {name}: {} must hold 3 axes (1, 2 or 3)", key("AXES")))?;
    let units = kernel
        .text(&key("UNITS"))
        .unwrap_or("")
        .to_ascii_uppercase();
    let to_rad = match units.as_str() {
        "RADIANS" => 1.0,
        "DEGREES" => 1f64.to_radians(),
        "ARCMINUTES" => 1f64.to_radians() / 60.0,
        "ARCSECONDS" => 1f64.to_radians() / 3600.0,
        "HOURANGLE" => 15f64.to_radians(),
        "MINUTEANGLE" => 15f64.to_radians() / 60.0,
        "SECONDANGLE" => 15f64.to_radians() / 3600.0,
        other => {
            return Err(format!(
                "frame {name}: {} {other:?} is not a SPICE angle unit",
                key("UNITS")
            ))
        }
    };
    Ok((0..3).fold(DMat3::IDENTITY, |m, k| {
        m * frame_rotation(values[k] * to_rad, axes[k] as usize)
    }))
}

/// SPICE's `rotate(angle, axis)`: the matrix that maps vectors into a frame rotated by
/// `angle` about `axis` (1 = x, 2 = y, 3 = z).
fn frame_rotation(angle: f64, axis: usize) -> DMat3 {
    let (s, c) = angle.sin_cos();
    let (i, j) = match axis {
        1 => (1, 2),
        2 => (2, 0),
        _ => (0, 1),
    };
    let mut cols = [DVec3::ZERO; 3];
    let k = 3 - i - j;
    cols[k][k] = 1.0;
    cols[i][i] = c;
    cols[j][j] = c;
    // Row i gets +sin in column j, row j gets −sin in column i.
    cols[j][i] = s;
    cols[i][j] = -s;
    DMat3::from_cols(cols[0], cols[1], cols[2])
}

/// NAIF ids of bodies whose IAU frames scenes name most (SPICE's built-in names).
const BODY_IDS: &[(&str, i32)] = &[
    ("SUN", 10),
    ("MERCURY", 199),
    ("VENUS", 299),
    ("EARTH", 399),
    ("MOON", 301),
    ("MARS", 499),
    ("PHOBOS", 401),
    ("DEIMOS", 402),
    ("JUPITER", 599),
    ("IO", 501),
    ("EUROPA", 502),
    ("GANYMEDE", 503),
    ("CALLISTO", 504),
    ("SATURN", 699),
    ("ENCELADUS", 602),
    ("TITAN", 606),
    ("URANUS", 799),
    ("NEPTUNE", 899),
    ("PLUTO", 999),
    ("CHARON", 901),
    ("CERES", 2000001),
    ("PALLAS", 2000002),
    ("VESTA", 2000004),
    ("LUTETIA", 2000021),
    ("IDA", 2243),
    ("EROS", 2000433),
    ("ITOKAWA", 2025143),
    ("BENNU", 2101955),
    ("RYUGU", 2162173),
];

/// The NAIF id of body `name`: from the kernels' NAIF_BODY_NAME/NAIF_BODY_CODE, SPICE's
/// built-in names above, or a number.
fn body_id(kernel: &TextKernel, name: &str) -> Option<i32> {
    let from_kernels = kernel.texts("NAIF_BODY_NAME").and_then(|names| {
        let codes = kernel.numbers("NAIF_BODY_CODE")?;
        let k = names.iter().position(|n| n.eq_ignore_ascii_case(name))?;
        codes.get(k).map(|c| *c as i32)
    });
    from_kernels
        .or_else(|| BODY_IDS.iter().find(|(n, _)| *n == name).map(|(_, id)| *id))
        .or_else(|| name.parse().ok())
}

fn number(kernel: &TextKernel, key: &str) -> Option<f64> {
    kernel.numbers(key)?.first().copied()
}

fn defined_frames(kernel: &TextKernel) -> String {
    let mut names: Vec<&str> = kernel
        .names()
        .filter_map(|n| n.strip_prefix("FRAME_"))
        .filter(|n| !n.starts_with(|c: char| c.is_ascii_digit() || c == '-'))
        .collect();
    names.sort_unstable();
    if names.is_empty() {
        "none (load a frame kernel, .tf)".into()
    } else {
        names.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_rotations_follow_the_spice_convention() {
        // rotate(90°, 3) maps x to −y... in SPICE: [[c, s, 0], [−s, c, 0], [0, 0, 1]].
        let m = frame_rotation(std::f64::consts::FRAC_PI_2, 3);
        assert!((m * DVec3::X - DVec3::new(0.0, -1.0, 0.0)).length() < 1e-15);
        let m = frame_rotation(std::f64::consts::FRAC_PI_2, 1);
        assert!((m * DVec3::Y - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-15);
        let m = frame_rotation(std::f64::consts::FRAC_PI_2, 2);
        assert!((m * DVec3::Z - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-15);
    }
}
