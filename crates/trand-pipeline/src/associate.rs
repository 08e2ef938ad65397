//! Instance association across the t = 0 training views: per-image instance ids made consistent.
//!
//! A segmenter without tracking (SAM, Mask R-CNN, a detector) numbers each image's instances on its
//! own, so id 2 in one view need not be id 2 in the next; it may also split an object in two, merge two,
//! or miss one. TRAN-D's object channels assume one id per object in every view. This module finds
//! that id geometrically, without a network, by letting every mask vote in a shared voxel volume (the
//! idea of Gaga's 3D-aware association, on a visual hull instead of a point cloud):
//!
//! 1. **Voting hull.** Voxels of the cameras' working box are kept when at least two views see them
//!    and every view that sees them, or all but one when three or more do, shows an object there
//!    (one miss or a thin boundary error does not carve an object away). Each kept voxel records
//!    the instance id each view shows at it.
//! 2. **Matching.** Two instances of two views are the same object when the voxels they cover
//!    coincide: their voxel IoU. Every view is tried as the reference; each other view's instances are
//!    assigned to the reference's by the Hungarian method on `1 − IoU` (pairs below
//!    [`MIN_IOU`] are not matched), and the reference with the largest total IoU is kept, so a view
//!    that split, merged or missed objects does not name them. Instances still unmatched after step 3
//!    are matched the same way among themselves, and where two views agree they found an object
//!    the reference did not show ([`found_objects`]).
//! 3. **Consensus.** Every voxel takes the object most of its views' matched instances name, and
//!    each view's instances are matched again (Hungarian, voxel IoU) to the objects as the other
//!    views name them (splatted into the view with a depth test), twice. An instance still unmatched
//!    is an object no other instance of its view stands for when it shows some of it
//!    ([`FREE_SHARE`]: a mostly hidden object shows few pixels, and its rays cross the objects in
//!    front of it; the one its own id names when it shows that one, since a sliver's rays may cross
//!    a missed object in front of it), a piece of an object when most of it shows that object
//!    ([`SPLIT_SHARE`]: a split), and otherwise an object the reference did not show, which founds
//!    a new one.
//! 4. **Merges.** The consensus voxels are splatted into each view with a depth test. An instance
//!    whose pixels show, for at least [`MERGE_SHARE`] of them, an object that no other instance of
//!    the view stands for covers two objects: those pixels are given to that object.
//!
//! 5. **Misses.** An object with no instance in a view whose splatted silhouette there lies mostly
//!    on the view's background ([`MISS_SHARE`], at least [`MIN_MISS_AREA`] of the image) was missed
//!    by the segmenter: those pixels are given to it, an approximation (the hull of the other views
//!    is a little wider than the object) that costs less than a view teaching that the object is
//!    not there, which also carves it out of the visual-hull initialisation.
//!
//! Objects take the reference's ids; new ones their own id when free, else the smallest free id. When
//! every confidently matched instance keeps its id, the ids were consistent ([`Identity::Auto`] then
//! trains on the masks as they are).
//! The confidence of an instance is the voxel IoU of its match (for pieces and new objects, the share
//! of its voxels in the object).

use std::collections::BTreeMap;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;
use trand_core::Camera;
use trand_core::matching::hungarian;
use trand_io::View;

use crate::{PipelineError, Result};

/// Voxels along the working box's longer horizontal side.
pub const GRID: usize = 240;
/// Smallest voxel IoU of two instances taken for the same object.
pub const MIN_IOU: f64 = 0.2;
/// An unmatched instance with at least this share of its voxels in one object is a piece of it.
pub const SPLIT_SHARE: f64 = 0.5;
/// An unmatched instance that shows an object no other instance of its view stands for, on at least
/// this share of its pixels or voxels, is that object (a small, mostly hidden view of it); the
/// unmatched instances and the free objects are paired by the Hungarian method.
pub const FREE_SHARE: f64 = 0.05;
/// A view misses an object when the object has no instance there and at least this share of its
/// splatted silhouette lies on the view's background ...
pub const MISS_SHARE: f64 = 0.5;
/// ... covering at least this share of the image (an object hidden behind others shows less).
pub const MIN_MISS_AREA: f64 = 0.002;
/// Share of an instance's pixels that must show another, otherwise unclaimed, object for a merge.
pub const MERGE_SHARE: f64 = 0.35;

/// Whether instance ids name the same object in every mask, at t = 0 (the training views, see
/// [`associate`]) and at t = 1 (the new mask against the t = 0 objects, see `crate::detect`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Identity {
    /// Trust the ids unless they disagree with the geometry: at t = 0 the training views are
    /// associated only when the association changes an id; at t = 1 the new mask's ids are used
    /// when they are all t = 0 objects, the t = 0 views needed no association, and the rendered
    /// objects do not contradict them.
    Auto,
    /// The ids name the same object in every view (a tracker carried them over; BOP masks are named
    /// by object id). At t = 1 an object whose id is absent was removed.
    #[serde(rename = "ids", alias = "object-ids")]
    #[cfg_attr(feature = "clap", value(name = "ids", alias = "object-ids"))]
    ObjectIds,
    /// Per-image ids: associate by overlap (t = 0: voxel votes; t = 1: IoU and centroid of the
    /// rendered t = 0 objects, Hungarian).
    Overlap,
}

/// What happened to one instance of one view.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Role {
    /// Matched to an object of the reference view (or is one).
    Matched,
    /// A piece of an object another instance of the view also stands for.
    Piece,
    /// An object the reference view does not show.
    New,
    /// Covers an object besides its own; some of its pixels were given to the other.
    Merged,
    /// Shows no object of the hull and no voxel of its own; its pixels take the object the splat
    /// shows most there, if any.
    Unsupported,
}

/// One instance of a view and the object it was found to be.
#[derive(Clone, Debug, Serialize)]
pub struct InstanceMatch {
    pub id: u16,
    pub object: u16,
    pub role: Role,
    pub confidence: f64,
}

/// The association of one view.
#[derive(Clone, Debug, Serialize)]
pub struct ViewAssociation {
    pub view: String,
    pub instances: Vec<InstanceMatch>,
    /// Objects the view's mask missed, drawn in from the hull: `(object, pixels)`.
    pub filled: Vec<(u16, usize)>,
}

/// The association of every training view.
#[derive(Clone, Debug, Serialize)]
pub struct Association {
    /// The view whose instances named the objects.
    pub reference: String,
    /// Object ids after association, sorted.
    pub objects: Vec<u16>,
    /// True when the masks' own ids fit the association (see [`ids_agree`]): `Auto` then trains on
    /// them unchanged.
    pub consistent: bool,
    pub views: Vec<ViewAssociation>,
    /// Smallest instance confidence (1 when there is none).
    pub min_confidence: f64,
}

impl Association {
    /// Whether the relabelled masks differ from the views' own: ids changed, or a missed object
    /// was drawn in.
    pub fn changes_masks(&self) -> bool {
        !self.consistent || self.views.iter().any(|v| !v.filled.is_empty())
    }

    /// Every missed mask drawn in: `(view, object id, pixels)`, in view order.
    pub fn drawn(&self) -> Vec<(String, u16, usize)> {
        self.views
            .iter()
            .flat_map(|v| v.filled.iter().map(|&(id, px)| (v.view.clone(), id, px)))
            .collect()
    }
}

/// Kept voxels of the voting hull with the id each view shows there (0: background or unseen).
struct Hull {
    centres: Vec<DVec3>,
    /// `labels[voxel · views + view]`.
    labels: Vec<u16>,
    /// The view that shows background at the voxel, when one does (the hull tolerates one).
    background: Vec<Option<u8>>,
    views: usize,
    voxel: f64,
}

fn id_at(cam: &Camera, ids: &[u16], w: usize, h: usize, p: DVec3) -> Option<u16> {
    crate::targets::pixel_index(cam, (w, h), p).map(|o| ids[o])
}

/// A kept voxel: centre, the id each view shows, the view that shows background.
type KeptVoxel = (DVec3, Vec<u16>, Option<u8>);

fn voting_hull(views: &[(&Camera, &trand_io::InstanceMap)], min: DVec3, max: DVec3) -> Hull {
    let voxel = (max.x - min.x).max(max.y - min.y) / GRID as f64;
    let n = |k: usize| (((max[k] - min[k]) / voxel).ceil() as usize).max(1);
    let (nx, ny, nz) = (n(0), n(1), n(2));
    let nv = views.len();
    let columns: Vec<Vec<KeptVoxel>> = (0..nx * ny)
        .into_par_iter()
        .map(|c| {
            let (ix, iy) = (c % nx, c / nx);
            (0..nz)
                .filter_map(|iz| {
                    let p = min + (DVec3::new(ix as f64, iy as f64, iz as f64) + 0.5) * voxel;
                    let mut labels = vec![0u16; nv];
                    let (mut seen, mut objects) = (0, 0);
                    let mut background = None;
                    for (v, (cam, inst)) in views.iter().enumerate() {
                        let (w, h) = (inst.width as usize, inst.height as usize);
                        if let Some(id) = id_at(cam, &inst.data, w, h, p) {
                            seen += 1;
                            if id != 0 {
                                objects += 1;
                                labels[v] = id;
                            } else {
                                background = Some(v as u8);
                            }
                        }
                    }
                    let misses = if seen >= 3 { 1 } else { 0 };
                    (seen >= 2 && objects >= 2 && seen - objects <= misses)
                        .then_some((p, labels, background))
                })
                .collect()
        })
        .collect();
    let mut hull = Hull {
        centres: Vec::new(),
        labels: Vec::new(),
        background: Vec::new(),
        views: nv,
        voxel,
    };
    for (p, l, b) in columns.into_iter().flatten() {
        hull.centres.push(p);
        hull.labels.extend(l);
        hull.background.push(b);
    }
    hull
}

/// Per view, its instance ids (sorted) and the voxel count of each.
fn instance_sizes(hull: &Hull, ids: &[Vec<u16>]) -> Vec<Vec<usize>> {
    (0..hull.views)
        .map(|v| {
            let mut n = vec![0usize; ids[v].len()];
            for l in hull.labels.chunks(hull.views) {
                if let Ok(k) = ids[v].binary_search(&l[v]) {
                    n[k] += 1;
                }
            }
            n
        })
        .collect()
}

/// Voxel IoU of every instance of view `a` (rows) with every instance of view `b` (columns).
fn pair_iou(
    hull: &Hull,
    ids: &[Vec<u16>],
    sizes: &[Vec<usize>],
    a: usize,
    b: usize,
) -> Vec<Vec<f64>> {
    let mut inter = vec![vec![0usize; ids[b].len()]; ids[a].len()];
    for l in hull.labels.chunks(hull.views) {
        if let (Ok(i), Ok(j)) = (ids[a].binary_search(&l[a]), ids[b].binary_search(&l[b])) {
            inter[i][j] += 1;
        }
    }
    inter
        .iter()
        .enumerate()
        .map(|(i, row)| {
            row.iter()
                .enumerate()
                .map(|(j, &c)| {
                    let u = sizes[a][i] + sizes[b][j] - c;
                    if u == 0 { 0.0 } else { c as f64 / u as f64 }
                })
                .collect()
        })
        .collect()
}

/// Matches of the instances still unmatched in `map` to those of view `r`: per view and instance,
/// `(instance of r, voxel IoU)`, and the total IoU over the other views.
type Matches = Vec<Vec<Option<(usize, f64)>>>;

fn match_to(
    hull: &Hull,
    ids: &[Vec<u16>],
    sizes: &[Vec<usize>],
    map: &Matches,
    r: usize,
) -> (Matches, f64) {
    let mut total = 0.0;
    let free = |v: usize, k: usize| map[v][k].is_none();
    let out = (0..hull.views)
        .map(|v| {
            let mut m = vec![None; ids[v].len()];
            if v == r || ids[r].is_empty() || ids[v].is_empty() {
                return m;
            }
            let iou = pair_iou(hull, ids, sizes, r, v);
            let cost: Vec<Vec<f64>> = iou
                .iter()
                .enumerate()
                .map(|(i, row)| {
                    row.iter()
                        .enumerate()
                        .map(|(j, x)| {
                            if free(r, i) && free(v, j) {
                                1.0 - x
                            } else {
                                1.0
                            }
                        })
                        .collect()
                })
                .collect();
            for (i, j) in hungarian(&cost).into_iter().enumerate() {
                if let Some(j) = j.filter(|&j| free(r, i) && free(v, j) && iou[i][j] >= MIN_IOU) {
                    m[j] = Some((i, iou[i][j]));
                    total += iou[i][j];
                }
            }
            m
        })
        .collect();
    (out, total)
}

/// Objects founded by reference views, then refined: the view whose unmatched instances the other
/// views' unmatched instances match best names objects for those that are matched, every view is
/// matched again ([`refine`]), and this repeats while two views agree on an object not yet named (an
/// object the first reference did not show). Returns the matches, the names and the first reference.
fn found_objects(
    hull: &Hull,
    ids: &[Vec<u16>],
    sizes: &[Vec<usize>],
    maps: &[(&Camera, &trand_io::InstanceMap)],
) -> (Matches, Vec<u16>, usize) {
    let mut map: Matches = ids.iter().map(|i| vec![None; i.len()]).collect();
    let mut names: Vec<u16> = Vec::new();
    let mut first = None;
    let limit: usize = ids.iter().map(Vec::len).sum();
    while names.len() < limit {
        let (r, (m, total)) = (0..hull.views)
            .map(|r| (r, match_to(hull, ids, sizes, &map, r)))
            .fold(None::<(usize, (Matches, f64))>, |best, cur| match best {
                Some(b) if b.1.1 >= cur.1.1 => Some(b),
                _ => Some(cur),
            })
            .expect("at least one view");
        let founders: Vec<usize> = (0..ids[r].len())
            .filter(|&k| m.iter().flatten().flatten().any(|x| x.0 == k))
            .collect();
        // The first reference names all its instances; later ones those another view confirms.
        let founders: Vec<usize> = if first.is_none() {
            (0..ids[r].len()).collect()
        } else {
            founders
        };
        if founders.is_empty() || (first.is_some() && total <= 0.0) {
            break;
        }
        let unmatched = |m: &Matches| m.iter().flatten().filter(|x| x.is_none()).count();
        let before = (map.clone(), names.len(), unmatched(&map));
        let base = names.len();
        for &k in &founders {
            let id = ids[r][k];
            let name = if names.contains(&id) {
                (1..=u16::MAX)
                    .find(|i| !names.contains(i))
                    .expect("fewer than 65535 objects")
            } else {
                id
            };
            names.push(name);
        }
        for &k in &founders {
            map[r][k] = Some((
                base + founders.iter().position(|&f| f == k).expect("founder"),
                1.0,
            ));
        }
        for (v, row) in m.iter().enumerate() {
            for (j, x) in row.iter().enumerate() {
                if let Some((k, iou)) = x.filter(|x| founders.contains(&x.0)) {
                    map[v][j] = Some((
                        base + founders.iter().position(|&f| f == k).expect("founder"),
                        iou,
                    ));
                }
            }
        }
        for _ in 0..REFINE_ROUNDS {
            map = refine(hull, ids, maps, &map, names.len());
        }
        if first.is_some() && unmatched(&map) >= before.2 {
            // The new objects explain nothing the views agree on: keep the previous matches.
            map = before.0;
            names.truncate(before.1);
            break;
        }
        first.get_or_insert(r);
    }
    (map, names, first.unwrap_or(0))
}

/// Object index a strict majority (and at least two) of each voxel's matched labels name. A voxel
/// one view sees as background is owned only when that view has no instance of the object (it
/// missed it); otherwise it is phantom volume of the tolerant hull.
fn consensus(hull: &Hull, ids: &[Vec<u16>], map: &Matches, objects: usize) -> Vec<Option<usize>> {
    let claimed: Vec<Vec<bool>> = map
        .iter()
        .map(|m| {
            let mut c = vec![false; objects];
            for (g, _) in m.iter().flatten() {
                c[*g] = true;
            }
            c
        })
        .collect();
    hull.labels
        .chunks(hull.views)
        .zip(&hull.background)
        .map(|(l, bg)| {
            let mut votes = vec![0u32; objects];
            for (v, &id) in l.iter().enumerate() {
                if let Some((g, _)) = ids[v].binary_search(&id).ok().and_then(|k| map[v][k]) {
                    votes[g] += 1;
                }
            }
            let best = votes.iter().copied().max().unwrap_or(0);
            let total: u32 = votes.iter().sum();
            // Phantom voxels between objects, seen as different objects from different views, have
            // no majority; left unowned they cannot hide an object behind them.
            let g = (best >= 2 && 2 * best > total)
                .then(|| votes.iter().position(|&c| c == best).expect("max exists"))?;
            match bg {
                Some(v) if claimed[*v as usize][g] => None,
                _ => Some(g),
            }
        })
        .collect()
}

/// Rounds of [`refine`].
const REFINE_ROUNDS: usize = 2;

/// Reassigns every view's instances to the objects, by the Hungarian method on `1 − IoU` of each
/// instance's pixels with each object's silhouette, as the other views' matches name its voxels
/// (leave one view out, so that a view's own mistakes do not vote for themselves), splatted into the
/// view with a depth test. Comparing what the view shows, rather than the voxels along its rays, keeps
/// a large object hidden behind an instance from claiming it.
fn refine(
    hull: &Hull,
    ids: &[Vec<u16>],
    maps: &[(&Camera, &trand_io::InstanceMap)],
    map: &[Vec<Option<(usize, f64)>>],
    objects: usize,
) -> Vec<Vec<Option<(usize, f64)>>> {
    (0..hull.views)
        .map(|v| {
            let mut m = vec![None; ids[v].len()];
            if objects == 0 || ids[v].is_empty() {
                return m;
            }
            let mut others = map.to_vec();
            others[v] = vec![None; ids[v].len()];
            let owner = consensus(hull, ids, &others, objects);
            let (cam, inst) = maps[v];
            let seen = splat(hull, &owner, cam, inst.width as usize, inst.height as usize);
            let mut size = vec![0usize; objects];
            let mut pixels = vec![0usize; ids[v].len()];
            let mut inter = vec![vec![0usize; objects]; ids[v].len()];
            for (&id, o) in inst.data.iter().zip(&seen) {
                if let Some(g) = *o {
                    size[g] += 1;
                }
                if let Ok(k) = ids[v].binary_search(&id) {
                    pixels[k] += 1;
                    if let Some(g) = *o {
                        inter[k][g] += 1;
                    }
                }
            }
            let iou: Vec<Vec<f64>> = inter
                .iter()
                .enumerate()
                .map(|(k, row)| {
                    row.iter()
                        .zip(&size)
                        .map(|(&c, &n)| {
                            let u = pixels[k] + n - c;
                            if u == 0 { 0.0 } else { c as f64 / u as f64 }
                        })
                        .collect()
                })
                .collect();
            let cost: Vec<Vec<f64>> = iou
                .iter()
                .map(|r| r.iter().map(|x| 1.0 - x).collect())
                .collect();
            for (k, g) in hungarian(&cost).into_iter().enumerate() {
                if let Some(g) = g.filter(|&g| iou[k][g] >= MIN_IOU) {
                    m[k] = Some((g, iou[k][g]));
                }
            }
            m
        })
        .collect()
}

/// Object index of the nearest consensus voxel at every pixel of a view (splatted, depth-tested).
fn splat(
    hull: &Hull,
    owner: &[Option<usize>],
    cam: &Camera,
    w: usize,
    h: usize,
) -> Vec<Option<usize>> {
    let mut depth = vec![f64::INFINITY; w * h];
    let mut out = vec![None; w * h];
    let k = &cam.intrinsics;
    for (p, o) in hull.centres.iter().zip(owner) {
        let (Some(o), Some((x, y, z))) = (o, cam.project(*p)) else {
            continue;
        };
        let r = (0.5 * k.fx.max(k.fy) * hull.voxel / z).ceil() as i64;
        let (cx, cy) = (x.round() as i64, y.round() as i64);
        for yy in (cy - r).max(0)..=(cy + r).min(h as i64 - 1) {
            for xx in (cx - r).max(0)..=(cx + r).min(w as i64 - 1) {
                let q = yy as usize * w + xx as usize;
                if z < depth[q] {
                    depth[q] = z;
                    out[q] = Some(*o);
                }
            }
        }
    }
    out
}

/// What an instance of a view shows of each object: in 2D (its pixels where the splatted consensus
/// shows the object) and in 3D (its voxels the object owns).
struct Evidence {
    pixels: usize,
    shown: BTreeMap<usize, usize>,
    voxels: usize,
    owned: BTreeMap<usize, usize>,
    unowned: usize,
}

impl Evidence {
    fn of(
        hull: &Hull,
        owner: &[Option<usize>],
        inst: &trand_io::InstanceMap,
        seen: &[Option<usize>],
        v: usize,
        id: u16,
    ) -> Self {
        let mut e = Evidence {
            pixels: 0,
            shown: BTreeMap::new(),
            voxels: 0,
            owned: BTreeMap::new(),
            unowned: 0,
        };
        for (&i, o) in inst.data.iter().zip(seen) {
            if i == id {
                e.pixels += 1;
                if let Some(o) = o {
                    *e.shown.entry(*o).or_default() += 1;
                }
            }
        }
        for (l, o) in hull.labels.chunks(hull.views).zip(owner) {
            if l[v] == id {
                e.voxels += 1;
                match o {
                    Some(o) => *e.owned.entry(*o).or_default() += 1,
                    None => e.unowned += 1,
                }
            }
        }
        e
    }

    /// The larger of the share of pixels showing `g` and the share of voxels `g` owns.
    fn score(&self, g: usize) -> f64 {
        let share = |m: &BTreeMap<usize, usize>, n: usize| {
            m.get(&g).map_or(0.0, |&c| c as f64 / n.max(1) as f64)
        };
        share(&self.shown, self.pixels).max(share(&self.owned, self.voxels))
    }
}

/// Whether a view's own ids fit its association: every instance matched with confidence keeps its id,
/// and every other one (a piece, a new or unsupported instance) has an id that names an object
/// no matched instance of the view stands for. A mostly hidden sliver that the association could
/// not place does not make consistent ids look per-image.
fn ids_agree(v: &ViewAssociation, names: &[u16]) -> bool {
    v.instances.iter().all(|m| match m.role {
        Role::Matched | Role::Merged => m.id == m.object,
        Role::New if m.id == m.object => true,
        _ => {
            names.contains(&m.id)
                && !v
                    .instances
                    .iter()
                    .any(|o| o.object == m.id && matches!(o.role, Role::Matched | Role::Merged))
        }
    })
}

/// Associates the instances of `views` (all with an instance map) inside the box `min`..`max`.
/// Returns the association and each view's instance map relabelled with object ids.
pub fn associate(
    views: &[View],
    min: DVec3,
    max: DVec3,
) -> Result<(Association, Vec<trand_io::InstanceMap>)> {
    let maps: Vec<(&Camera, &trand_io::InstanceMap)> = views
        .iter()
        .map(|v| {
            v.instance
                .as_ref()
                .map(|m| (&v.camera, m))
                .ok_or_else(|| PipelineError::View {
                    view: v.name.clone(),
                    what: "no instance mask".into(),
                })
        })
        .collect::<Result<_>>()?;
    if views.is_empty() {
        return Err(PipelineError::Invalid("no views to associate".into()));
    }
    let hull = voting_hull(&maps, min, max);
    let ids: Vec<Vec<u16>> = maps.iter().map(|(_, m)| m.ids()).collect();
    let sizes = instance_sizes(&hull, &ids);
    let (mut map, mut names, r) = found_objects(&hull, &ids, &sizes, &maps);
    let mut roles: Vec<Vec<Role>> = map
        .iter()
        .map(|m| m.iter().map(|_| Role::Matched).collect())
        .collect();
    // Unmatched instances: hidden objects, pieces of an object, or new objects.
    let mut owner = consensus(&hull, &ids, &map, names.len());
    for v in 0..views.len() {
        if map[v].iter().all(Option::is_some) {
            continue;
        }
        let (cam, inst) = maps[v];
        let seen = splat(
            &hull,
            &owner,
            cam,
            inst.width as usize,
            inst.height as usize,
        );
        let ev: Vec<Evidence> = (0..ids[v].len())
            .map(|k| Evidence::of(&hull, &owner, inst, &seen, v, ids[v][k]))
            .collect();
        let unmatched: Vec<usize> = (0..ids[v].len()).filter(|&k| map[v][k].is_none()).collect();
        let claimed: Vec<usize> = map[v].iter().flatten().map(|m| m.0).collect();
        let free: Vec<usize> = (0..names.len()).filter(|g| !claimed.contains(g)).collect();
        if !free.is_empty() {
            // Where the instance's own id names a free object it shows, the id decides: a sliver
            // of a mostly hidden object says little about which object it is, and its rays may
            // cross a missed object in front of it.
            let cost: Vec<Vec<f64>> = unmatched
                .iter()
                .map(|&k| {
                    free.iter()
                        .map(|&g| {
                            let sc = ev[k].score(g);
                            if names[g] == ids[v][k] && sc >= FREE_SHARE {
                                -1.0
                            } else {
                                1.0 - sc
                            }
                        })
                        .collect()
                })
                .collect();
            for (row, col) in hungarian(&cost).into_iter().enumerate() {
                let (k, Some(g)) = (unmatched[row], col.map(|c| free[c])) else {
                    continue;
                };
                if ev[k].score(g) >= FREE_SHARE {
                    map[v][k] = Some((g, ev[k].score(g)));
                }
            }
        }
        for k in unmatched {
            if map[v][k].is_some() {
                continue;
            }
            let best =
                (0..names.len())
                    .map(|g| (ev[k].score(g), g))
                    .fold(None::<(f64, usize)>, |b, c| match b {
                        Some(b) if b.0 >= c.0 => Some(b),
                        _ => Some(c),
                    });
            match best {
                Some((sc, g)) if sc >= SPLIT_SHARE => {
                    map[v][k] = Some((g, sc));
                    roles[v][k] = Role::Piece;
                }
                _ if ev[k].unowned == 0 => roles[v][k] = Role::Unsupported,
                _ => {
                    let id = ids[v][k];
                    let name = if names.contains(&id) {
                        (1..=u16::MAX)
                            .find(|i| !names.contains(i))
                            .expect("fewer than 65535 objects")
                    } else {
                        id
                    };
                    names.push(name);
                    let g = names.len() - 1;
                    map[v][k] = Some((g, ev[k].unowned as f64 / ev[k].voxels.max(1) as f64));
                    roles[v][k] = Role::New;
                    for (l, o) in hull.labels.chunks(hull.views).zip(owner.iter_mut()) {
                        if l[v] == id && o.is_none() {
                            *o = Some(g);
                        }
                    }
                }
            }
        }
    }
    owner = consensus(&hull, &ids, &map, names.len());
    // Relabel every view; merges and unsupported instances by the splatted consensus.
    let mut relabelled = Vec::with_capacity(views.len());
    let mut out_views = Vec::with_capacity(views.len());
    for (v, (cam, inst)) in maps.iter().enumerate() {
        let (w, h) = (inst.width as usize, inst.height as usize);
        let seen = splat(&hull, &owner, cam, w, h);
        let claimed: Vec<usize> = map[v].iter().flatten().map(|m| m.0).collect();
        let mut data = vec![0u16; w * h];
        let mut instances = Vec::with_capacity(ids[v].len());
        for (k, &id) in ids[v].iter().enumerate() {
            let pixels: Vec<usize> = (0..w * h).filter(|&p| inst.data[p] == id).collect();
            let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
            for &p in &pixels {
                if let Some(o) = seen[p] {
                    *counts.entry(o).or_default() += 1;
                }
            }
            let own = map[v][k].map(|m| m.0).or_else(|| {
                counts
                    .iter()
                    .max_by_key(|(g, c)| (**c, std::cmp::Reverse(**g)))
                    .map(|(g, _)| *g)
            });
            let others: Vec<usize> = counts
                .iter()
                .filter(|&(g, &c)| {
                    Some(*g) != own
                        && !claimed.contains(g)
                        && c as f64 >= MERGE_SHARE * pixels.len() as f64
                })
                .map(|(g, _)| *g)
                .collect();
            let own = match own {
                Some(g) => g,
                None => {
                    // Nothing in the hull explains it: an object of its own.
                    let name = (1..=u16::MAX)
                        .find(|i| !names.contains(i))
                        .expect("few objects");
                    names.push(name);
                    names.len() - 1
                }
            };
            for &p in &pixels {
                data[p] = match seen[p] {
                    Some(o) if others.contains(&o) => names[o],
                    _ => names[own],
                };
            }
            let role = if others.is_empty() {
                roles[v][k]
            } else {
                Role::Merged
            };
            instances.push(InstanceMatch {
                id,
                object: names[own],
                role,
                confidence: map[v][k].map_or(0.0, |m| m.1),
            });
        }
        // Objects the view shows (the others' hull projects onto its background) but has no
        // instance of: a missed mask, drawn in from the hull so that the view does not teach that
        // the object is absent.
        let mut filled = Vec::new();
        let now_claimed: Vec<usize> = instances
            .iter()
            .filter_map(|m| names.iter().position(|n| *n == m.object))
            .collect();
        for g in (0..names.len()).filter(|g| !now_claimed.contains(g)) {
            let shown: Vec<usize> = (0..w * h).filter(|&p| seen[p] == Some(g)).collect();
            let on_background: Vec<usize> = shown
                .iter()
                .copied()
                .filter(|&p| inst.data[p] == 0)
                .collect();
            if on_background.len() as f64 >= MISS_SHARE * shown.len() as f64
                && on_background.len() as f64 >= MIN_MISS_AREA * (w * h) as f64
            {
                for &p in &on_background {
                    data[p] = names[g];
                }
                filled.push((names[g], on_background.len()));
            }
        }
        relabelled.push(
            trand_io::InstanceMap::from_vec(inst.width, inst.height, 1, data).expect("same size"),
        );
        out_views.push(ViewAssociation {
            view: views[v].name.clone(),
            instances,
            filled,
        });
    }
    let consistent = out_views.iter().all(|v| ids_agree(v, &names));
    let min_confidence = out_views
        .iter()
        .flat_map(|v| v.instances.iter().map(|m| m.confidence))
        .fold(1.0, f64::min);
    let mut objects = names;
    objects.sort_unstable();
    Ok((
        Association {
            reference: views[r].name.clone(),
            objects,
            consistent,
            views: out_views,
            min_confidence,
        },
        relabelled,
    ))
}

#[cfg(test)]
mod tests;
