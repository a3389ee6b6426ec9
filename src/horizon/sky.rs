//! Sky lookups: where the Sun stands in a facet's sky, and what its horizon map says
//! there.
//!
//! In: a [`HorizonMap`] (or a [`PointHorizon`]) from `map`, a facet's unit normal and a
//! unit Sun direction (both body frame). Out: the Sun's [`SkyPosition`] (its wedge, its
//! place between wedge centres, the sine and cosine of its elevation), whether it
//! clears the facet's upper bound for certain (`clears`, the exact mode) or stands under
//! the interpolated horizon (`hides`, the approximate mode), and the [`LocalHorizon`]
//! there (radians, radians per radian of azimuth) for the solar disk.
//!
//! This is the step loop's side of a map; `map` is the build's. They are kept apart
//! because a map's cache key hashes the build's source: lookups can change without every
//! cached map being built again. The two agree through what they share: the facet's
//! [`tangent_frame`], the fast `atan2_within` (its error is inside the margins the
//! build leaves, `CLEAR_MARGIN` and the wedges' overlap) and the cells' quanta.

use super::geometry::{atan2_within, tangent_frame};
use super::map::{HorizonMap, PointHorizon, CLEAR_MARGIN, QUANTA_PER_RAD};
use glam::DVec3;
use std::f64::consts::TAU;
use std::sync::LazyLock;

/// Where the Sun stands in a facet's sky: its wedge, its place between wedge centres
/// and its elevation above the facet's plane (as a sine and a cosine: most lookups
/// decide without the angle).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkyPosition {
    /// The wedge the azimuth falls in.
    pub wedge: usize,
    /// The azimuth φ in wedge widths Δ from the first wedge's centre, `φ/Δ − ½`, in
    /// `[−½, A − ½)`: the wedge centres on either side lie at its floor and one above.
    pub between: f64,
    /// Sine of the elevation above the facet's plane.
    pub sin_elevation: f64,
    /// Cosine of the elevation: the length of the direction's part in the plane.
    cos_elevation: f64,
}

impl SkyPosition {
    /// Elevation above the facet's plane, radians (within 5e-10 rad, the fast
    /// `atan2`'s error).
    #[inline]
    pub fn elevation(&self) -> f64 {
        atan2_within(self.sin_elevation, self.cos_elevation)
    }
}

/// The approximate horizon toward the Sun: its elevation and slope.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalHorizon {
    /// Elevation of the horizon at the Sun's azimuth, radians.
    pub elevation: f64,
    /// Its rate of change with azimuth, radians per radian.
    pub slope: f64,
}

impl HorizonMap {
    /// True when a Sun at `sin_elevation` above facet `i`'s plane stands above every
    /// wedge of its horizon for certain (as [`HorizonMap::clears`] certifies in one
    /// wedge), and above [`HorizonMap::horizon`] at any azimuth: its azimuth need not
    /// be found.
    #[inline]
    pub fn above_all(&self, i: usize, sin_elevation: f64) -> bool {
        sin_elevation > self.ceilings[i]
    }

    /// True when a disk Sun of angular `radius` (radians) whose centre stands at
    /// `sin_elevation` above facet `i`'s plane lies so far above every cell of its map
    /// that the approximate horizon ([`HorizonMap::horizon`]), taken across the disk as a
    /// straight line ([`super::disk::SolarDisk::cut_by`]), misses the disk at any azimuth:
    /// the disk's share is then its centre's, found without its azimuth or a cell.
    ///
    /// The horizon there lies between two centres, each at most the ceiling's
    /// elevation `C`, so its slope is at most `C·A/2π` (A wedges) and the line, tilted
    /// by it, reaches at most `ρ·√(1 + (C·A/(2π cos e))²)` toward the disk's centre; the
    /// Sun's sine must stand above the ceiling's by that (times 1.001, for rounding),
    /// which puts its elevation above `C` by as much. `C ≤ tan C` bounds the angle from
    /// its sine, and the test is taken squared, times both cosines squared: no root, no
    /// division.
    #[inline]
    pub fn disk_above_all(&self, i: usize, sin_elevation: f64, radius: f64) -> bool {
        disk_above(self.ceilings[i], self.azimuths, sin_elevation, radius)
    }

    /// As [`HorizonMap::position`] for facet `i` (normal `normal`) under a disk Sun of
    /// angular `radius` centred at `sun`, or `None` when the disk stands so far above
    /// its octant of azimuth's ceiling that no horizon its map gives there cuts it (the
    /// test of [`HorizonMap::disk_above_all`], with the octant's ceiling): the straight
    /// horizon across the disk is the one at the centre's azimuth, between two wedge
    /// centres that the octant's ceiling bounds.
    #[inline]
    pub fn locate_disk(
        &self,
        i: usize,
        normal: DVec3,
        (sun, radius): (DVec3, f64),
        sin_elevation: f64,
    ) -> Option<SkyPosition> {
        self.in_octant(i, (normal, sun), sin_elevation, |ceiling| {
            !disk_above(ceiling, self.azimuths, sin_elevation, radius)
        })
    }

    /// Where the unit Sun direction `sun` (body frame) stands in the sky of a facet with
    /// unit normal `normal`, given `sin_elevation = normal·sun`.
    #[inline]
    pub fn position(&self, normal: DVec3, sun: DVec3, sin_elevation: f64) -> SkyPosition {
        sky_position(self.azimuths, normal, sun, sin_elevation)
    }

    /// As [`HorizonMap::position`] for facet `i` (normal `normal`), or `None` when the
    /// Sun stands above every wedge of its octant of azimuth (found by signs and one
    /// comparison, without an angle): clear for certain, as [`HorizonMap::above_all`].
    #[inline]
    pub fn locate(
        &self,
        i: usize,
        normal: DVec3,
        sun: DVec3,
        sin_elevation: f64,
    ) -> Option<SkyPosition> {
        self.in_octant(i, (normal, sun), sin_elevation, |ceiling| {
            sin_elevation <= ceiling
        })
    }

    /// The Sun's position in facet `i`'s sky when `needs_cells` says so of the ceiling of
    /// the octant of azimuth it stands in (a sine), else `None`.
    #[inline]
    fn in_octant(
        &self,
        i: usize,
        (normal, sun): (DVec3, DVec3),
        sin_elevation: f64,
        needs_cells: impl FnOnce(f64) -> bool,
    ) -> Option<SkyPosition> {
        let (x, y) = in_plane(normal, sun);
        let ceiling = self.octant_ceilings[i][octant(x, y)] as f64;
        needs_cells(ceiling).then(|| position_in_plane(self.azimuths, x, y, sin_elevation))
    }

    /// True when facet `i` sees a Sun at `at` for certain: above the upper bound of its
    /// wedge (the exact tracers agree). The elevation's angle is taken only when its
    /// sine lies within `SINE_SLACK` (2e-7) of the bound's.
    #[inline]
    pub fn clears(&self, i: usize, at: &SkyPosition) -> bool {
        let upper = self.cell(i, at.wedge)[0];
        let sin = sine_of_quanta(upper);
        // sin(h + m) ≤ sin h + m: a sine above sin h + m is above the margin too.
        if at.sin_elevation > sin + CLEAR_MARGIN + SINE_SLACK {
            true
        } else if at.sin_elevation < sin - SINE_SLACK {
            false
        } else {
            clears_bound(at, upper as f64 / QUANTA_PER_RAD)
        }
    }

    /// True when a point Sun at `at` stands at or below the approximate horizon of facet
    /// `i` ([`HorizonMap::horizon`]). The elevation's angle is taken only when its sine
    /// lies between the two wedge centres' (widened by `SINE_SLACK`): the horizon
    /// between them lies between them.
    #[inline]
    pub fn hides(&self, i: usize, at: &SkyPosition) -> bool {
        let (k0, k1, t) = centres_around(self.azimuths, at);
        let (q0, q1) = (self.cell(i, k0)[1], self.cell(i, k1)[1]);
        if at.sin_elevation < sine_of_quanta(q0.min(q1)) - SINE_SLACK {
            true
        } else if at.sin_elevation > sine_of_quanta(q0.max(q1)) + SINE_SLACK {
            false
        } else {
            let centres = [q0, q1].map(|q| q as f64 / QUANTA_PER_RAD);
            at.elevation() <= between_centres(self.azimuths, centres, t).elevation
        }
    }

    /// The approximate horizon of facet `i` at the Sun's azimuth: linear between the
    /// horizons at the two nearest wedge centres.
    #[inline]
    pub fn horizon(&self, i: usize, at: &SkyPosition) -> LocalHorizon {
        let (k0, k1, t) = centres_around(self.azimuths, at);
        let centres = [k0, k1].map(|k| self.cell(i, k)[1] as f64 / QUANTA_PER_RAD);
        between_centres(self.azimuths, centres, t)
    }
}

impl PointHorizon {
    /// Where the unit direction `dir` stands in this sky.
    pub fn position(&self, dir: DVec3) -> SkyPosition {
        sky_position(self.azimuths(), self.up, dir, self.up.dot(dir))
    }

    /// True when a direction at `at` is above every point of the mesh in its wedge.
    pub fn clears(&self, at: &SkyPosition) -> bool {
        clears_bound(at, self.cells[at.wedge][0])
    }

    /// The approximate horizon at `at`'s azimuth: linear between wedge centres.
    pub fn horizon(&self, at: &SkyPosition) -> LocalHorizon {
        let (k0, k1, t) = centres_around(self.azimuths(), at);
        between_centres(self.azimuths(), [k0, k1].map(|k| self.cells[k][1]), t)
    }
}

/// Where the unit direction `dir` stands in the sky of a plane with unit normal `up`
/// cut into `azimuths` wedges, given `sin_elevation = up·dir`.
///
/// Both angles come from [`atan2_within`], within
/// [`ANGLE_ERROR`](super::geometry::ANGLE_ERROR) of the exact ones: less than the margin
/// by which each wedge's upper bound was widened (the build's `WEDGE_OVERLAP`) and by
/// which a Sun must clear it ([`CLEAR_MARGIN`]), so that a Sun near a wedge's edge is
/// checked against a bound that holds where it really is.
#[inline]
fn sky_position(azimuths: u32, up: DVec3, dir: DVec3, sin_elevation: f64) -> SkyPosition {
    let (x, y) = in_plane(up, dir);
    position_in_plane(azimuths, x, y, sin_elevation)
}

/// The components of `dir` along the tangent frame of the plane with unit normal `up`.
#[inline]
fn in_plane(up: DVec3, dir: DVec3) -> (f64, f64) {
    let (t1, t2) = tangent_frame(up);
    (dir.dot(t1), dir.dot(t2))
}

/// [`sky_position`] from the in-plane components `x`, `y` of the direction.
#[inline]
fn position_in_plane(azimuths: u32, x: f64, y: f64, sin_elevation: f64) -> SkyPosition {
    let mut phi = atan2_within(y, x);
    if phi < 0.0 {
        phi += TAU;
    }
    let w = phi * (azimuths as f64 / TAU);
    SkyPosition {
        wedge: (w as usize).min(azimuths as usize - 1),
        between: w - 0.5,
        sin_elevation,
        cos_elevation: (x * x + y * y).sqrt(),
    }
}

/// True when a Sun at `at` stands above the upper bound `upper` (radians) of its wedge
/// for certain: by more than its elevation's error ([`CLEAR_MARGIN`]).
#[inline]
fn clears_bound(at: &SkyPosition, upper: f64) -> bool {
    at.elevation() > upper + CLEAR_MARGIN
}

/// True when a disk Sun of angular `radius` whose centre stands at `sin_elevation`
/// clears, tilt included, every horizon of a map of `azimuths` wedges whose centres lie
/// below the sine `ceiling` ([`HorizonMap::disk_above_all`] gives the bound).
#[inline]
fn disk_above(ceiling: f64, azimuths: u32, sin_elevation: f64, radius: f64) -> bool {
    let above = sin_elevation - ceiling - 1e-12;
    // The reach is at least the radius; an infinite ceiling reaches straight up.
    if !(ceiling < 1.0 && above > radius) {
        return false;
    }
    let cos2 = (1.0 - sin_elevation * sin_elevation).max(0.0);
    let ceiling_cos2 = 1.0 - ceiling * ceiling;
    let per_radian = azimuths as f64 / TAU;
    let reach = 1.001 * radius;
    let both = cos2 * ceiling_cos2;
    above * above * both >= reach * reach * (both + (ceiling * per_radian).powi(2))
}

/// The octant 0–7 of the azimuth atan2(y, x) in [0, 2π), π/4 wide each, from signs and
/// one comparison (a direction on an octant's edge may fall on either side: the octants'
/// wedges overlap by one, see `map::octant_wedges`).
#[inline]
fn octant(x: f64, y: f64) -> usize {
    match (y >= 0.0, x >= 0.0) {
        (true, true) => usize::from(y >= x),
        (true, false) => 2 + usize::from(y <= -x),
        (false, false) => 4 + usize::from(-y >= -x),
        (false, true) => 6 + usize::from(-y <= x),
    }
}

/// The horizon a fraction `t` of the way from one wedge centre to the next (as
/// [`centres_around`] gives it), linear between their elevations `[h0, h1]` (radians).
#[inline]
fn between_centres(azimuths: u32, [h0, h1]: [f64; 2], t: f64) -> LocalHorizon {
    LocalHorizon {
        elevation: h0 + (h1 - h0) * t,
        slope: (h1 - h0) * (azimuths as f64 / TAU),
    }
}

/// The wedges whose centres lie on either side of `at`'s azimuth, and how far (0–1) it
/// lies from the first toward the second.
#[inline]
fn centres_around(azimuths: u32, at: &SkyPosition) -> (usize, usize, f64) {
    let a = azimuths as usize;
    // `between` lies in [−½, A − ½): the wedge below is −1 (the last) to A − 1. Its floor
    // is a truncation where it is not negative (a libm call, `floor`, cost more).
    let (below, k0) = if at.between < 0.0 {
        (-1.0, a - 1)
    } else {
        let k = at.between as usize;
        (k as f64, k)
    };
    let k1 = if k0 + 1 == a { 0 } else { k0 + 1 };
    (k0, k1, at.between - below)
}

/// Slack (in sine) that covers the rounding of [`sine_of_quanta`] to `f32` (at most
/// 3e-8), of the Sun's sine, and [`ANGLE_ERROR`](super::geometry::ANGLE_ERROR) of the
/// angle the slow path takes, so that deciding by sines outside it gives what the angles
/// give.
const SINE_SLACK: f64 = 2e-7;

/// The sine of an elevation of `q` quanta, from a table (f32, 256 KiB, built once): the
/// lookups' test against a cell without taking the Sun's angle.
#[inline]
fn sine_of_quanta(q: u16) -> f64 {
    static SINES: LazyLock<Vec<f32>> = LazyLock::new(|| {
        (0..=u16::MAX)
            .map(|q| (q as f64 / QUANTA_PER_RAD).sin() as f32)
            .collect()
    });
    SINES[q as usize] as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::horizon::map::{octant_wedges, MapKind};
    use crate::TestRng;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn sky_positions_fall_in_the_wedge_of_their_azimuth() {
        let map =
            HorizonMap::from_cells((16, MapKind::Bounded), 1, vec![[0, 0]; 16]).expect("cells");
        let n = DVec3::new(0.2, -0.3, 0.9).normalize();
        let (t1, t2) = tangent_frame(n);
        assert!((t1.cross(t2) - n).length() < 1e-12);
        for k in 0..16 {
            let phi = (k as f64 + 0.25) * TAU / 16.0;
            let s = ((t1 * phi.cos() + t2 * phi.sin()) * 0.8 + n * 0.6).normalize();
            let at = map.position(n, s, n.dot(s));
            assert_eq!(at.wedge, k);
            assert!((at.between - (k as f64 - 0.25)).abs() < 1e-9);
            assert!((at.elevation() - n.dot(s).asin()).abs() < 1e-15);
        }
    }

    #[test]
    fn sines_decide_as_the_angles_do_even_at_a_hair_from_a_cell() {
        // Suns placed a hair (down to 1e-12 rad) above or below a cell's elevation, or an
        // interpolated horizon's: `clears` and `hides`, which decide by sines where they
        // can, give what the elevation angle compared with the cells gives. The table
        // itself is checked against libm's sine.
        for q in (0..=u16::MAX).step_by(97).chain([u16::MAX]) {
            let exact = (q as f64 / QUANTA_PER_RAD).sin();
            assert!((sine_of_quanta(q) - exact).abs() <= 3e-8, "{q}");
        }
        let mut rng = TestRng::new(0x05EE_D0F5_1AE5);
        let mut random = move || rng.unit();
        let azimuths = 16;
        let cells = (0..azimuths)
            .map(|_| {
                let upper = (random() * 65535.0) as u16;
                [upper, (upper as f64 * random()) as u16]
            })
            .collect();
        let map = HorizonMap::from_cells((azimuths, MapKind::Bounded), 1, cells).expect("fits");
        let hairs = [0.0, 1e-12, 1e-10, 1e-9, 3e-9, 1e-8, 1e-7, 3e-7, 1e-6, 1e-3];
        let (mut cleared, mut hidden, mut cases) = (0, 0, 0);
        for _ in 0..4000 {
            let phi = TAU * random();
            let at = |elevation: f64| {
                let (x, y) = (phi.cos() * elevation.cos(), phi.sin() * elevation.cos());
                position_in_plane(azimuths, x, y, elevation.sin())
            };
            let probe = at(0.5);
            let upper = map.wedge(0, probe.wedge)[0];
            let horizon = map.horizon(0, &probe).elevation;
            for &hair in &hairs {
                for sign in [-1.0, 1.0] {
                    for target in [upper, upper + CLEAR_MARGIN, horizon] {
                        let sun = at((target + sign * hair).min(FRAC_PI_2));
                        let by_angle = clears_bound(&sun, upper);
                        assert_eq!(map.clears(0, &sun), by_angle, "{sun:?} {upper}");
                        let under = sun.elevation() <= map.horizon(0, &sun).elevation;
                        assert_eq!(map.hides(0, &sun), under, "{sun:?}");
                        cleared += usize::from(by_angle);
                        hidden += usize::from(under);
                        cases += 1;
                    }
                }
            }
        }
        // Both answers occur often: the test compares, not one side only.
        assert!(
            cleared > cases / 10 && cleared < 9 * cases / 10,
            "{cleared} of {cases}"
        );
        assert!(
            hidden > cases / 10 && hidden < 9 * cases / 10,
            "{hidden} of {cases}"
        );
    }

    #[test]
    fn ceilings_only_clear_suns_the_cells_clear() {
        // Random maps (some wedge counts not divisible by 8) and random Suns: wherever a
        // ceiling decides, the Sun's own wedge clears and it stands above the
        // interpolated horizon; and the octants' wedges hold each azimuth's neighbours.
        let mut rng = TestRng::new(0x2545_F491_4F6C_DD1D);
        let mut random = move || rng.unit();
        let (mut decided, mut looked_up) = (0, 0);
        for azimuths in [8u32, 12, 128, 131] {
            let facets = 50;
            let cells = (0..facets * azimuths as usize)
                .map(|_| {
                    let upper = (random() * random() * 40000.0) as u16;
                    [upper, (upper as f64 * random()) as u16]
                })
                .collect();
            let map =
                HorizonMap::from_cells((azimuths, MapKind::Bounded), facets, cells).expect("fits");
            for _ in 0..20_000 {
                let i = (random() * facets as f64) as usize;
                let unit = |r: &mut dyn FnMut() -> f64| {
                    let z: f64 = 2.0 * r() - 1.0;
                    let a = TAU * r();
                    let s = (1.0 - z * z).sqrt();
                    DVec3::new(s * a.cos(), s * a.sin(), z)
                };
                let normal = unit(&mut random);
                let sun = unit(&mut random);
                let cos = normal.dot(sun);
                if cos <= 0.0 {
                    continue;
                }
                let at = map.position(normal, sun, cos);
                let (x, y) = in_plane(normal, sun);
                let wedges = octant_wedges(azimuths as usize, octant(x, y));
                let below = (at.between.floor() as isize).rem_euclid(azimuths as isize) as usize;
                for k in [at.wedge, below, (below + 1) % azimuths as usize] {
                    assert!(wedges.contains(&k), "wedge {k} not in octant {wedges:?}");
                }
                let located = map.locate(i, normal, sun, cos);
                if map.above_all(i, cos) || located.is_none() {
                    decided += 1;
                    assert!(map.clears(i, &at), "{i} {at:?}");
                    assert!(at.elevation() > map.horizon(i, &at).elevation, "{i} {at:?}");
                } else {
                    looked_up += 1;
                    assert_eq!(located, Some(at));
                }
            }
        }
        assert!(decided > 1000 && looked_up > 1000, "{decided} {looked_up}");
    }

    /// The disk tests' random numbers in [0, 1) from `seed`, and their limb-darkened disk.
    fn disk_test(seed: u64) -> (impl FnMut() -> f64, super::super::disk::SolarDisk) {
        let mut rng = TestRng::new(seed);
        let disk = super::super::disk::SolarDisk {
            limb_darkening: 0.6,
        };
        (move || rng.unit(), disk)
    }

    #[test]
    fn a_disk_above_every_cell_is_cut_by_no_horizon() {
        // Random maps whose centres jump from wedge to wedge (the steepest horizons a map
        // can give), random Suns and disk radii: wherever `disk_above_all` says so, the
        // straight horizon at the Sun's azimuth leaves the whole disk in view, as the
        // step loop would find by reading the cells. A test of the ceiling alone (the
        // disk's radius above it, tilt ignored) is cut on some of them: the tilt matters.
        let (mut random, disk) = disk_test(0x9E37_79B9_7F4A_7C15);
        let (mut above, mut naive_cut) = (0, 0);
        for azimuths in [8u32, 64, 128] {
            let facets = 40;
            let cells = (0..facets * azimuths as usize)
                .map(|k| {
                    let high = (random() * random() * 30000.0) as u16;
                    let centre = if k % 2 == 0 { high } else { 0 };
                    [high, centre]
                })
                .collect();
            let map =
                HorizonMap::from_cells((azimuths, MapKind::Bounded), facets, cells).expect("fits");
            for _ in 0..40_000 {
                let i = (random() * facets as f64) as usize;
                let radius = 0.02 * random() * random();
                let ceiling = map.ceilings[i].min(1.0).asin();
                let e = (ceiling + radius * 40.0 * random()).min(FRAC_PI_2 - 1e-3);
                let a = TAU * random();
                let (s, c) = (e.sin(), e.cos());
                let normal = DVec3::Z;
                let (t1, t2) = tangent_frame(normal);
                let sun = (normal * s + (t1 * a.cos() + t2 * a.sin()) * c).normalize();
                let cos = normal.dot(sun);
                let at = map.position(normal, sun, cos);
                let cut = disk.cut_by(cos.asin(), map.horizon(i, &at), radius);
                if map.disk_above_all(i, cos, radius) {
                    above += 1;
                    assert!(cut.is_none(), "facet {i}, e {e}, radius {radius}: {cut:?}");
                } else if cos > map.ceilings[i] + radius && cut.is_some() {
                    naive_cut += 1;
                }
            }
        }
        assert!(above > 5000 && naive_cut > 10, "{above} {naive_cut}");
    }

    #[test]
    fn a_disk_above_its_octants_cells_is_cut_by_no_horizon() {
        // As above, with Suns drawn about their octant's ceiling: wherever `locate_disk`
        // finds no position, the straight horizon at the Sun's azimuth leaves the whole
        // disk in view; elsewhere it gives `position`'s. Many of those it decides stand
        // below the whole map's ceiling (the octant spares their cells).
        let (mut random, disk) = disk_test(0x2545_F491_4F6C_DD1D);
        let (mut decided, mut below_whole, mut looked_up) = (0, 0, 0);
        for azimuths in [8u32, 60, 128] {
            let facets = 40;
            let cells = (0..facets * azimuths as usize)
                .map(|k| {
                    let high = (random() * random() * random() * 40000.0) as u16;
                    let centre = if k % 3 == 0 { high } else { high / 4 };
                    [high, centre]
                })
                .collect();
            let map =
                HorizonMap::from_cells((azimuths, MapKind::Bounded), facets, cells).expect("fits");
            let normal = DVec3::new(0.3, -0.5, 0.8).normalize();
            let (t1, t2) = tangent_frame(normal);
            for _ in 0..40_000 {
                let i = (random() * facets as f64) as usize;
                let radius = 0.02 * random() * random();
                let a = TAU * random();
                let octant = octant(a.cos(), a.sin());
                let ceiling = (map.octant_ceilings[i][octant] as f64).min(1.0).asin();
                let e = (ceiling + radius * 20.0 * (random() - 0.2)).clamp(1e-3, FRAC_PI_2 - 1e-3);
                let (s, c) = (e.sin(), e.cos());
                let sun = (normal * s + (t1 * a.cos() + t2 * a.sin()) * c).normalize();
                let cos = normal.dot(sun);
                let at = map.position(normal, sun, cos);
                match map.locate_disk(i, normal, (sun, radius), cos) {
                    None => {
                        decided += 1;
                        below_whole += usize::from(!map.disk_above_all(i, cos, radius));
                        let cut = disk.cut_by(cos.asin(), map.horizon(i, &at), radius);
                        assert!(cut.is_none(), "facet {i}, e {e}, radius {radius}: {cut:?}");
                    }
                    Some(located) => {
                        looked_up += 1;
                        assert_eq!(located, at);
                    }
                }
            }
        }
        assert!(
            below_whole > 5000 && looked_up > 5000,
            "{decided} decided, {below_whole} below the whole ceiling, {looked_up} looked up"
        );
    }
}
