//! Map-projected terrain: meshes whose vertices are polar-stereographic map coordinates
//! and heights, as DEM-derived patches of the lunar poles come (e.g. LOLA products).
//!
//! In: a vertex `(x, y, h)` — stereographic easting and northing and the height above a
//! reference sphere of radius `R`, all in one length unit. Out: the body-fixed Cartesian
//! position in the same unit. The projection is the standard polar one: for the south
//! pole `x = ρ sin λ`, `y = ρ cos λ`; for the north pole `x = ρ sin λ`, `y = −ρ cos λ`; with
//! `ρ = 2R tan(c/2)`, `c` the angular distance from the pole and `λ` the east longitude.
//! The point is then `(R + h)(sin c cos λ, sin c sin λ, ±cos c)`.

use super::RawMesh;
use glam::DVec3;
use serde::Deserialize;

/// Which pole a polar-stereographic projection is centred on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Pole {
    North,
    South,
}

/// A polar-stereographic projection onto a sphere of radius `radius` (mesh units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolarStereographic {
    pub pole: Pole,
    pub radius: f64,
}

impl PolarStereographic {
    /// The body-fixed position of map point `(x, y)` at height `h` (all in mesh units).
    pub fn to_body_fixed(&self, map: DVec3) -> DVec3 {
        let rho = map.x.hypot(map.y);
        let c = 2.0 * (rho / (2.0 * self.radius)).atan();
        let (northing, z_sign) = match self.pole {
            Pole::South => (map.y, -1.0),
            Pole::North => (-map.y, 1.0),
        };
        let lon = map.x.atan2(northing);
        let r = self.radius + map.z;
        DVec3::new(
            r * c.sin() * lon.cos(),
            r * c.sin() * lon.sin(),
            z_sign * r * c.cos(),
        )
    }

    /// `raw` with every vertex mapped to body-fixed coordinates. The triangles keep their
    /// winding: the projection preserves orientation (map up becomes outward).
    pub fn apply(&self, raw: RawMesh) -> RawMesh {
        RawMesh {
            vertices: raw
                .vertices
                .iter()
                .map(|&v| self.to_body_fixed(v))
                .collect(),
            triangles: raw.triangles,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const R: f64 = 1737.4;

    #[test]
    fn the_pole_maps_to_the_pole_and_heights_are_radial() {
        let south = PolarStereographic {
            pole: Pole::South,
            radius: R,
        };
        assert!(
            (south.to_body_fixed(DVec3::new(0.0, 0.0, 2.0)) - DVec3::new(0.0, 0.0, -R - 2.0))
                .length()
                < 1e-9
        );
        let north = PolarStereographic {
            pole: Pole::North,
            radius: R,
        };
        assert!((north.to_body_fixed(DVec3::ZERO) - DVec3::new(0.0, 0.0, R)).length() < 1e-9);
    }

    #[test]
    fn longitudes_and_colatitudes_follow_the_polar_convention() {
        // On the south map, +y is the 0° meridian and +x is 90° E; ρ = 2R tan(c/2).
        let south = PolarStereographic {
            pole: Pole::South,
            radius: R,
        };
        let c = 3f64.to_radians();
        let rho = 2.0 * R * (c / 2.0).tan();
        let p = south.to_body_fixed(DVec3::new(0.0, rho, 0.0));
        assert!((p - R * DVec3::new(c.sin(), 0.0, -c.cos())).length() < 1e-9);
        let p = south.to_body_fixed(DVec3::new(rho, 0.0, 0.0));
        assert!((p - R * DVec3::new(0.0, c.sin(), -c.cos())).length() < 1e-9);
        // On the north map, −y is the 0° meridian.
        let north = PolarStereographic {
            pole: Pole::North,
            radius: R,
        };
        let p = north.to_body_fixed(DVec3::new(0.0, -rho, 0.0));
        assert!((p - R * DVec3::new(c.sin(), 0.0, c.cos())).length() < 1e-9);
    }
}
