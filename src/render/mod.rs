//! Render: simulated camera images of the bodies of a scene at one epoch.
//!
//! In: the [`World`], one [`EpochState`] (Sun direction and flux per body, poses), a
//! [`Camera`], and a [`Reflectance`] per body. Out: a [`GeometryImage`] — per pixel the
//! body and facet seen through the pixel centre, the incidence, emission and phase angles
//! there, and whether the point is in sunlight — and from it images of radiance
//! (W m⁻² sr⁻¹, L = J·r with J the solar flux at the body) and of I/F (π·r). Pixels that
//! see no body, or a shadowed or night-side point, are 0.
//!
//! Visibility by rasterisation: every facet is projected through the pinhole; each pixel
//! whose centre falls inside the projected triangle (the exact, watertight edge test of
//! [`crate::trace::ray::inside`], which for a pinhole is the exact ray–triangle test of
//! the pixel-centre ray) gets the depth where that ray meets the facet's plane, and the
//! nearest facet wins. Facets with a corner at or behind the camera plane are left out
//! and counted ([`GeometryImage::clipped_facets`]): the camera belongs outside the bodies.
//!
//! Shadows at the point hit, not at the facet centroid, through [`crate::illum`]'s own
//! shadow queries (own body unless it is convex, every other body whose bounding sphere
//! can reach the receiver's shadow) and its minimum blocker height against
//! self-shadowing. Flat shading:
//! the facet's normal is used over the whole facet. Only single scattering of direct
//! sunlight is rendered (no light scattered between facets).

pub mod camera;
pub mod job;

use crate::ephemeris::EpochState;
use crate::error::{Error, Result};
use crate::illum::{Direct, StepCounts, Sunlight};
use crate::image::Image;
use crate::photometry::{i_over_f, Angles, Reflectance};
use crate::trace::{self, TracerKind};
use crate::world::{FrameTransform, World};
use camera::Camera;
use glam::DVec3;
use rayon::prelude::*;

/// What one pixel sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Body index in the world.
    pub body: u32,
    /// Facet index within the body.
    pub facet: u32,
    /// Geometry at the point hit (facet normal).
    pub angles: Angles,
    /// True when the Sun is above the facet and no facet blocks it.
    pub lit: bool,
    /// Distance from the camera to the point, metres.
    pub range_m: f64,
}

/// Per-pixel geometry of one view.
#[derive(Debug, Clone)]
pub struct GeometryImage {
    pub width: usize,
    pub height: usize,
    /// Row-major, row 0 at the top; `None` where no body is seen.
    pub samples: Vec<Option<Sample>>,
    /// Solar flux at each body, W/m².
    pub flux_w_m2: Vec<f64>,
    /// Facets left out because a corner lies at or behind the camera plane.
    pub clipped_facets: usize,
}

impl GeometryImage {
    /// Bidirectional reflectance r (sr⁻¹) per pixel; 0 where nothing lit is seen.
    pub fn reflectance(&self, materials: &[&dyn Reflectance]) -> Vec<f64> {
        self.samples
            .par_iter()
            .map(|s| match s {
                Some(s) if s.lit => materials[s.body as usize].reflectance(&s.angles),
                _ => 0.0,
            })
            .collect()
    }

    /// Radiance image (W m⁻² sr⁻¹) with each body's flux scaled by `flux_scale` (the share
    /// of the solar flux in a spectral band; 1 for the whole spectrum).
    pub fn radiance(&self, materials: &[&dyn Reflectance], flux_scale: f64) -> Image {
        let r = self.reflectance(materials);
        self.image_from(&r, |s, r| r * self.flux_w_m2[s.body as usize] * flux_scale)
    }

    /// I/F image (π·r, dimensionless).
    pub fn i_over_f(&self, materials: &[&dyn Reflectance]) -> Image {
        let r = self.reflectance(materials);
        self.image_from(&r, |_, r| i_over_f(r))
    }

    fn image_from(&self, r: &[f64], value: impl Fn(&Sample, f64) -> f64 + Sync) -> Image {
        let mut image = Image::new(self.width, self.height);
        image
            .pixels
            .par_iter_mut()
            .zip(r.par_iter().zip(&self.samples))
            .for_each(|(p, (&r, s))| *p = s.as_ref().map_or(0.0, |s| value(s, r)));
        image
    }

    /// Number of pixels that see a body.
    pub fn covered(&self) -> usize {
        self.samples.iter().filter(|s| s.is_some()).count()
    }
}

/// The renderer: the direct-irradiance stage's shadow tracers, built once.
pub struct Renderer<'w> {
    world: &'w World,
    shadows: Direct<'w>,
}

/// Rows of the image handled together by one task.
const BAND_ROWS: usize = 8;

/// One body as the camera sees it.
struct BodyView {
    /// Body frame → camera frame.
    to_camera: FrameTransform,
    /// Camera centre in the body frame, metres.
    eye: DVec3,
    /// Vertices projected to image points (u, v, 0).
    image_points: Vec<DVec3>,
    /// Per facet: whether every corner is in front of the camera.
    in_front: Vec<bool>,
}

impl<'w> Renderer<'w> {
    /// Builds the shadow tracers of every body.
    pub fn new(world: &'w World, kind: TracerKind) -> Renderer<'w> {
        Renderer {
            world,
            shadows: Direct::new(world, kind),
        }
    }

    /// What every pixel of `camera` sees at `state`.
    pub fn geometry(&self, state: &EpochState, camera: &Camera) -> Result<GeometryImage> {
        let bodies = &self.world.bodies;
        if state.bodies.len() != bodies.len() {
            return Err(Error::Usage(format!(
                "the epoch state has {} bodies, the world {}",
                state.bodies.len(),
                bodies.len()
            )));
        }
        let views: Vec<BodyView> = (0..bodies.len())
            .map(|b| self.view(b, state, camera))
            .collect();
        let shadows = (0..bodies.len())
            .map(|b| self.shadows.sunlight(b, state))
            .collect::<Result<Vec<_>>>()?;
        let bands = self.bin_by_band(&views, camera);
        let mut samples = vec![None; camera.width * camera.height];
        samples
            .par_chunks_mut(BAND_ROWS * camera.width)
            .zip(bands.par_iter())
            .enumerate()
            .for_each(|(band, (out, facets))| {
                let row0 = band * BAND_ROWS;
                let hits = self.nearest_hits(&views, camera, row0, out.len(), facets);
                for (k, hit) in hits.into_iter().enumerate() {
                    out[k] = hit.map(|(b, f)| {
                        let (u, v) = (k % camera.width, row0 + k / camera.width);
                        self.sample(b, f, &views[b], &shadows[b], state, camera, u, v)
                    });
                }
            });
        Ok(GeometryImage {
            width: camera.width,
            height: camera.height,
            samples,
            flux_w_m2: state.bodies.iter().map(|s| s.flux_w_m2).collect(),
            clipped_facets: views
                .iter()
                .map(|v| v.in_front.iter().filter(|f| !**f).count())
                .sum(),
        })
    }

    /// Projects body `b` into the camera.
    fn view(&self, b: usize, state: &EpochState, camera: &Camera) -> BodyView {
        let mesh = &self.world.bodies[b].mesh;
        let to_camera = state.bodies[b].pose.relative_to(&camera.pose);
        let eye = to_camera.rotation.transpose() * -to_camera.offset_m;
        let camera_points: Vec<DVec3> = mesh
            .vertices
            .par_iter()
            .map(|&v| to_camera.point(v))
            .collect();
        let image_points = camera_points
            .par_iter()
            .map(|&p| {
                let (u, v) = camera.project(p);
                DVec3::new(u, v, 0.0)
            })
            .collect();
        let in_front = mesh
            .triangles
            .par_iter()
            .map(|t| t.iter().all(|&i| camera_points[i as usize].z > 0.0))
            .collect();
        BodyView {
            to_camera,
            eye,
            image_points,
            in_front,
        }
    }

    /// Per band of rows, the (body, facet) pairs whose projection may cover its pixels.
    fn bin_by_band(&self, views: &[BodyView], camera: &Camera) -> Vec<Vec<(u32, u32)>> {
        let n_bands = camera.height.div_ceil(BAND_ROWS);
        let mut bands = vec![Vec::new(); n_bands];
        for (b, view) in views.iter().enumerate() {
            let mesh = &self.world.bodies[b].mesh;
            let ranges: Vec<Option<(usize, usize)>> = (0..mesh.len())
                .into_par_iter()
                .map(|f| {
                    let (_, rows) = pixel_box(view, &mesh.triangles[f], f, camera)?;
                    Some((rows.0 / BAND_ROWS, rows.1 / BAND_ROWS))
                })
                .collect();
            for (f, range) in ranges.into_iter().enumerate() {
                if let Some((first, last)) = range {
                    for band in &mut bands[first..=last] {
                        band.push((b as u32, f as u32));
                    }
                }
            }
        }
        bands
    }

    /// Z-buffer of one band: per pixel the nearest (body, facet) hit by the centre ray.
    fn nearest_hits(
        &self,
        views: &[BodyView],
        camera: &Camera,
        row0: usize,
        len: usize,
        facets: &[(u32, u32)],
    ) -> Vec<Option<(usize, usize)>> {
        let width = camera.width;
        let rows_here = len / width;
        let mut depth = vec![f64::INFINITY; len];
        let mut hit = vec![None; len];
        for &(b, f) in facets {
            let (b, f) = (b as usize, f as usize);
            let view = &views[b];
            let mesh = &self.world.bodies[b].mesh;
            let tri = mesh.triangles[f];
            let Some((cols, rows)) = pixel_box(view, &tri, f, camera) else {
                continue;
            };
            let image_tri = tri.map(|i| view.image_points[i as usize]);
            // Facet plane in the camera frame: n·x = n·a.
            let n = view.to_camera.vector(mesh.normals[f]);
            let n_dot_a = n.dot(view.to_camera.point(mesh.vertices[tri[0] as usize]));
            for row in rows.0.max(row0)..=rows.1.min(row0 + rows_here - 1) {
                for col in cols.0..=cols.1 {
                    let (u, v) = (col as f64 + 0.5, row as f64 + 0.5);
                    if !trace::ray::inside(&image_tri, DVec3::new(u, v, 0.0)) {
                        continue;
                    }
                    // Depth (camera z) where the pixel-centre ray meets the facet's plane.
                    let z = n_dot_a / n.dot(camera.ray(u, v));
                    let k = (row - row0) * width + col;
                    if z > 0.0 && z < depth[k] {
                        depth[k] = z;
                        hit[k] = Some((b, f));
                    }
                }
            }
        }
        hit
    }

    /// The geometry and illumination where the centre ray of pixel (u, v) meets facet `f`.
    #[allow(clippy::too_many_arguments)]
    fn sample(
        &self,
        b: usize,
        f: usize,
        view: &BodyView,
        shadows: &Sunlight<'_>,
        state: &EpochState,
        camera: &Camera,
        col: usize,
        row: usize,
    ) -> Sample {
        let mesh = &self.world.bodies[b].mesh;
        let n = mesh.normals[f];
        let a = mesh.vertices[mesh.triangles[f][0] as usize];
        let dir = (view.to_camera.rotation.transpose()
            * camera.ray(col as f64 + 0.5, row as f64 + 0.5))
        .normalize();
        let t = n.dot(a - view.eye) / n.dot(dir);
        let mut point = view.eye + t * dir;
        // Back onto the facet's plane: the eye is far away, its rounding is not.
        point -= n * n.dot(point - a);
        let sun = state.bodies[b].sun_dir;
        let to_eye = -dir;
        let angles = Angles::from_vectors(n, sun, to_eye);
        let lit = angles.cos_i > 0.0 && {
            let t_min = self.shadows.t_min(b, f, angles.cos_i);
            !shadows.blocked(point, t_min, f, &mut StepCounts::default())
        };
        Sample {
            body: b as u32,
            facet: f as u32,
            angles,
            lit,
            range_m: t,
        }
    }
}

/// The pixel columns and rows (inclusive) whose centres may fall inside facet `f`'s
/// projection, or `None` when it covers no pixel centre or is clipped.
fn pixel_box(
    view: &BodyView,
    tri: &[u32; 3],
    f: usize,
    camera: &Camera,
) -> Option<((usize, usize), (usize, usize))> {
    if !view.in_front[f] {
        return None;
    }
    let p = tri.map(|i| view.image_points[i as usize]);
    let lo = p[0].min(p[1]).min(p[2]);
    let hi = p[0].max(p[1]).max(p[2]);
    // Pixel centres c + 0.5 with lo ≤ c + 0.5 ≤ hi.
    let first = |x: f64| (x - 0.5).ceil().max(0.0);
    let last = |x: f64, n: usize| (x - 0.5).floor().min(n as f64 - 1.0);
    let (c0, c1) = (first(lo.x), last(hi.x, camera.width));
    let (r0, r1) = (first(lo.y), last(hi.y, camera.height));
    if c0 > c1 || r0 > r1 {
        return None;
    }
    Some(((c0 as usize, c1 as usize), (r0 as usize, r1 as usize)))
}
