//! World: every body of a scene in its own body-fixed frame, and the poses that place the
//! bodies relative to each other.
//!
//! In: meshes in metres (body-fixed, relative to each body's centre). Out: [`World`], the
//! bodies with their facet-id offsets, and [`Pose`] transforms between body frames. Keeping
//! each body in its own frame is what keeps a 1 m facet 20,000 km from the scene origin as
//! exact as one at the origin: only differences of body positions are ever formed.

use crate::mesh::Mesh;
use glam::{DMat3, DVec3};

/// Where a body is at one epoch: its rotation and the position of its centre, both
/// relative to the scene frame (an inertial frame; for SPICE scenes, J2000).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation taking body-fixed vectors to the scene frame.
    pub body_to_scene: DMat3,
    /// Body centre in the scene frame, metres.
    pub position_m: DVec3,
}

impl Pose {
    /// A body at the scene origin with axes aligned to the scene frame.
    pub const IDENTITY: Pose = Pose {
        body_to_scene: DMat3::IDENTITY,
        position_m: DVec3::ZERO,
    };

    /// The transform taking points in this body's frame to points in `other`'s frame.
    pub fn relative_to(&self, other: &Pose) -> FrameTransform {
        let scene_to_other = other.body_to_scene.transpose();
        FrameTransform {
            rotation: scene_to_other * self.body_to_scene,
            // Difference of positions first: both may be huge, their difference is not.
            offset_m: scene_to_other * (self.position_m - other.position_m),
        }
    }
}

/// A rigid transform between two body frames: `x_to = rotation · x_from + offset_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTransform {
    pub rotation: DMat3,
    pub offset_m: DVec3,
}

impl FrameTransform {
    /// Maps a point (metres).
    pub fn point(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.offset_m
    }

    /// Maps a direction.
    pub fn vector(&self, v: DVec3) -> DVec3 {
        self.rotation * v
    }
}

/// One body: a named mesh in its own frame.
#[derive(Debug, Clone)]
pub struct Body {
    /// Name used in outputs (unique within a scene).
    pub name: String,
    /// The mesh in metres, body-fixed frame.
    pub mesh: Mesh,
    /// True when the mesh was found to be a closed convex surface (no self-shadowing).
    pub convex: bool,
    /// Radius of a sphere about the body origin that contains every vertex, metres.
    pub bounding_radius_m: f64,
    /// Whether its facets' statistics are written (false: it only casts shadows and
    /// scatters light).
    pub outputs: bool,
    /// The mesh followed by terrain around it that only casts shadows (so facet ids of
    /// the mesh are the same in both); `None`: the mesh alone casts.
    pub casters: Option<Mesh>,
    /// True for terrain: a patch of a larger surface (`MeshReport::is_patch`: a boundary
    /// whose openings are a sizeable share of its area, not a body's seams or small
    /// holes), or a mesh with surroundings. Its horizons are far and low all around, which makes its horizon
    /// map dearer to build (`horizon::shadows`). Set from the mesh inspection when a
    /// scene is prepared; a body made with [`Body::new`] counts as closed until told.
    pub open: bool,
    /// For a generated ellipsoid, its semi-axes along the frame's x, y, z (metres): a disk
    /// Sun behind it is hidden in closed form ([`crate::horizon::eclipse`]), not by rays
    /// through the mesh.
    pub ellipsoid_radii_m: Option<DVec3>,
}

impl Body {
    /// A body from a mesh; `convex` comes from the mesh inspection.
    pub fn new(name: impl Into<String>, mesh: Mesh, convex: bool) -> Body {
        let bounding_radius_m = mesh
            .triangles
            .iter()
            .flatten()
            .map(|&v| mesh.vertices[v as usize].length())
            .fold(0.0, f64::max);
        Body {
            name: name.into(),
            mesh,
            convex,
            bounding_radius_m,
            outputs: true,
            open: false,
            ellipsoid_radii_m: None,
            casters: None,
        }
    }

    /// Adds terrain around the mesh that hides the Sun from its facets but receives
    /// nothing; the body then counts as able to shadow itself.
    pub fn with_surroundings(mut self, surroundings: &Mesh) -> Body {
        let casters = self.mesh.joined(surroundings);
        let reach = casters
            .vertices
            .iter()
            .map(|v| v.length())
            .fold(0.0, f64::max);
        self.bounding_radius_m = self.bounding_radius_m.max(reach);
        self.convex = false;
        self.open = true;
        self.casters = Some(casters);
        self
    }

    /// Everything of the body that casts shadows: the mesh, with its surroundings.
    pub fn shadow_mesh(&self) -> &Mesh {
        self.casters.as_ref().unwrap_or(&self.mesh)
    }

    /// Marks the body as the generated ellipsoid of semi-axes `radii_m` (metres) its mesh
    /// approximates; the bounding sphere then holds the ellipsoid, not only the mesh.
    pub fn with_ellipsoid(mut self, radii_m: DVec3) -> Body {
        self.bounding_radius_m = self.bounding_radius_m.max(radii_m.max_element());
        self.ellipsoid_radii_m = Some(radii_m);
        self
    }
}

/// All bodies of a scene. Global facet id = `offsets[body] + local id`.
#[derive(Debug, Clone, Default)]
pub struct World {
    pub bodies: Vec<Body>,
}

impl World {
    /// Total number of facets over all bodies.
    pub fn facet_count(&self) -> usize {
        self.bodies.iter().map(|b| b.mesh.len()).sum()
    }

    /// The global facet ids of the bodies that get outputs, body by body.
    pub fn output_ranges(&self) -> Vec<std::ops::Range<usize>> {
        self.bodies
            .iter()
            .zip(self.offsets())
            .filter(|(b, _)| b.outputs)
            .map(|(b, offset)| offset..offset + b.mesh.len())
            .collect()
    }

    /// Facets of the bodies that get outputs.
    pub fn output_facet_count(&self) -> usize {
        self.output_ranges().iter().map(|r| r.len()).sum()
    }

    /// Each body's first index among the facets that get outputs (the order of the run's
    /// statistics and output tables; a body without outputs gets the next body's).
    pub fn output_offsets(&self) -> Vec<usize> {
        self.running_sum(|b| if b.outputs { b.mesh.len() } else { 0 })
    }

    /// First global facet id of each body.
    pub fn offsets(&self) -> Vec<usize> {
        self.running_sum(|b| b.mesh.len())
    }

    /// Per body, the sum of `count` over the bodies before it.
    fn running_sum(&self, count: impl Fn(&Body) -> usize) -> Vec<usize> {
        let mut acc = 0;
        self.bodies
            .iter()
            .map(|b| {
                let o = acc;
                acc += count(b);
                o
            })
            .collect()
    }
}
