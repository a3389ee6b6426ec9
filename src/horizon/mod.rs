//! Horizon: what each facet can see of the sky above its plane, computed once per mesh.
//!
//! In: a body's mesh (metres, body frame) and its BVH. Out, per facet:
//! - [`bound::HorizonBound`]: the sine of the highest elevation of anything else, which
//!   spares the exact tracers every ray toward a Sun above it;
//! - [`map::HorizonMap`]: the horizon as a function of azimuth (an exact upper bound and
//!   the horizon at the centre of each wedge), kept on disk by [`cache`] and used by the
//!   step loop instead of rays when it pays;
//!   [`sky`] holds the step loop's side of it: where the Sun stands in a facet's sky
//!   and what the map says there;
//! - [`disk::SolarDisk`]: the share of a limb-darkened solar disk above a horizon;
//! - [`band::SunBand`]: the directions a run's Sun takes, to which a map may be limited.
//!
//! `geometry` holds the elevation bounds of boxes and triangles they are built from;
//! `outline` a triangle's highest point per azimuth, from which a map's cells are filled.

pub mod band;
pub mod bound;
pub mod cache;
pub mod disk;
pub mod eclipse;
mod geometry;
pub mod map;
mod outline;
pub mod shadows;
pub mod sky;

pub use geometry::tangent_frame;
pub use shadows::{HorizonMode, ShadowMethod, Shadows, SunShape};
