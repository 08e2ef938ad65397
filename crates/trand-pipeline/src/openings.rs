//! Open vessels: where the masks cannot tell an opening from a lid, a thin-shell prior decides.
//!
//! **Why a lid forms.** Instance masks constrain a surfel model only up to its visual hull. For an
//! upright tumbler, mug or bowl the hull is solid: every pixel of the opening is an object pixel (its
//! first surface is the inner wall or the bottom), and the ring views, looking down at 40–60°, leave a
//! pyramidal "roof" above the rim (each view's silhouette cone is tangent to the far rim and rises
//! towards the camera by `cot e` per unit of run). Colour does not break the tie for glass: what is
//! seen through the opening is seen through a thin wall as well. The optimiser keeps the surfels that
//! the training rays meet first, so it ends with a lid on the roof, up to a container's depth too near.
//!
//! **What is done.** Before training, the training masks are turned into a labelled voxel hull
//! ([`object_voxels`]: a voxel is inside when every view that sees it shows an object there, and it is
//! labelled with the object most views show). Each object's hull gives a radial profile `R(z)` about a
//! vertical axis ([`Profile`]). The top of the profile that shrinks at least half as fast as a roof
//! would (`−dR/dz ≥ ½ cot e_max`) is the roof; the first slice below it is the rim. An object is an
//! **open vessel** ([`classify`]) when it stands upright (on the table or on another object), nothing
//! stands on it (an object leaning on its rim from outside keeps its own voxels out of the carving),
//! its whole top lies in the hull's box, and its rim is its widest cross-section over
//! the upper body (tumblers, mugs and bowls standing on their base). Its opening is
//! then carved ([`Opening::carves`]): everything above the rim, and everything further than a wall
//! margin inside the profile above the floor, measured about the body's own centre line and with
//! the last slices under the rim as wide as the rim ([`Carving`]). The training views then have to
//! explain the opening with the inner walls and the bottom, which is where a test ray through the
//! opening first meets glass.
//!
//! **From one side** (a narrow baseline, [`Baseline::Narrow`]) the hull is the support prior's (see
//! [`crate::support`]): exact at each object's front, stretched behind it over the table it hides.
//! The axis is read from the slices' fronts ([`narrow`]) and the roof over a rim, a lens shrinking
//! from the back, rises twice as high as the ring's; the rest of the decision is the same. An object
//! standing behind a vessel and rising above its rim claims the hull over the opening, which then
//! counts as closed ([`Closed::Supports`]): the cost of not carving an upturned tumbler that carries
//! a glass.
//!
//! Closed tops are never carved: spheroids, bottles and domes (an upturned bowl) narrow towards the
//! top, wine glasses' bowls are wider than their rim, and an object that carries another over its
//! top is closed.
//! An upturned straight-walled vessel with nothing on it (an upturned mug) looks the same as an upright
//! one to the masks and is taken as open: the one case this prior gets wrong.

use std::collections::{BTreeMap, HashSet};

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::Serialize;
use trand_core::Camera;

use crate::targets::TrainView;

pub mod narrow;
pub mod overhang;

/// Where the training views look from, which decides how a hull is read (see [`Profile::seen_from`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Baseline {
    /// Views around the objects (the paper's ring): the hull is the object's, up to a roof.
    Wide,
    /// Views within a few degrees of one another, looking along `toward` (horizontal, unit), with
    /// the support prior applied to the hull: exact at the front only ([`narrow`]).
    Narrow { toward: DVec2 },
}

impl Baseline {
    /// How many times `R tan e` the hull rises over a flat rim of radius `R`: the ring's silhouette
    /// planes meet over the axis; from one side the lens over the rim shrinks from the back only,
    /// over the rim's whole diameter.
    fn roof_rise(self) -> f64 {
        match self {
            Baseline::Wide => 1.0,
            Baseline::Narrow { .. } => 2.0,
        }
    }
}

/// Edge of a hull voxel (m): well below a wall margin, and a 0.7 m box stays under 20 M voxels.
pub const VOXEL_M: f64 = 0.002;
/// Radial margin kept inside the profile for the wall (m): glass walls are 2–5 mm thick and the hull
/// overestimates the outer surface by about a voxel.
pub const WALL_MARGIN_M: f64 = 0.006;
/// Height below the rim over which the wall keeps only [`LIP_WALL_M`] (m). Looking into an open
/// vessel, every ray over the near rim crosses the top of the wall: there the body's
/// [`WALL_MARGIN_M`] is a ledge a few millimetres wider than the glass at the rim's height, which
/// hides the far wall several centimetres deeper (the near errors of open vessels, BENCHMARKS.md
/// §1). Lower down a thick wall only moves the far wall's inside a few millimetres.
pub const LIP_BAND_M: f64 = 0.010;
/// Wall kept within [`LIP_BAND_M`] of the rim, across a vertical wall (m): a glass wall's thickness;
/// the hull's overestimate of the outer surface (about a voxel) stays on the kept side.
pub const LIP_WALL_M: f64 = 0.003;
/// Height above the hull's bottom below which nothing is carved (m): the vessel's base.
pub const FLOOR_M: f64 = 0.005;
/// A rim must be at least this wide (m): narrower tops (bottle necks) are not openings one can see into.
pub const MIN_RIM_RADIUS_M: f64 = 0.02;
/// The rim may be this much narrower than the widest slice of the upper body and still count as the
/// widest (m): about one voxel of hull noise on each side.
pub const RIM_TOLERANCE_M: f64 = 0.0035;
/// The wall of a straight vessel may narrow this much below the rim (m): a tumbler's taper plus
/// hull noise.
pub const MAX_TAPER_M: f64 = 0.008;
/// A straight-walled vessel's rim stands at least this many times its radius high; lower or
/// narrowing bodies are judged by their crown ([`MAX_BOWL_CROWN`]).
pub const MIN_ASPECT: f64 = 1.5;
/// Share of a straight vessel's height that may narrow where its foot is hidden (see
/// [`MIN_HIDDEN_FOOT_ASPECT`]).
pub const HIDDEN_FOOT: f64 = 0.3;
/// A straight vessel whose lowest [`HIDDEN_FOOT`] narrows must stand this many radii high: more than a
/// sphere's rim (about 1.5 radii above its foot) or a spheroid's up to `c/a` of 1.3.
pub const MIN_HIDDEN_FOOT_ASPECT: f64 = 2.0;
/// Another object's voxels above a rim whose centre lies within this share of the rim's radius
/// from the axis stand on the vessel; further out, the object leans on the rim.
pub const MAX_LEANER_OFFSET: f64 = 0.5;
/// Largest [`Profile::crown`] of a bowl. A bowl's profile is a spheroid's lower half; what differs is
/// the hull above the widest slice: over a flat rim of radius `R` only the roof, `R tan e` high (0.88 R
/// for ring views at 41°); over a spheroid with semi-axes `a`, `c` the cap and the roof over it, whose
/// silhouette planes meet `√(a² sin² e + c² cos² e) / cos e` above the equator (1.1–1.3 a for
/// `c/a` of 0.7–1). The crown also counts the band within a voxel of the widest slice, which adds
/// about 0.2 to both; the threshold sits between the two.
pub const MAX_BOWL_CROWN: f64 = 1.22;
/// A bowl flares: its rim is at least this many times wider than its foot (the lowest fifth of its
/// height). An upturned bowl, a dome, narrows from the table up.
pub const MIN_BOWL_FLARE: f64 = 1.1;
/// Share of an object's footprint another object's voxels fill in a slice of what it stands on
/// ([`support_under`]).
const SUPPORT_FILL: f64 = 0.25;
/// Least height (m) of an object's hull above the top of what it stands on ([`support_under`]).
const MIN_BODY_M: f64 = 0.03;
/// A hull starting this high above the table (m) stands on another object (see [`Profile::of`]).
pub const RAISED_M: f64 = 0.01;
/// Largest lean of the axis (horizontal drift of the slice centres per unit height) of an upright
/// object: tan 10°.
pub const MAX_LEAN: f64 = 0.18;
/// The hull above a rim may stand this many times the roof's height (`R tan e`) before it counts as
/// more than a roof: the polygonal roof of six views is a little higher than the cone of many.
const ROOF_SLACK: f64 = 1.2;
/// A waist below the widest slice narrower than this fraction of it is a stem.
pub const MAX_STEM_RATIO: f64 = 0.35;
/// A stemmed cup's rim is at least this fraction of its widest slice (a wine glass's bowl closes in
/// towards the rim; an upturned one shows its foot, far narrower than its bowl, on top).
pub const MIN_CUP_RIM_RATIO: f64 = 0.75;
/// Largest [`Profile::elongation`] of a standing vessel: a mug's handle stretches its footprint a
/// little.
pub const MAX_ELONGATION: f64 = 1.3;
/// Angular sectors of the radial profile; the lower quartile over sectors ignores a handle.
const SECTORS: usize = 16;
/// Slices below the roof's start whose widest gives the rim radius.
const RIM_WINDOW: usize = 4;
/// Slices (of [`VOXEL_M`]) compared by the roof test.
const ROOF_RUN: usize = 4;
/// Largest share of an object's hull voxels above a gap that are strays (see [`hull_end`]).
const MAX_STRAY_SHARE: f64 = 0.25;
/// An object needs this many voxels for a profile.
const MIN_VOXELS: usize = 200;
/// A slice at most this wide (m) is a roof's apex, not the object's (see [`Profile::top_slice`]).
const APEX_M: f64 = 2.0 * VOXEL_M;

/// Labelled voxel centres of the training masks' visual hull, per object id (the masks as given,
/// [`TrainView::given_ids`]).
pub fn object_voxels(views: &[TrainView], min: DVec3, max: DVec3) -> BTreeMap<u16, Vec<DVec3>> {
    object_voxels_where(views, min, max, |_| true)
}

/// [`object_voxels`] of the points `keep` accepts (the support prior's test, on a narrow baseline).
pub fn object_voxels_where(
    views: &[TrainView],
    min: DVec3,
    max: DVec3,
    keep: impl Fn(DVec3) -> bool + Sync,
) -> BTreeMap<u16, Vec<DVec3>> {
    let n = |k: usize| (((max[k] - min[k]) / VOXEL_M).ceil() as usize).max(1);
    let (nx, ny, nz) = (n(0), n(1), n(2));
    let columns: Vec<Vec<(u16, DVec3)>> = (0..nx * ny)
        .into_par_iter()
        .map(|c| {
            let (ix, iy) = (c % nx, c / nx);
            (0..nz)
                .filter_map(|iz| {
                    let p = min + (DVec3::new(ix as f64, iy as f64, iz as f64) + 0.5) * VOXEL_M;
                    label_of(views, p).filter(|_| keep(p)).map(|id| (id, p))
                })
                .collect()
        })
        .collect();
    let mut out: BTreeMap<u16, Vec<DVec3>> = BTreeMap::new();
    for (id, p) in columns.into_iter().flatten() {
        out.entry(id).or_default().push(p);
    }
    out
}

/// The object most views show at `p`, if every view that sees `p` (at least two) shows an object.
fn label_of(views: &[TrainView], p: DVec3) -> Option<u16> {
    let mut votes: [(u16, u8); 8] = [(0, 0); 8];
    let mut seen = 0;
    for v in views {
        let Some(id) = id_at(v, p) else { continue };
        if id == 0 {
            return None;
        }
        seen += 1;
        if let Some(slot) = votes.iter_mut().find(|s| s.0 == id || s.1 == 0) {
            slot.0 = id;
            slot.1 += 1;
        }
    }
    (seen >= 2).then(|| votes.iter().max_by_key(|s| s.1).map(|s| s.0))?
}

/// Instance id of the pixel `p` projects to, `None` outside the image or behind the camera.
fn id_at(v: &TrainView, p: DVec3) -> Option<u16> {
    v.pixel_of(p).map(|o| v.given_ids[o])
}

/// Radial profile of one object's hull about a vertical axis, in slices of [`VOXEL_M`].
#[derive(Clone, Debug, Serialize)]
pub struct Profile {
    /// Axis position (x, y).
    pub axis: [f64; 2],
    /// Height of the bottom of slice 0.
    pub z0: f64,
    /// Lower quartile over sectors of the largest radius in each sector, per slice (0 for an empty
    /// slice; see [`sector_radius`]).
    pub radius: Vec<f64>,
    /// Elongation of the footprint: `√(λ₁/λ₂)` of the covariance of the voxels' (x, y), 1 for a
    /// round object; a tumbler lying on its side is its length over its diameter (1.2–1.8).
    pub elongation: f64,
    /// Horizontal drift of the slice centres per unit height (0 for a vertical axis).
    pub lean: f64,
    /// The highest slice whose [`sector_radius`] about its own centre (its voxels' component-wise
    /// median) instead of the axis exceeds [`APEX_M`] (0 if none): a bottle's neck off an axis
    /// misread by a few millimetres still shows as a column ([`Profile::neck_top`]).
    pub own_top: usize,
}

impl Profile {
    /// Profile of `voxels` (world positions of one object's hull voxels) seen from around it.
    pub fn of(voxels: &[DVec3]) -> Option<Self> {
        Self::seen_from(voxels, Baseline::Wide)
    }

    /// Profile of `voxels` whose hull the views of `baseline` carved. From one side the axis is
    /// read from the slices' fronts ([`narrow`]), and the footprint's depth, not seen, is not
    /// measured (elongation 1).
    pub fn seen_from(voxels: &[DVec3], baseline: Baseline) -> Option<Self> {
        Self::standing_on(voxels, baseline, None)
    }

    /// [`Profile::seen_from`] for an object standing on a support whose top is at height `base`
    /// (see [`support_under`]): seen from around it, its axis and lean are read from the slices above
    /// the support only. Below, its hull wraps the support: where the views see the object in front
    /// of what carries it, the voxels around the support take the object's label, and their centre
    /// lies between the two.
    pub fn standing_on(voxels: &[DVec3], baseline: Baseline, base: Option<f64>) -> Option<Self> {
        if voxels.len() < MIN_VOXELS {
            return None;
        }
        let z0 = voxels.iter().map(|p| p.z).fold(f64::INFINITY, f64::min) - 0.5 * VOXEL_M;
        let top = voxels.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
        let slices = (((top - z0) / VOXEL_M).floor() as usize) + 1;
        let mut by_slice: Vec<Vec<DVec2>> = vec![Vec::new(); slices];
        for p in voxels {
            let k = (((p.z - z0) / VOXEL_M).floor() as usize).min(slices - 1);
            by_slice[k].push(p.truncate());
        }
        // The body the axis is read from: above the support, where there is one.
        let first = base.filter(|_| baseline == Baseline::Wide).map_or(0, |b| {
            (((b - z0) / VOXEL_M).max(0.0) as usize).min(slices - 1)
        });
        let body = &by_slice[first..];
        let n = body.len();
        let height = (n as f64 * VOXEL_M).max(VOXEL_M);
        // The foot (the lowest fifth, rounded up), the second and the middle fifth.
        let fifth = |f: usize| &body[f * n / 5..((f + 1) * n / 5).max(f * n / 5 + 1)];
        let parts = [&body[..n.div_ceil(5)], fifth(1), fifth(2)];
        let (axis, lean) = match baseline {
            // Just above the support the hull still mixes with its top: the body is read from
            // its second and middle fifths.
            Baseline::Wide if first > 0 => {
                let axis = inscribed_centre(parts[1])?;
                let middle = inscribed_centre(parts[2]).unwrap_or(axis);
                (axis, (middle - axis).length() / (0.2 * height))
            }
            Baseline::Wide => wide_axis(parts, height, z0)?,
            Baseline::Narrow { toward } => {
                let centre = |slices| median_point(&narrow::slice_centres(slices, toward, VOXEL_M));
                let foot = centre(parts[0])?;
                let middle = centre(parts[2]).unwrap_or(foot);
                (foot, (middle - foot).length() / (0.4 * height))
            }
        };
        let end = hull_end(&by_slice);
        let radius = by_slice[..end]
            .iter()
            .map(|s| sector_radius(s, axis))
            .collect();
        // From the top down: only the slices above the first wide one are measured.
        let own_top = by_slice[..end]
            .iter()
            .rposition(|s| median_point(s).is_some_and(|c| sector_radius(s, c) > APEX_M))
            .unwrap_or(0);
        let elongation = match baseline {
            Baseline::Wide => elongation(&by_slice[..end].concat()),
            Baseline::Narrow { .. } => 1.0,
        };
        Some(Self {
            elongation,
            axis: axis.to_array(),
            z0,
            radius,
            lean,
            own_top,
        })
    }

    /// Index of the rim slice: the highest slice below the roof. The roof is the run of top slices
    /// each narrower by at least `slope · ROOF_RUN · VOXEL_M` than the slice `ROOF_RUN` below it, or
    /// at most two voxels wide (its apex).
    pub fn rim_slice(&self, slope: f64) -> usize {
        let drop = slope * ROOF_RUN as f64 * VOXEL_M;
        let mut k = self.radius.len() - 1;
        // The apex of a roof is a few voxels wide: its slices count as roof whatever lies below.
        while k >= ROOF_RUN
            && (self.radius[k] <= APEX_M || self.radius[k] < self.radius[k - ROOF_RUN] - drop)
        {
            k -= 1;
        }
        k
    }

    /// Height of the hull's top (without its apex spike, see [`Profile::top_slice`]) above the
    /// lowest slice within a voxel of the widest one, over the widest radius (see
    /// [`MAX_BOWL_CROWN`]).
    pub fn crown(&self) -> f64 {
        let widest = self.radius.iter().fold(0.0f64, |a, &b| a.max(b));
        let first = self
            .radius
            .iter()
            .position(|&r| r >= widest - 1.5 * VOXEL_M)
            .unwrap_or(0);
        (self.top_slice() + 1).saturating_sub(first) as f64 * VOXEL_M / widest.max(VOXEL_M)
    }

    /// The highest slice wider than [`APEX_M`]. Where the silhouette planes of a few views meet,
    /// the hull ends in a spike one or two voxels thick whose height depends on the views' exact
    /// azimuths (up to a few centimetres), not on the object; the shape tests leave it out.
    pub fn top_slice(&self) -> usize {
        self.radius.iter().rposition(|&r| r > APEX_M).unwrap_or(0)
    }

    /// [`Profile::own_top`], or [`Profile::top_slice`] if higher. Where the profile's axis is a few millimetres off (a raised object's foot mixes with
    /// its support), a bottle's neck reads as an apex about the axis (the radius is a lower quartile
    /// over sectors, and the sectors away from the neck see only its near edge, or nothing), and its
    /// shoulder as a rim under a roof; about its own centre the neck keeps its width, while an apex
    /// spike one or two voxels thick stays under [`APEX_M`].
    pub fn neck_top(&self) -> usize {
        self.own_top.max(self.top_slice())
    }

    /// The slice holding height `z` (it may lie above the last one); `None` below slice 0.
    pub fn slice_of(&self, z: f64) -> Option<usize> {
        let k = ((z - self.z0) / VOXEL_M).floor();
        (k >= 0.0).then_some(k as usize)
    }

    /// Height of the top of slice `k`.
    pub fn slice_top(&self, k: usize) -> f64 {
        self.z0 + (k + 1) as f64 * VOXEL_M
    }
}

/// Where a hull's profile ends: at its first empty slice above which lie fewer than
/// [`MAX_STRAY_SHARE`] of its voxels (strays: label noise at occlusions, not the object's top). A
/// gap with more above it is a thin part the hull lost (a wine glass's stem, a few pixels wide, is
/// gone wherever one view's mask is eroded or its camera a little off), bridged as empty slices.
fn hull_end(by_slice: &[Vec<DVec2>]) -> usize {
    let total: usize = by_slice.iter().map(Vec::len).sum();
    let mut above = total;
    for (k, s) in by_slice.iter().enumerate() {
        above -= s.len();
        if s.is_empty() && (above as f64) < MAX_STRAY_SHARE * total as f64 {
            return k;
        }
    }
    by_slice.len()
}

/// The axis and lean of a hull seen from around it, from its foot, second and middle fifths by
/// height (`parts`): the foot's centre, and the drift from it to the middle fifth's centre per unit
/// `height`.
///
/// Where a raised object's foot hull mixes with what it stands on (a bowl on an upturned
/// tumbler), the lowest fifth's centre is off the axis: such an object (its hull starting `z0`
/// above [`RAISED_M`]) that leans by its foot only is judged, and centred, by its second fifth. On
/// the table, a foot leaning alone is left leaning: a spheroid's hull under boundary errors would
/// pass for a bowl's.
fn wide_axis(parts: [&[Vec<DVec2>]; 3], height: f64, z0: f64) -> Option<(DVec2, f64)> {
    let foot_axis = median_point(&parts[0].concat())?;
    // The middle fifth, below any roof (whose voxels lean towards the cameras off the rig's axis).
    let middle_centre = median_point(&parts[2].concat()).unwrap_or(foot_axis);
    let foot_lean = (middle_centre - foot_axis).length() / (0.4 * height);
    let raised = z0 > RAISED_M;
    Some(match median_point(&parts[1].concat()) {
        Some(c) if raised && foot_lean > MAX_LEAN => {
            let above = (middle_centre - c).length() / (0.2 * height);
            if above <= MAX_LEAN {
                (c, above)
            } else {
                (foot_axis, foot_lean)
            }
        }
        _ => (foot_axis, foot_lean),
    })
}

/// Component-wise median of points.
fn median_point(pts: &[DVec2]) -> Option<DVec2> {
    if pts.is_empty() {
        return None;
    }
    let med = |f: fn(&DVec2) -> f64| {
        let mut v: Vec<f64> = pts.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    Some(DVec2::new(med(|p| p.x), med(|p| p.y)))
}

/// Centre of the largest circle inside each slice's cross-section (its voxels farthest from
/// any empty cell, to within a voxel, averaged), the median over `slices`.
///
/// Why not the median of the voxels: a mug's body above the foot carries its handle, and its hull
/// carries more, a wedge where the views that see the handle beside the body widen their
/// silhouettes, which pulls a median or a fitted circle a centimetre towards it. The hull is the
/// intersection of the views' silhouette strips, each centred on the body where the handle does
/// not widen it, so the inscribed circle stays on the body.
fn inscribed_centre(slices: &[Vec<DVec2>]) -> Option<DVec2> {
    let centres: Vec<DVec2> = slices.iter().filter_map(|s| slice_inscribed(s)).collect();
    median_point(&centres)
}

/// [`inscribed_centre`] of one slice's voxel centres.
fn slice_inscribed(pts: &[DVec2]) -> Option<DVec2> {
    let cell = |p: &DVec2| {
        [
            (p.x / VOXEL_M).floor() as i64,
            (p.y / VOXEL_M).floor() as i64,
        ]
    };
    let cells: HashSet<[i64; 2]> = pts.iter().map(cell).collect();
    let empty: HashSet<[i64; 2]> = cells
        .iter()
        .flat_map(|[x, y]| [[x + 1, *y], [x - 1, *y], [*x, y + 1], [*x, y - 1]])
        .filter(|c| !cells.contains(c))
        .collect();
    let depth: Vec<([i64; 2], i64)> = cells
        .iter()
        .map(|c| {
            let d = empty
                .iter()
                .map(|e| (e[0] - c[0]).pow(2) + (e[1] - c[1]).pow(2))
                .min()
                .unwrap_or(0);
            (*c, d)
        })
        .collect();
    let deepest = depth.iter().map(|(_, d)| *d).max()?;
    let floor = ((deepest as f64).sqrt() - 1.0).max(0.0).powi(2);
    let inner: Vec<DVec2> = depth
        .iter()
        .filter(|(_, d)| *d as f64 >= floor)
        .map(|(c, _)| (DVec2::new(c[0] as f64, c[1] as f64) + 0.5) * VOXEL_M)
        .collect();
    Some(inner.iter().fold(DVec2::ZERO, |a, p| a + *p) / inner.len() as f64)
}

/// Lower quartile over [`SECTORS`] angular sectors of the largest distance from `axis` (empty
/// sectors count as 0), plus half a voxel for the voxel's own extent.
///
/// Why not the median: a ring of `n` views carves a circle's hull to a polygon whose sides touch
/// it and whose corners stand `1/cos(π/n)` out (15 % for six views), and over a rim the roof's
/// planes cut those corners first. The median radius thus shrinks by several millimetres from a
/// straight wall to its rim, as over a narrowing top, and more for wide vessels; the sides, which
/// the lower quartile follows, stay at the wall's radius up to the rim. A handle widens a few
/// sectors only.
fn sector_radius(pts: &[DVec2], axis: DVec2) -> f64 {
    let far = sector_extents(pts, axis);
    0.5 * (far[SECTORS / 4 - 1] + far[SECTORS / 4]) + 0.5 * VOXEL_M
}

/// `√(λ₁/λ₂)` of the 2×2 covariance of `pts` (see [`Profile::elongation`]).
fn elongation(pts: &[DVec2]) -> f64 {
    let n = pts.len().max(1) as f64;
    let m = pts.iter().fold(DVec2::ZERO, |a, p| a + *p) / n;
    let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
    for p in pts {
        let d = *p - m;
        xx += d.x * d.x;
        xy += d.x * d.y;
        yy += d.y * d.y;
    }
    let (t, det) = ((xx + yy) / n, (xx * yy - xy * xy) / (n * n));
    let disc = (0.25 * t * t - det).max(0.0).sqrt();
    ((0.5 * t + disc) / (0.5 * t - disc).max(1e-12)).sqrt()
}

/// The largest distance from `axis` in each of [`SECTORS`] angular sectors (0 for empty ones),
/// ascending.
fn sector_extents(pts: &[DVec2], axis: DVec2) -> [f64; SECTORS] {
    if pts.is_empty() {
        return [0.0; SECTORS];
    }
    let mut far = [0.0f64; SECTORS];
    for p in pts {
        let d = *p - axis;
        let a = d.y.atan2(d.x) + std::f64::consts::PI;
        let s = ((a / std::f64::consts::TAU * SECTORS as f64) as usize).min(SECTORS - 1);
        far[s] = far[s].max(d.length());
    }
    far.sort_by(f64::total_cmp);
    far
}

/// Why an object's top is not carved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Closed {
    /// Too few hull voxels for a profile.
    TooSmall,
    /// The axis leans: the profile about a vertical axis says nothing about the opening.
    Leaning,
    /// The top is narrower than [`MIN_RIM_RADIUS_M`] (a bottle's neck) or narrower than the body
    /// below it (a dome, a sphere, a wine glass's bowl, an upturned tapered tumbler).
    NarrowTop,
    /// Neither a straight-walled vessel nor a bowl: the hull rises higher above its widest slice than
    /// a roof over a rim would ([`Profile::crown`] above [`MAX_BOWL_CROWN`]), as over a spheroid.
    RoundTop,
    /// Neither a straight-walled vessel nor a bowl: a bowl's crown, but the hull does not flare from
    /// its foot by [`MIN_BOWL_FLARE`] (an upturned bowl).
    NoFlare,
    /// Another object stands on its top (see [`MAX_LEANER_OFFSET`]).
    Supports,
    /// Its hull reaches the top of the box it was searched in, so its top was never seen: a bottle
    /// cut at its shoulder would pass for a roof over a rim.
    Truncated,
    /// Its footprint is oblong ([`MAX_ELONGATION`]), not a standing vessel's circle: an object lying
    /// on its side.
    NotRound,
}

/// The carved region of an open vessel (world frame, z up).
#[derive(Clone, Debug, Serialize)]
pub struct Opening {
    pub shape: Shape,
    pub profile: Profile,
    /// Height of the rim: everything above it is carved.
    pub rim_z: f64,
    /// Radius of the rim slice.
    pub rim_radius: f64,
    /// Below this height nothing is carved (the base).
    pub floor_z: f64,
    /// Where the carving is centred, slice by slice ([`Carving::of`]).
    pub carving: Carving,
    /// Hull voxels ([`voxel_key`]) of objects leaning on the rim, within the carved region: what lies
    /// in them (or next to them) is theirs and is not carved.
    #[serde(skip)]
    pub others: HashSet<[i64; 3]>,
}

/// The voxel of the grid of pitch [`VOXEL_M`] (aligned with the world origin) that holds `p`.
pub fn voxel_key(p: DVec3) -> [i64; 3] {
    (p / VOXEL_M).floor().as_i64vec3().to_array()
}

impl Opening {
    /// The decision this opening reports in `run.json`'s `vessel_tops`.
    pub fn top(&self) -> Top {
        Top::Open {
            shape: self.shape,
            rim_z: self.rim_z,
            rim_radius: self.rim_radius,
        }
    }

    /// Whether `p` lies in or next to (one voxel) a voxel of [`Opening::others`]; the hull's grid
    /// need not be aligned with [`voxel_key`]'s, which the margin covers.
    fn is_others(&self, p: DVec3) -> bool {
        let [x, y, z] = voxel_key(p);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| (-1..=1).any(|dz| self.others.contains(&[x + dx, y + dy, z + dz])))
        })
    }

    /// Whether `p` lies in the carved region: above the rim within the rim's radius plus a margin,
    /// or above the floor and more than [`WALL_MARGIN_M`] inside the profile; within [`LIP_BAND_M`]
    /// below the rim, more than [`Carving::lip_margin`] inside the slice's own radius as well.
    pub fn carves(&self, p: [f32; 3]) -> bool {
        let p = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        if !self.others.is_empty() && self.is_others(p) {
            return false;
        }
        let Some(k) = self.profile.slice_of(p.z) else {
            return false;
        };
        let k = k.min(self.carving.radius.len() - 1);
        let r = (p.truncate() - self.carving.centre(k)).length();
        if p.z > self.rim_z {
            return r < self.rim_radius + WALL_MARGIN_M && p.z < self.rim_z + 4.0 * self.rim_radius;
        }
        if p.z < self.floor_z {
            return false;
        }
        let wall = self.carving.radius[k] - WALL_MARGIN_M;
        if p.z > self.rim_z - LIP_BAND_M {
            return r < wall.max(self.carving.slice_radius[k] - self.carving.lip_margin(k));
        }
        r < wall
    }
}

/// The carved region's centre line and radius per slice of the [`Profile`].
///
/// The profile's axis is its foot's centre, which decides whether the object stands upright; but a
/// foot's hull is the least reliable part of it (it mixes with what the object stands on, a wine
/// glass's foot is a thin disc that one eroded mask or a camera a little off shifts by millimetres),
/// and an opening carved about an axis a few millimetres off leaves a crescent of the lid on one
/// side. The carving of a hull seen from around it is centred instead on the body it carves: a
/// least-squares line through the slice centres (component-wise medians) of the upper half below the
/// rim, and each slice's radius is measured again about it ([`sector_radius`]). Above the rim the rim
/// slice's centre is kept.
#[derive(Clone, Debug, Serialize)]
pub struct Carving {
    /// Centre of slice 0 and its drift per slice (x, y).
    pub centre0: [f64; 2],
    pub drift: [f64; 2],
    /// Radius per slice about the centre line, up to the rim slice.
    pub radius: Vec<f64>,
    /// Each slice's own radius about the centre line, before the rim window widens the last ones.
    pub slice_radius: Vec<f64>,
}

impl Carving {
    /// The carving of the hull `voxels` whose profile's rim is slice `rim`.
    pub fn of(voxels: &[DVec3], profile: &Profile, rim: usize) -> Self {
        let mut by_slice: Vec<Vec<DVec2>> = vec![Vec::new(); rim + 1];
        for p in voxels {
            if let Some(k) = profile.slice_of(p.z).filter(|&k| k <= rim) {
                by_slice[k].push(p.truncate());
            }
        }
        let centres: Vec<(f64, DVec2)> = (rim / 2..=rim)
            .filter_map(|k| median_point(&by_slice[k]).map(|c| (k as f64, c)))
            .collect();
        let (centre0, drift) =
            line_fit(&centres).unwrap_or((DVec2::from_array(profile.axis), DVec2::ZERO));
        let centre = |k: usize| centre0 + drift * k as f64;
        let mut radius: Vec<f64> = by_slice
            .iter()
            .enumerate()
            .map(|(k, s)| {
                if s.is_empty() {
                    0.0
                } else {
                    sector_radius(s, centre(k))
                }
            })
            .collect();
        // The roof of a few views starts shallow at its edge and narrows the last slices below the
        // rim (see `RIM_WINDOW`): they are carved as wide as the widest of them.
        let slice_radius = radius.clone();
        let window = rim.saturating_sub(RIM_WINDOW)..=rim;
        let rim_radius = radius[window.clone()].iter().fold(0.0f64, |a, &b| a.max(b));
        for r in &mut radius[window] {
            *r = rim_radius;
        }
        Self {
            centre0: centre0.to_array(),
            drift: drift.to_array(),
            radius,
            slice_radius,
        }
    }

    /// The carving about the profile's own axis, with the profile's radii. From one side (a narrow
    /// baseline) the hull stretches behind the object over the table it hides, so its slices' centres
    /// lie behind the axis; the profile's axis was read from their fronts instead.
    pub fn about_axis(profile: &Profile, rim: usize) -> Self {
        Self {
            centre0: profile.axis,
            drift: [0.0, 0.0],
            radius: profile.radius[..=rim].to_vec(),
            slice_radius: profile.radius[..=rim].to_vec(),
        }
    }

    /// Radial margin for the wall at slice `k` of the lip: a wall [`LIP_WALL_M`] thick whose radius
    /// changes by `dr` per slice of height `h` is `LIP_WALL_M·√(1 + (dr/h)²)` wide across, and the
    /// slice itself spans `|dr|`, so a bowl's flare keeps about the body's margin. `dr` is the central
    /// difference of [`Carving::slice_radius`] (one-sided at the ends; the body's margin for a single
    /// slice). Hull noise of a voxel between slices reads as slope and only widens the margin.
    pub fn lip_margin(&self, k: usize) -> f64 {
        let n = self.slice_radius.len();
        let (lo, hi) = (k.saturating_sub(1), (k + 1).min(n - 1));
        if hi == lo {
            return WALL_MARGIN_M;
        }
        let dr = (self.slice_radius[hi] - self.slice_radius[lo]).abs() / (hi - lo) as f64;
        LIP_WALL_M * (1.0 + (dr / VOXEL_M).powi(2)).sqrt() + dr
    }

    /// Centre of slice `k` (the rim slice's above the rim).
    pub fn centre(&self, k: usize) -> DVec2 {
        let k = k.min(self.radius.len() - 1) as f64;
        DVec2::from_array(self.centre0) + DVec2::from_array(self.drift) * k
    }
}

/// Least-squares line `c(k) = c0 + k d` through `(k, centre)` pairs; a single pair gives no drift.
fn line_fit(pts: &[(f64, DVec2)]) -> Option<(DVec2, DVec2)> {
    let n = pts.len() as f64;
    if pts.is_empty() {
        return None;
    }
    let mk = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let mc = pts.iter().fold(DVec2::ZERO, |a, p| a + p.1) / n;
    let skk: f64 = pts.iter().map(|p| (p.0 - mk).powi(2)).sum();
    let d = if skk > 0.0 {
        pts.iter()
            .fold(DVec2::ZERO, |a, p| a + (p.1 - mc) * (p.0 - mk))
            / skk
    } else {
        DVec2::ZERO
    };
    Some((mc - d * mk, d))
}

/// What [`classify`] decided for one object.
#[derive(Clone, Debug, Serialize)]
pub struct VesselTop {
    pub object_id: u16,
    pub voxels: usize,
    /// The opening was found from the given poses and kept where the settled poses' hull closed it,
    /// for this reason (see `reconstruct::retake_openings`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub from_given_poses: Option<Closed>,
    /// The settled poses' hull opened it as this shape, and the given poses' read a round top: it
    /// stays closed (see `reconstruct::retake_openings`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub opened_when_settled: Option<Shape>,
    /// The given poses opened it, the settled poses closed it, and the hull carving had taken from
    /// it was filled with surfels again ([`crate::refill`]).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub refilled: bool,
    #[serde(flatten)]
    pub top: Top,
}

impl VesselTop {
    /// One object's decision as [`classify`] reads it from one hull, before any retake marks it.
    pub fn new(object_id: u16, voxels: usize, top: Top) -> Self {
        Self {
            object_id,
            voxels,
            from_given_poses: None,
            opened_when_settled: None,
            refilled: false,
            top,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
#[serde(tag = "top", rename_all = "snake_case")]
pub enum Top {
    Open {
        shape: Shape,
        rim_z: f64,
        rim_radius: f64,
    },
    Closed {
        because: Closed,
    },
}

/// Steepest elevation of the cameras over the point `at` (radians).
pub fn max_elevation(cameras: &[Camera], at: DVec3) -> f64 {
    cameras
        .iter()
        .map(|c| {
            let d = c.center() - at;
            (d.z / d.length()).asin()
        })
        .fold(0.0, f64::max)
}

/// Decides, for every object of the hull, whether its top is an opening; returns the openings and the
/// decision per object (for `run.json`). `ceiling` is the top of the box the hull was searched in.
pub fn classify(
    hull: &BTreeMap<u16, Vec<DVec3>>,
    cameras: &[Camera],
    ceiling: f64,
    baseline: Baseline,
) -> (Vec<Opening>, Vec<VesselTop>) {
    let mut openings = Vec::new();
    let mut report = Vec::new();
    for (&id, voxels) in hull {
        let top = match open_top(id, voxels, hull, cameras, ceiling, baseline) {
            Ok(o) => {
                let t = o.top();
                openings.push(o);
                t
            }
            Err(because) => Top::Closed { because },
        };
        report.push(VesselTop::new(id, voxels.len(), top));
    }
    (openings, report)
}

/// The vessels whose opening is carved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Shape {
    /// Walls within [`MAX_TAPER_M`] of the rim's radius, at least [`MIN_ASPECT`] radii high: tumblers,
    /// mugs (the sectors' lower quartile ignores the handle).
    Straight,
    /// Widest at the rim, flaring from its foot by at least [`MIN_BOWL_FLARE`], with a crown of at
    /// most [`MAX_BOWL_CROWN`].
    Bowl,
    /// A cup on a stem: below the widest slice the profile narrows to under [`MAX_STEM_RATIO`] of it,
    /// and the rim is at least [`MIN_CUP_RIM_RATIO`] of the widest (wine glasses).
    Stemmed,
}

/// Which open vessel the profile below the rim slice `rim` is, or why it is closed.
fn vessel_shape(
    profile: &Profile,
    rim: usize,
    rim_radius: f64,
    crown_limit: f64,
) -> Result<Shape, Closed> {
    let r = &profile.radius[..=rim];
    // The cup's widest slice, in the upper half (a wine glass's foot may be as wide as its bowl).
    let half = r.len() / 2;
    let (widest_at, widest) =
        r[half..].iter().enumerate().fold(
            (half, 0.0f64),
            |a, (k, &v)| if v > a.1 { (half + k, v) } else { a },
        );
    let above_foot = (0.15 * widest_at as f64) as usize;
    let waist = r[above_foot..widest_at.max(above_foot + 1)]
        .iter()
        .fold(f64::INFINITY, |a, &b| a.min(b));
    if waist < MAX_STEM_RATIO * widest {
        return if rim_radius >= MIN_CUP_RIM_RATIO * widest {
            Ok(Shape::Stemmed)
        } else {
            Err(Closed::NarrowTop)
        };
    }
    let upper_widest = r[(0.4 * rim as f64) as usize..]
        .iter()
        .fold(0.0f64, |a, &b| a.max(b));
    if rim_radius + RIM_TOLERANCE_M < upper_widest {
        return Err(Closed::NarrowTop);
    }
    // The whole wall above the base's rounding: a sphere's hull is a barrel over most of its height.
    // Or, for a tall vessel, the wall above its lowest [`HIDDEN_FOOT`]: there the hull narrows where
    // the vessel's foot is hidden (its labels go to an object in front, or it stands on a support
    // whose top takes its label), as a sphere's hull narrows, but a sphere's rim stands only about
    // 1.5 radii high.
    let rim_height = (rim + 1) as f64 * VOXEL_M;
    let wall_from = |f: f64| {
        r[(f * rim as f64) as usize..]
            .iter()
            .fold(f64::INFINITY, |a, &b| a.min(b))
    };
    let straight = |f: f64, aspect: f64| {
        wall_from(f) >= rim_radius - MAX_TAPER_M && rim_height >= aspect * rim_radius
    };
    if straight(0.1, MIN_ASPECT) || straight(HIDDEN_FOOT, MIN_HIDDEN_FOOT_ASPECT) {
        Ok(Shape::Straight)
    } else if profile.crown() > crown_limit {
        Err(Closed::RoundTop)
    } else if rim_radius < MIN_BOWL_FLARE * foot_radius(r) {
        Err(Closed::NoFlare)
    } else {
        Ok(Shape::Bowl)
    }
}

/// The top of what the vessel stands on: the highest hull voxel, inside the rim's circle, of another
/// object centred under the vessel (its voxels there average within [`MAX_LEANER_OFFSET`] rim radii of
/// the axis) that reaches as low as the vessel's hull (to within a voxel) and ends below the rim. A
/// stacked vessel's hull continues into its support as a cone (the masks cannot tell where one ends),
/// so its wall seems to start below the support's top; carving from there would take the support's
/// top and the vessel's own bottom away. `None` on the table: a neighbour's or a leaning object's
/// voxels in the circle lie off-centre, an object nested inside does not reach below the vessel.
fn support_top(
    hull: &BTreeMap<u16, Vec<DVec3>>,
    id: u16,
    profile: &Profile,
    axis: DVec2,
    rim: (f64, f64),
) -> Option<f64> {
    let (rim_z, rim_radius) = rim;
    hull.iter()
        .filter(|(o, _)| **o != id)
        .filter_map(|(_, vs)| {
            let (under, placement) = in_rim_circle(vs, axis, rim_radius, |_| true)?;
            let lowest = under.iter().fold(f64::INFINITY, |a, p| a.min(p.z));
            let top = under.iter().fold(f64::NEG_INFINITY, |a, p| a.max(p.z)) + 0.5 * VOXEL_M;
            (placement == Placement::Centred
                && lowest <= profile.z0 + VOXEL_M
                && top + FLOOR_M < rim_z)
                .then_some(top)
        })
        .reduce(f64::max)
}

/// The top of another object that object `id` (its hull `voxels`) stands on, if any. Read before
/// the profile, from the voxels only: `id`'s footprint is the circle of its upper body (the
/// [`sector_radius`] about the median of its voxels between half and four fifths of its height),
/// and a support is another object whose voxels fill at least [`SUPPORT_FILL`] of that circle in
/// some slice at least [`RAISED_M`] above `id`'s lowest voxel and [`MIN_BODY_M`] below its top,
/// where `id`'s hull reaches down to the table (within [`RAISED_M`]) around its support, which
/// the raised rule of [`wide_axis`] cannot see. Its highest such slice is
/// the support's top. Label noise and a neighbour's flank fill far less of it.
pub fn support_under(id: u16, voxels: &[DVec3], hull: &BTreeMap<u16, Vec<DVec3>>) -> Option<f64> {
    let (low, high) = voxels
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.z), hi.max(p.z))
        });
    // A hull that starts above the table is judged by the raised rule instead (see [`wide_axis`]).
    if low > RAISED_M {
        return None;
    }
    let upper: Vec<DVec2> = voxels
        .iter()
        .filter(|p| p.z >= low + 0.5 * (high - low) && p.z <= low + 0.8 * (high - low))
        .map(|p| p.truncate())
        .collect();
    let centre = median_point(&upper)?;
    let radius = sector_radius(&upper, centre);
    let fill = SUPPORT_FILL * std::f64::consts::PI * (radius / VOXEL_M).powi(2);
    hull.iter()
        .filter(|(o, _)| **o != id)
        .filter_map(|(_, vs)| {
            let mut counts: BTreeMap<i64, usize> = BTreeMap::new();
            for p in vs
                .iter()
                .filter(|p| (p.truncate() - centre).length() < radius)
            {
                *counts.entry((p.z / VOXEL_M).floor() as i64).or_default() += 1;
            }
            let (k, _) = counts.iter().rev().find(|(_, n)| **n as f64 >= fill)?;
            let top = (*k + 1) as f64 * VOXEL_M;
            (top + MIN_BODY_M <= high && top >= low + RAISED_M).then_some(top)
        })
        .reduce(f64::max)
}

/// Where another object's voxels inside a rim's circle lie, seen from above.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Placement {
    /// Their mean is within [`MAX_LEANER_OFFSET`] rim radii of the vessel's axis.
    Centred,
    OffCentre,
}

/// The voxels of `vs` that `keep` accepts inside the rim's circle (horizontal distance to `axis`
/// below `rim_radius`), and where they lie, when there are more than a few (a stray voxel or two
/// come from label noise at occlusions).
fn in_rim_circle(
    vs: &[DVec3],
    axis: DVec2,
    rim_radius: f64,
    keep: impl Fn(&DVec3) -> bool,
) -> Option<(Vec<DVec3>, Placement)> {
    let inside: Vec<DVec3> = vs
        .iter()
        .filter(|p| keep(p) && (p.truncate() - axis).length() < rim_radius)
        .copied()
        .collect();
    if inside.len() <= MIN_VOXELS / 4 {
        return None;
    }
    let centre = inside.iter().fold(DVec2::ZERO, |a, p| a + p.truncate()) / inside.len() as f64;
    let placement = if (centre - axis).length() < MAX_LEANER_OFFSET * rim_radius {
        Placement::Centred
    } else {
        Placement::OffCentre
    };
    Some((inside, placement))
}

/// The voxels of the objects that lean on the rim (`rim_z`, `rim_radius`) of object `id` from
/// outside: those with more than a few voxels above the rim inside its circle, off-centre; their
/// voxels near the rim are kept out of the carving. An object centred over the opening stands on
/// the vessel, or the "vessel" is an upturned one carrying it: [`Closed::Supports`].
fn leaning_voxels(
    hull: &BTreeMap<u16, Vec<DVec3>>,
    id: u16,
    axis: DVec2,
    rim_z: f64,
    rim_radius: f64,
) -> Result<Vec<DVec3>, Closed> {
    let mut leaning = Vec::new();
    for (_, vs) in hull.iter().filter(|(o, _)| **o != id) {
        let Some((_, placement)) = in_rim_circle(vs, axis, rim_radius, |p| p.z > rim_z) else {
            continue;
        };
        if placement == Placement::Centred {
            return Err(Closed::Supports);
        }
        leaning.extend(vs.iter().filter(|p| {
            (p.truncate() - axis).length() < rim_radius + 2.0 * WALL_MARGIN_M
                && p.z < rim_z + 4.0 * rim_radius
        }));
    }
    Ok(leaning)
}

/// The lowest slice of `r` (a straight vessel's profile up to its rim slice `rim`) within
/// [`RIM_TOLERANCE_M`] of the narrowest slice of its wall above [`HIDDEN_FOOT`].
fn wall_start(r: &[f64], rim: usize) -> usize {
    let wall = r[(HIDDEN_FOOT * rim as f64) as usize..]
        .iter()
        .fold(f64::INFINITY, |a, &b| a.min(b));
    r.iter()
        .position(|&v| v >= wall - RIM_TOLERANCE_M)
        .unwrap_or(0)
}

/// Widest radius of the lowest fifth of the slices `r`.
fn foot_radius(r: &[f64]) -> f64 {
    r[..r.len().div_ceil(5)]
        .iter()
        .fold(0.0f64, |a, &b| a.max(b))
}

/// The opening of object `id`, or why it has none.
fn open_top(
    id: u16,
    voxels: &[DVec3],
    hull: &BTreeMap<u16, Vec<DVec3>>,
    cameras: &[Camera],
    ceiling: f64,
    baseline: Baseline,
) -> Result<Opening, Closed> {
    let base = support_under(id, voxels, hull);
    let profile = Profile::standing_on(voxels, baseline, base).ok_or(Closed::TooSmall)?;
    if profile.slice_top(profile.radius.len() - 1) > ceiling - VOXEL_M {
        return Err(Closed::Truncated);
    }
    if profile.lean > MAX_LEAN {
        return Err(Closed::Leaning);
    }
    let axis = DVec2::from_array(profile.axis);
    let centre = axis.extend(profile.z0 + 0.5 * profile.radius.len() as f64 * VOXEL_M);
    let elevation = max_elevation(cameras, centre).max(0.1);
    let rim = profile.rim_slice(0.5 / elevation.tan());
    // The widest of the last 10 mm below the roof: the roof of a few views starts shallow at its edge.
    let rim_radius = profile.radius[rim.saturating_sub(RIM_WINDOW)..=rim]
        .iter()
        .fold(0.0f64, |a, &b| a.max(b));
    if rim_radius < MIN_RIM_RADIUS_M {
        return Err(Closed::NarrowTop);
    }
    if profile.elongation > MAX_ELONGATION {
        return Err(Closed::NotRound);
    }
    // The bowl's crown is its roof's height over its radius (see [`MAX_BOWL_CROWN`]).
    let crown_limit = MAX_BOWL_CROWN + (baseline.roof_rise() - 1.0) * elevation.tan();
    let shape = vessel_shape(&profile, rim, rim_radius, crown_limit)?;
    let rim_z = profile.slice_top(rim);
    // Above a flat rim the hull is only the roof, at most `R tan e` high (the silhouette planes meet
    // over the axis); a bottle's shoulder is followed by a neck that stands higher.
    let above = profile.neck_top().saturating_sub(rim) as f64 * VOXEL_M;
    if above > ROOF_SLACK * rim_radius * baseline.roof_rise() * elevation.tan() + 2.0 * VOXEL_M {
        return Err(Closed::NarrowTop);
    }
    // Another object resting above the rim: centred, the top is closed; leaning on the rim from
    // outside, the opening is carved around it.
    let leaning = leaning_voxels(hull, id, axis, rim_z, rim_radius)?;
    // A straight vessel's base is where its wall starts: below, a hidden foot's hull may be its
    // support's top, which is not carved.
    let base = match shape {
        Shape::Straight => wall_start(&profile.radius[..=rim], rim),
        Shape::Bowl | Shape::Stemmed => 0,
    };
    let floor_z = profile.slice_top(base) - VOXEL_M + FLOOR_M;
    let floor_z = support_top(hull, id, &profile, axis, (rim_z, rim_radius))
        .map_or(floor_z, |top| floor_z.max(top + FLOOR_M));
    let carving = match baseline {
        Baseline::Wide => Carving::of(voxels, &profile, rim),
        Baseline::Narrow { .. } => Carving::about_axis(&profile, rim),
    };
    Ok(Opening {
        shape,
        carving,
        others: leaning.iter().map(|p| voxel_key(*p)).collect(),
        floor_z,
        rim_z,
        rim_radius,
        profile,
    })
}
