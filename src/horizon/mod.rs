//! Horizon: what each facet can see of the sky above its plane, computed once per mesh.
//!
//! In: a body's mesh (metres, body frame) and its BVH. Out, per facet:
//! - [`bound::HorizonBound`]: the sine of the highest elevation of anything else, which
//!   spares the exact tracers every ray toward a Sun above it;
//! - [`map::HorizonMap`]: the horizon as a function of azimuth (an exact upper bound and
//!   the horizon at the centre of each wedge), kept on disk by [`cache`] and used by the
//!   step loop instead of rays when it pays;
//! - [`disk::SolarDisk`]: the share of a limb-darkened solar disk above a horizon.
//!
//! `geometry` holds the elevation bounds of boxes and triangles they are built from.

pub mod bound;
pub mod cache;
pub mod disk;
pub mod eclipse;
mod geometry;
pub mod map;
pub mod shadows;

pub use shadows::{HorizonMode, ShadowMethod, Shadows, SunShape};

/// A floor (two triangles at z = 0 around the origin, facing +z) and a vertical wall of
/// height `h` along x = `wall_x`, from y = −`half` to `half` (metres): the closed-form
/// horizon the bound's and the maps' tests check.
#[cfg(test)]
fn floor_and_wall(h: f64, wall_x: f64, half: f64) -> crate::mesh::Mesh {
    use glam::DVec3;
    let raw = crate::mesh::RawMesh {
        vertices: vec![
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(-1.0, 1.0, 0.0),
            DVec3::new(wall_x, -half, 0.0),
            DVec3::new(wall_x, half, 0.0),
            DVec3::new(wall_x, half, h),
            DVec3::new(wall_x, -half, h),
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]],
    };
    crate::mesh::Mesh::from_raw(raw, crate::mesh::LengthUnit::M)
}
