//! The t = 0 reconstruction: targets → initial surfels → optimisation → object surfels.
//!
//! Methods (the paper's rows): [`Method::Trand`] (object-aware 2DGS with masks, Dice and the
//! object-aware 3D loss), [`Method::NoObjectLoss`] (the loss ablation) and [`Method::Plain2dgs`] (the
//! 2DGS baseline on whole photographs, no masks, no object channels used).
//!
//! Initialisation ([`InitMode`]): the authors' random slab (100k points), or — trand's default, chosen
//! by measurement (BENCHMARKS.md) — the same slab samples carved by the training masks (a visual hull):
//! points that project onto an object pixel in every training view that sees them. Surfels that start
//! outside every object cost time and are pruned anyway, since the masked targets are black there.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use rand::SeedableRng;
use rand_pcg::Pcg64;
use trand_core::{Surfels, math::softmax};
use trand_io::{Sequence, TrainSelection, View, ViewCount, select_train_views};
use trand_train::config::{Activation, TrainConfig};
use trand_train::init::{InitConfig, SlabBox, random_init, slab_points, surfels_from_points};

use crate::associate::{Association, Identity, associate};
use crate::checkpoint::{Checkpoint, Snapshot};
use crate::front_fill::{self, FrontFill};
use crate::mask_agreement::MaskAgreement;
use crate::missed_masks::{self, MissedFill, MissedMasks, RedrawReport, Redrawn};
use crate::openings::overhang::{OverhangRule, Overhangs};
use crate::openings::{Baseline, Closed, Opening, Top, VesselTop};
use crate::refill;
use crate::support::{Support, SupportPrior};
use crate::table_align::{self, TableAlign, TableAlignment};
use crate::table_height::{self, MIN_TABLE_SHIFT_M, TableLevel};
use crate::targets::{self, CoarseViews, Supervision, TrainView};
use crate::trainer::{StepReport, Trainer, camera_extent};
use crate::{PipelineError, Result};

/// Which of the paper's methods to run.
///
/// The plain 2DGS baseline is written `plain2dgs` in `config.toml` and `run.json` (the name runs have
/// always recorded) and is also read as `plain-2dgs`, the name the command line, `trand bench` and
/// the README use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    Trand,
    NoObjectLoss,
    #[serde(alias = "plain-2dgs")]
    #[cfg_attr(feature = "clap", value(name = "plain2dgs", alias = "plain-2dgs"))]
    Plain2dgs,
}

impl Method {
    pub fn supervision(self) -> Supervision {
        match self {
            Method::Plain2dgs => Supervision::FullImage,
            _ => Supervision::ObjectAware,
        }
    }
}

/// How the initial surfels are placed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum InitMode {
    /// The authors' random slab (points in the volume and on the four side faces).
    Slab,
    /// Slab samples (volume only, taller box) kept where every training mask that sees them is an object.
    VisualHull,
}

/// What is done about the tops of open vessels (see [`crate::openings`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum OpeningPrior {
    /// Surfels are kept out of the opening of every object the hull shows to be an upright
    /// straight-walled vessel, so that its inside is fitted instead of a lid.
    Carve,
    /// No prior: the masks' visual hull decides (a lid forms over every opening).
    Off,
}

/// Everything a reconstruction needs besides the data.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReconstructOptions {
    pub method: Method,
    pub views: u32,
    /// Integer image downsampling for training (1 = native resolution).
    pub downsample: u32,
    pub init_mode: InitMode,
    pub init: InitConfig,
    pub openings: OpeningPrior,
    /// Whether the training masks' instance ids name the same object in every view.
    pub identity: Identity,
    /// The table-support restriction of the visual hull (see [`crate::support`]).
    pub support: SupportPrior,
    /// Whether holes in an object's front are filled after training (see [`crate::front_fill`]).
    pub front_fill: FrontFill,
    /// Whether the training cameras are first aligned on the table's texture (see
    /// [`crate::table_align`]).
    pub table_align: TableAlign,
    /// When surfels overhanging an opening's lip are carved with it (see
    /// [`crate::openings::overhang`]).
    pub overhangs: OverhangRule,
    /// Which cameras the masks a segmenter missed are drawn in through (see [`crate::missed_masks`]).
    pub missed_masks: MissedMasks,
    /// How the losses supervise the pixels drawn in for a missed mask (see [`crate::missed_masks`]).
    pub missed_fill: MissedFill,
    pub train: TrainConfig,
    /// Object channels K (background included).
    pub num_objects: usize,
}

impl Default for ReconstructOptions {
    fn default() -> Self {
        Self {
            method: Method::Trand,
            views: 6,
            downsample: 1,
            init_mode: InitMode::VisualHull,
            init: InitConfig::default(),
            openings: OpeningPrior::Carve,
            identity: Identity::Auto,
            support: SupportPrior::Auto,
            front_fill: FrontFill::HullFront,
            table_align: TableAlign::Texture,
            overhangs: OverhangRule::Carve,
            missed_masks: MissedMasks::CorrectedCameras,
            missed_fill: MissedFill::Unknown,
            train: TrainConfig::default(),
            num_objects: trand_core::DEFAULT_NUM_OBJECTS,
        }
    }
}

/// The most initial points (slab volume + 4 faces) accepted: fifty times the authors' 100k.
pub const MAX_INIT_POINTS: usize = 5_000_000;

/// The largest training downsampling factor.
pub const MAX_DOWNSAMPLE: u32 = 64;

impl ReconstructOptions {
    /// Checks every range before any work (the error names the key): views, downsampling, the
    /// object-channel count, the initial point count (with overflow-checked arithmetic) and the
    /// training configuration.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(PipelineError::Invalid(format!("invalid option {m}")));
        view_count(self.views)?;
        if self.downsample == 0 || self.downsample > MAX_DOWNSAMPLE {
            return bad(format!(
                "`downsample` = {}: must be 1 to {MAX_DOWNSAMPLE}",
                self.downsample
            ));
        }
        let kmax = trand_core::MAX_NUM_OBJECTS;
        if self.num_objects < 2 || self.num_objects > kmax {
            return bad(format!(
                "`num_objects` (--objects) = {}: must be 2 to {kmax} (background included)",
                self.num_objects
            ));
        }
        let points = self
            .init
            .num_per_face
            .checked_mul(4)
            .and_then(|f| f.checked_add(self.init.num_volume));
        if points.is_none_or(|n| n > MAX_INIT_POINTS) {
            return bad(format!(
                "`init.num_volume` + 4 × `init.num_per_face` = {} + 4 × {}: at most {MAX_INIT_POINTS}",
                self.init.num_volume, self.init.num_per_face
            ));
        }
        if !(self.init.opacity > 0.0 && self.init.opacity < 1.0) {
            return bad(format!(
                "`init.opacity` = {}: must lie in (0, 1)",
                self.init.opacity
            ));
        }
        if !self.init.grey.is_finite() {
            return bad(format!("`init.grey` = {}: not finite", self.init.grey));
        }
        self.train.validate()?;
        Ok(())
    }
}

/// Result of a reconstruction.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    /// The surfels kept at the end (object surfels, or all of them for plain 2DGS).
    pub surfels: Surfels,
    /// Surfel count before the object filter (the front fill's surfels included).
    pub num_trained: usize,
    /// `(object id, channel)`.
    pub channels: Vec<(u16, usize)>,
    pub train_views: Vec<String>,
    pub preprocess_s: f64,
    /// Training and the front fill after it.
    pub optimise_s: f64,
    /// `(iteration, loss)` of every iteration.
    pub curve: Vec<(u32, f32)>,
    pub initial_surfels: usize,
    /// The opening prior's decision per object (empty when it is off).
    pub vessel_tops: Vec<VesselTop>,
    /// Whether the visual hull was restricted by the support prior.
    pub support_applied: bool,
    /// How the training masks' ids were taken.
    pub identity: IdentityReport,
    /// The training masks grown to meet their photograph's edge.
    pub grown_to_image_edges: Vec<EdgeGrowth>,
    /// Whether the opening prior was decided again with the settled pose corrections.
    pub openings_retaken: bool,
    /// How well the training masks agree (measured when the opening prior applies), and whether
    /// surfels overhanging an opening's lip were carved for it ([`crate::openings::overhang`]).
    pub mask_agreement: Option<MaskAgreement>,
    pub overhangs: Overhangs,
    /// Surfels [`crate::front_fill`] added (0 when it is off or not applied).
    pub front_fill_added: usize,
    /// The pose refinement the run used (fixed for a narrow baseline, whatever was asked for).
    pub pose_refinement: trand_train::PoseRefinement,
    /// Each training view's pose correction (zero when the poses were fixed), `train_views` order.
    pub poses: trand_train::PoseCorrections,
    /// The table's height seen through the cameras after training, and how far the frame was moved
    /// for it (never with the poses fixed).
    pub table: TableLevel,
    /// The training cameras' alignment on the table before training, `None` where it was not tried.
    pub table_alignment: Option<TableAlignment>,
    /// Missed masks drawn again through corrected cameras ([`crate::missed_masks`]), `None` where
    /// none were.
    pub missed_masks: Option<RedrawReport>,
}

impl Reconstruction {
    /// Per training view: name, the correction's rotation (degrees) and translation (millimetres).
    pub fn pose_report(&self) -> Vec<serde_json::Value> {
        self.train_views
            .iter()
            .zip(self.poses.magnitudes())
            .zip(&self.poses.xi)
            .map(|((name, (deg, mm)), xi)| {
                serde_json::json!({
                    "view": name,
                    "rotation_deg": deg,
                    "translation_mm": mm,
                    "omega_rad": &xi[..3],
                    "delta_m": &xi[3..],
                })
            })
            .collect()
    }
}

/// The identity rule a reconstruction used, and the association when one was computed.
#[derive(Clone, Debug, serde::Serialize)]
pub struct IdentityReport {
    pub requested: Identity,
    /// `ids` or `overlap`: whether the masks' own ids were trained on.
    pub used: Identity,
    pub association: Option<Association>,
}

fn view_count(n: u32) -> Result<ViewCount> {
    match n {
        3 => Ok(ViewCount::Three),
        6 => Ok(ViewCount::Six),
        12 => Ok(ViewCount::Twelve),
        _ => Err(PipelineError::Invalid(format!(
            "--views must be 3, 6 or 12, not {n}"
        ))),
    }
}

/// `(object id, channel)` pairs.
pub type Channels = Vec<(u16, usize)>;

/// The t = 0 training views with the object channels they are supervised in.
#[derive(Clone, Debug)]
pub struct TrainViews {
    pub views: Vec<TrainView>,
    /// The views at the coarse levels of `opts.train.resolution`.
    pub coarse: Vec<CoarseViews>,
    pub channels: Channels,
    /// How the masks' ids were taken.
    pub identity: IdentityReport,
    /// The masks grown to meet their photograph's edge ([`crate::mask_edges`]).
    pub grown_to_image_edges: Vec<EdgeGrowth>,
}

/// One training mask grown to meet its photograph's edge, in native pixels.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct EdgeGrowth {
    pub view: String,
    pub object_id: u16,
    pub px: usize,
}

/// Builds the training views of t = 0, their channels, and how the masks' ids were taken (see
/// [`Identity`]; with `Auto`, associated only when the ids disagree with the geometry).
pub fn train_views(seq: &Sequence, opts: &ReconstructOptions) -> Result<TrainViews> {
    train_views_associated_through(seq, opts, None)
}

/// [`train_views`], the masks associated through `cameras` (one per training view, in their order)
/// instead of the views' own; the views keep their own.
pub fn train_views_associated_through(
    seq: &Sequence,
    opts: &ReconstructOptions,
    cameras: Option<&[trand_core::Camera]>,
) -> Result<TrainViews> {
    let mut chosen = match seq.train_selection {
        TrainSelection::Ring => select_train_views(&seq.train_t0, view_count(opts.views)?),
        TrainSelection::Listed => seq.train_t0.clone(),
    };
    if chosen.is_empty() {
        return Err(PipelineError::Invalid(format!(
            "{}: no training views at t=0",
            seq.root.display()
        )));
    }
    let sup = opts.method.supervision();
    let no_objects = |v: &View| {
        v.instance
            .as_ref()
            .is_none_or(|m| m.data.iter().all(|&id| id == 0))
    };
    if sup == Supervision::ObjectAware && chosen.iter().all(no_objects) {
        return Err(PipelineError::Invalid(format!(
            "{}: no object pixels in any t=0 training mask (0 is background)",
            seq.root.display()
        )));
    }
    let mut report = IdentityReport {
        requested: opts.identity,
        used: Identity::ObjectIds,
        association: None,
    };
    let mut object_ids = seq.object_ids.clone();
    if sup == Supervision::ObjectAware && opts.identity != Identity::ObjectIds {
        let mut through = chosen.clone();
        if let Some(c) = cameras {
            through.iter_mut().zip(c).for_each(|(v, c)| v.camera = *c);
        }
        let cams: Vec<_> = through.iter().map(|v| v.camera).collect();
        let b = hull_box_for(&cams)?;
        let (assoc, maps) = associate(
            &through,
            glam::DVec3::from_array(b.min),
            glam::DVec3::from_array(b.max),
        )?;
        if opts.identity == Identity::Overlap || assoc.changes_masks() {
            for (v, m) in chosen.iter_mut().zip(maps) {
                v.instance = Some(m);
            }
            object_ids = assoc.objects.clone();
            report.used = Identity::Overlap;
        }
        report.association = Some(assoc);
    }
    let channels = targets::channel_map(&object_ids, opts.num_objects)?;
    let edges: Vec<targets::MaskEdges> = chosen
        .iter()
        .map(|v| targets::MaskEdges::for_view(&opts.train.image_loss, v))
        .collect();
    let build_at = |factor: u32| {
        chosen
            .iter()
            .zip(&edges)
            .map(|(v, e)| {
                targets::build(
                    v,
                    &channels,
                    opts.num_objects,
                    opts.train.background,
                    sup,
                    (factor, e),
                )
            })
            .collect::<Result<Vec<_>>>()
    };
    let views = build_at(opts.downsample)?;
    let native = chosen
        .iter()
        .filter_map(|v| v.rgb.as_ref().map(|i| (i.width, i.height)))
        .fold((u32::MAX, u32::MAX), |a, b| (a.0.min(b.0), a.1.min(b.1)));
    let coarse = targets::coarse_views(&opts.train.resolution, opts.downsample, native, build_at)?;
    let grown_to_image_edges = chosen
        .iter()
        .zip(&edges)
        .flat_map(|(v, e)| {
            e.to_image_edge
                .iter()
                .filter(|g| g.1 > 0)
                .map(|&(object_id, px)| EdgeGrowth {
                    view: v.name.clone(),
                    object_id,
                    px,
                })
        })
        .collect();
    Ok(TrainViews {
        views,
        coarse,
        channels,
        identity: report,
        grown_to_image_edges,
    })
}

/// The box the visual hull is searched in: under the cameras' focus, tall enough for stacked
/// glassware (half the box's half-width).
pub fn hull_box(views: &[TrainView]) -> Result<SlabBox> {
    box_of_height(views, 0.5)
}

/// [`hull_box`] with its height `fraction` of the box's half-width.
fn box_of_height(views: &[TrainView], fraction: f64) -> Result<SlabBox> {
    let cams: Vec<_> = views.iter().map(|v| v.camera).collect();
    box_of_height_for(&cams, fraction)
}

/// [`hull_box`] of the cameras `cams`.
fn hull_box_for(cams: &[trand_core::Camera]) -> Result<SlabBox> {
    box_of_height_for(cams, 0.5)
}

/// The box under the cameras' focus with its height `fraction` of its half-width.
fn box_of_height_for(cams: &[trand_core::Camera], fraction: f64) -> Result<SlabBox> {
    let mut b = SlabBox::from_cameras(cams, 0.6, 0.2)?;
    b.max[2] = fraction * (b.max[0] - b.min[0]) * 0.5;
    Ok(b)
}

/// The box the opening prior's hull is searched in: twice as tall as [`hull_box`], so that an
/// object standing on another is seen whole (its top decides whether it is open).
pub fn openings_box(views: &[TrainView]) -> Result<SlabBox> {
    box_of_height(views, 1.0)
}

/// The openings of the training masks' vessels, with the decision per object.
pub fn find_openings(
    views: &[TrainView],
    opts: &ReconstructOptions,
) -> Result<(Vec<Opening>, Vec<VesselTop>)> {
    if opts.openings == OpeningPrior::Off || opts.method.supervision() != Supervision::ObjectAware {
        return Ok((Vec::new(), Vec::new()));
    }
    let b = openings_box(views)?;
    let (hull, baseline) = openings_hull(views, opts, &b)?;
    let cams: Vec<_> = views.iter().map(|v| v.camera).collect();
    Ok(crate::openings::classify(&hull, &cams, b.max[2], baseline))
}

/// The opening prior decided again from `settled` views (the training views with the settled pose
/// corrections), given the decision from the given poses. An opening the given poses found is kept
/// where the settled poses' hull closes it as leaning, narrow or not flaring: errors destroy a rim
/// under a roof more easily than they make one. A pose error blurs the rims, which the settled poses
/// restore; boundary errors move the settled cameras instead, and can tip an upright bowl or wine
/// glass over the lean limit or widen its hull's foot past the flare limit. A round top is the
/// exception: pose errors flatten a spheroid's dome into a bowl's crown far more often than they
/// raise an open bowl's crown into a dome, so where either hull reads one the object stays closed,
/// and where the settled poses' does, what carving took from it is refilled ([`crate::refill`]).
/// A hull the given poses read as not flaring (an upturned bowl) keeps the object closed as well
/// (BENCHMARKS.md §8 counts both ways).
fn retake_openings(
    given: Vec<Opening>,
    given_tops: Vec<VesselTop>,
    settled: &[TrainView],
    opts: &ReconstructOptions,
) -> Result<(Vec<Opening>, Vec<VesselTop>)> {
    let (openings, tops) = find_openings(settled, opts)?;
    Ok(keep_given_openings(
        given,
        &given_tops,
        openings,
        tops,
        Opening::top,
    ))
}

/// The settled decision (`openings` in the order of the open `tops`, as
/// [`crate::openings::classify`] gives them) with every object it closes but the given decision opened
/// opened as the given one was (`top_of` its opening's report), unless it closes it as a round top,
/// and every object it opens but the given decision read as a round top or as not flaring closed.
fn keep_given_openings<O>(
    given: Vec<O>,
    given_tops: &[VesselTop],
    openings: Vec<O>,
    tops: Vec<VesselTop>,
    top_of: impl Fn(&O) -> Top,
) -> (Vec<O>, Vec<VesselTop>) {
    let mut given_open: BTreeMap<u16, O> = given_tops
        .iter()
        .filter(|t| matches!(t.top, Top::Open { .. }))
        .map(|t| t.object_id)
        .zip(given)
        .collect();
    let given_round: BTreeMap<u16, Closed> = given_tops
        .iter()
        .filter_map(|t| match t.top {
            Top::Closed {
                because: because @ (Closed::RoundTop | Closed::NoFlare),
            } => Some((t.object_id, because)),
            _ => None,
        })
        .collect();
    let mut settled_open = openings.into_iter();
    let mut out = (Vec::new(), Vec::new());
    for mut t in tops {
        match t.top {
            // Either pose set's round top closes the object: the given poses' dome, flattened by
            // the settled cameras and eroded masks, can pass for a bowl's crown as well. Where the
            // given poses' hull does not flare, the given reading stands too.
            Top::Open { shape, .. } if given_round.contains_key(&t.object_id) => {
                settled_open.next();
                t.top = Top::Closed {
                    because: given_round[&t.object_id],
                };
                t.opened_when_settled = Some(shape);
            }
            Top::Open { .. } => out.0.extend(settled_open.next()),
            // A round top is the closed reading errors rarely make of an open vessel: they tip rims
            // into leaning or narrow tops, blur a bowl's flare away, and flatten domes into bowls.
            Top::Closed { because } if because != Closed::RoundTop => {
                if let Some(o) = given_open.remove(&t.object_id) {
                    t.top = top_of(&o);
                    t.from_given_poses = Some(because);
                    out.0.push(o);
                }
            }
            Top::Closed { .. } => {}
        }
        out.1.push(t);
    }
    out
}

/// The labelled hull the opening prior reads, in `b` (the [`openings_box`]), and where its views
/// look from: on a narrow baseline (the support prior applied) the hull keeps the support prior's
/// points.
pub fn openings_hull(
    views: &[TrainView],
    opts: &ReconstructOptions,
    b: &SlabBox,
) -> Result<(ObjectHull, Baseline)> {
    let (min, max) = (
        glam::DVec3::from_array(b.min),
        glam::DVec3::from_array(b.max),
    );
    Ok(match support_test(views, opts)? {
        Some(support) => {
            let cams: Vec<_> = views.iter().map(|v| v.camera).collect();
            (
                crate::openings::object_voxels_where(views, min, max, |p| support.holds(p)),
                Baseline::Narrow {
                    toward: mean_heading(&cams, 0.5 * (min + max)),
                },
            )
        }
        None => (
            crate::openings::object_voxels(views, min, max),
            Baseline::Wide,
        ),
    })
}

/// Hull voxel centres per object id ([`crate::openings::object_voxels`]).
pub type ObjectHull = std::collections::BTreeMap<u16, Vec<glam::DVec3>>;

/// The horizontal unit direction the cameras look along towards `target`, averaged.
fn mean_heading(cams: &[trand_core::Camera], target: glam::DVec3) -> glam::DVec2 {
    cams.iter()
        .filter_map(|c| (target - c.center()).truncate().try_normalize())
        .sum::<glam::DVec2>()
        .try_normalize()
        .unwrap_or(glam::DVec2::X)
}

/// The training views with their settled pose corrections, when the corrections settled and move
/// some view's picture of the objects (the corners and centre of the openings box) by more than a hull
/// voxel: less cannot change the voxel hull the opening prior is decided on, so exact poses keep their
/// first decision. `None` otherwise. A pure function of the settled corrections, so a resumed run
/// decides alike.
fn settled_views(
    views: &[TrainView],
    poses: &trand_train::PoseCorrections,
) -> Result<Option<Vec<TrainView>>> {
    if poses.settled.is_none() {
        return Ok(None);
    }
    let b = openings_box(views)?;
    let pick = |k: usize, bit: usize| if k & bit != 0 { b.max } else { b.min };
    let mut probes: Vec<glam::DVec3> = (0..8)
        .map(|k| glam::DVec3::new(pick(k, 1)[0], pick(k, 2)[1], pick(k, 4)[2]))
        .collect();
    probes.push(glam::DVec3::from_array(b.min).midpoint(glam::DVec3::from_array(b.max)));
    let cameras: Vec<trand_core::Camera> = views
        .iter()
        .enumerate()
        .map(|(i, v)| poses.settled_camera(i, &v.camera).expect("settled"))
        .collect();
    let moved = views.iter().zip(&cameras).any(|(v, c)| {
        probes
            .iter()
            .any(|&p| shift_m(&v.camera, c, p) > crate::openings::VOXEL_M)
    });
    // The views (images included) are copied only when the decision is retaken.
    Ok(moved.then(|| {
        views
            .iter()
            .zip(cameras)
            .map(|(v, camera)| TrainView {
                camera,
                ..v.clone()
            })
            .collect()
    }))
}

/// How far `p`'s image moves from camera `a` to camera `b`, in metres at `p`'s depth (0 when either
/// camera does not see it).
fn shift_m(a: &trand_core::Camera, b: &trand_core::Camera, p: glam::DVec3) -> f64 {
    match (a.project(p), b.project(p)) {
        (Some(u), Some(w)) => (u.0 - w.0).hypot(u.1 - w.1) * u.2 / a.intrinsics.fx,
        _ => 0.0,
    }
}

/// Removes the surfels inside any opening (and, with [`Overhangs::Carved`], those whose disc
/// overhangs its lip), with their optimiser state.
fn carve(trainer: &mut Trainer<'_>, openings: &[Opening], overhangs: Overhangs) {
    if openings.is_empty() {
        return;
    }
    let s = &trainer.surfels;
    let keep: Vec<bool> = (0..s.len())
        .map(|i| {
            !openings.iter().any(|o| {
                o.carves(s.means[i])
                    || overhangs == Overhangs::Carved
                        && o.overhangs(s.means[i], s.log_scales[i], s.quats[i])
            })
        })
        .collect();
    if keep.iter().all(|&k| k) {
        return;
    }
    trainer.surfels.retain(&keep);
    trainer.adam.retain(&keep);
    // Carving runs right after densification, when the statistics are zero anyway.
    trainer.stats = trand_train::DensifyStats::new(trainer.surfels.len());
}

/// Adds [`refill::surfels`] for the `closed` openings to the trainer's, with zero optimiser state:
/// hull samples of `views` drawn as for the initial surfels, with a seed of their own.
fn refill_closed(
    trainer: &mut Trainer<'_>,
    views: &[TrainView],
    closed: &[&Opening],
    openings: &[Opening],
    opts: &ReconstructOptions,
) -> Result<()> {
    if closed.is_empty() {
        return Ok(());
    }
    // Salted ("refill" in ASCII) so the samples are not the initial surfels' own.
    let cfg = InitConfig {
        seed: opts.init.seed ^ 0x7265_6669_6c6c,
        ..opts.init.clone()
    };
    let support = support_test(views, opts)?;
    let hull = visual_hull_points(views, &cfg, initial_hull_points(opts), support.as_ref())?;
    let mut rng = Pcg64::seed_from_u64(cfg.seed ^ 0x6875_6c6c);
    let layout = (trainer.surfels.sh_degree, trainer.surfels.num_objects);
    let added = refill::surfels(hull, closed, openings, views, &cfg, layout, &mut rng)?;
    if added.is_empty() {
        return Ok(());
    }
    trainer.surfels.append(&added);
    trainer.adam.append_zeros(added.len());
    // Like carving, refilling follows densification, when the statistics are zero anyway.
    trainer.stats = trand_train::DensifyStats::new(trainer.surfels.len());
    Ok(())
}

/// How many visual-hull samples [`initial_surfels`] starts from.
fn initial_hull_points(opts: &ReconstructOptions) -> usize {
    (opts.init.num_volume + 4 * opts.init.num_per_face) / 5
}

/// Slab samples carved by the masks (see the module docs).
fn visual_hull_points(
    views: &[TrainView],
    cfg: &InitConfig,
    target: usize,
    support: Option<&Support<'_>>,
) -> Result<Vec<[f32; 3]>> {
    let b = hull_box(views)?;
    let mut rng = Pcg64::seed_from_u64(cfg.seed);
    let inside = |p: [f32; 3]| {
        in_visual_hull(
            views,
            support,
            glam::DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64),
        )
    };
    let mut kept = Vec::with_capacity(target);
    // Draw in batches until enough points survive (or a budget of samples is spent).
    for _ in 0..200 {
        let batch = slab_points(&b, 20_000, 0, &mut rng);
        kept.extend(batch.into_iter().filter(|&p| inside(p)));
        if kept.len() >= target {
            break;
        }
    }
    kept.truncate(target);
    if kept.len() < 100 {
        return Err(PipelineError::Invalid(
            "the visual hull of the training masks is (nearly) empty: are the masks and poses consistent? \
             (try --init slab)"
                .into(),
        ));
    }
    Ok(kept)
}

/// Whether `q` projects onto an object pixel in every view that sees it, and at least two do (and
/// passes the support prior's test, where it applies).
fn in_visual_hull(views: &[TrainView], support: Option<&Support<'_>>, q: glam::DVec3) -> bool {
    if support.is_some_and(|s| !s.holds(q)) {
        return false;
    }
    targets::in_hull_of(views, q, |v| &v.ids)
}

/// The surfels [`front_fill::fill`] adds to `surfels` trained from `views` with `poses`: the views at
/// their corrected cameras, the visual hull they carve without the openings.
fn front_fill_surfels(
    surfels: &Surfels,
    views: &[TrainView],
    poses: &trand_train::PoseCorrections,
    openings: &[Opening],
    cfg: &TrainConfig,
) -> Result<Surfels> {
    let trained: Vec<TrainView> = views
        .iter()
        .enumerate()
        .map(|(i, v)| TrainView {
            camera: poses.camera(i, &v.camera),
            ..v.clone()
        })
        .collect();
    let settings = trand_render::RenderSettings {
        background: cfg.background,
        near: cfg.near as f64,
        sh_degree: Some(cfg.sh_degree),
        ..Default::default()
    };
    let hull = CarvedHull {
        views: &trained,
        openings,
    };
    front_fill::fill(surfels, &trained, &settings, &hull)
}

/// The visual hull of `views` and the openings carved from it, as [`front_fill`] reads them.
struct CarvedHull<'a> {
    views: &'a [TrainView],
    openings: &'a [Opening],
}

/// How far under an opening's rim the hull's band counts as its rim (see [`front_fill::Hull::at_rim`]).
const RIM_BAND_M: f64 = 0.005;

impl front_fill::Hull for CarvedHull<'_> {
    fn holds(&self, p: glam::DVec3, c: u8) -> bool {
        in_visual_hull(self.views, None, p)
            && self
                .views
                .iter()
                .filter(|v| v.pixel_of(p).is_some_and(|o| v.labels[o] == c))
                .count()
                >= 2
    }

    fn carved(&self, p: glam::DVec3) -> bool {
        let q = [p.x as f32, p.y as f32, p.z as f32];
        self.openings.iter().any(|o| o.carves(q))
    }

    fn at_rim(&self, p: glam::DVec3) -> bool {
        self.openings.iter().any(|o| {
            let lifted = [p.x as f32, p.y as f32, (o.rim_z + 0.001).max(p.z) as f32];
            p.z > o.rim_z - RIM_BAND_M && o.carves(lifted)
        })
    }
}

/// The support prior's test for these views, when [`ReconstructOptions::support`] applies to them.
pub fn support_test<'a>(
    views: &'a [TrainView],
    opts: &ReconstructOptions,
) -> Result<Option<Support<'a>>> {
    let b = hull_box(views)?;
    let centre = glam::DVec3::new(
        0.5 * (b.min[0] + b.max[0]),
        0.5 * (b.min[1] + b.max[1]),
        0.0,
    );
    Ok(Support::new(views, opts.support, centre))
}

/// Initial surfels for the chosen [`InitMode`].
pub fn initial_surfels(views: &[TrainView], opts: &ReconstructOptions) -> Result<Surfels> {
    let cams: Vec<_> = views.iter().map(|v| v.camera).collect();
    let k = opts.num_objects;
    let deg = opts.train.sh_degree;
    match (opts.init_mode, opts.method.supervision()) {
        (InitMode::VisualHull, Supervision::ObjectAware) => {
            let support = support_test(views, opts)?;
            let pts = visual_hull_points(
                views,
                &opts.init,
                initial_hull_points(opts),
                support.as_ref(),
            )?;
            let mut rng = Pcg64::seed_from_u64(opts.init.seed ^ 0x6875_6c6c);
            Ok(surfels_from_points(pts, &opts.init, deg, k, &mut rng)?)
        }
        _ => Ok(random_init(&opts.init, &cams, deg, k)?),
    }
}

/// TRAN-D keeps the object surfels only: some object channel above ½, background below ½, above the table.
pub fn object_filter(s: &Surfels) -> Vec<bool> {
    let k = s.num_objects;
    let mut p = vec![0.0f32; k];
    (0..s.len())
        .map(|i| {
            softmax(&s.obj_logits[i * k..(i + 1) * k], &mut p);
            p[0] < 0.5 && p[1..].iter().any(|&v| v > 0.5) && s.means[i][2] > 0.0
        })
        .collect()
}

/// Runs the t = 0 reconstruction. `on_step` sees every iteration; setting `cancel` stops after the
/// current iteration with [`PipelineError::Interrupted`] (the caller keeps its last checkpoint).
/// `start` continues from given surfels at an iteration with a fresh optimiser; for an exact resume
/// use [`reconstruct_from`].
pub fn reconstruct(
    seq: &Sequence,
    opts: &ReconstructOptions,
    start: Option<(Surfels, u32)>,
    on_step: &mut dyn FnMut(&StepReport, &Surfels),
    cancel: &AtomicBool,
) -> Result<Reconstruction> {
    let start = match start {
        Some((s, it)) => Start::Surfels(s, it),
        None => Start::Init,
    };
    reconstruct_from(
        seq,
        opts,
        start,
        &mut |r, snap| on_step(r, snap.surfels),
        cancel,
    )
}

/// Where [`reconstruct_from`] starts.
// Built once per run and moved, never stored in bulk: the size of `Surfels` (a few vectors' headers)
// is not worth a box.
#[allow(clippy::large_enum_variant)]
pub enum Start {
    /// From the initialisation ([`InitMode`]).
    Init,
    /// From these surfels after this iteration, with a fresh optimiser and sampler.
    Surfels(Surfels, u32),
    /// Exactly where a checkpoint left off: refused unless it was made from the same training views
    /// and options.
    Resume(Box<Checkpoint>),
}

/// A fingerprint of the training views as trained on (names, cameras, target images and labels):
/// FNV-1a over their bytes, so a checkpoint made from another sequence, other views or another
/// downsampling is recognised even where the cameras coincide.
pub fn training_fingerprint(views: &[TrainView]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for v in views {
        eat(v.name.as_bytes());
        let c = &v.camera;
        let k = &c.intrinsics;
        for x in [k.fx, k.fy, k.cx, k.cy]
            .iter()
            .chain(c.r_w2c.iter().flatten())
            .chain(&c.t_w2c)
        {
            eat(&x.to_le_bytes());
        }
        eat(&(v.width as u64).to_le_bytes());
        eat(&(v.height as u64).to_le_bytes());
        for x in v.rgb.iter().chain(&v.mask) {
            eat(&x.to_le_bytes());
        }
        eat(&v.labels);
        for id in &v.ids {
            eat(&id.to_le_bytes());
        }
    }
    format!("{h:016x}")
}

/// Checks that a checkpoint belongs to this run and fits its shapes.
fn check_resume(
    c: &Checkpoint,
    fingerprint: &str,
    options: &str,
    opts: &ReconstructOptions,
    num_views: usize,
    last: u32,
) -> Result<()> {
    let bad = |m: String| Err(PipelineError::Invalid(format!("checkpoint refused: {m}")));
    if c.fingerprint != fingerprint {
        return bad(format!(
            "it was made from other training views (fingerprint {} ≠ {fingerprint}: another sequence, view count or downsampling)",
            c.fingerprint
        ));
    }
    if c.options != options {
        let diff = c
            .options
            .lines()
            .zip(options.lines())
            .find(|(a, b)| a != b)
            .map_or_else(
                || "a key is missing on one side".to_string(),
                |(a, b)| format!("checkpoint `{a}`, this run `{b}`"),
            );
        return bad(format!(
            "it was made with other options ({diff}); resume with the same options"
        ));
    }
    if c.iteration < opts.train.start_iteration || c.iteration > last {
        return bad(format!(
            "its iteration {} is outside this run's {}..{last}",
            c.iteration, opts.train.start_iteration
        ));
    }
    let s = &c.surfels;
    if (s.sh_degree, s.num_objects) != (opts.train.sh_degree, opts.num_objects) {
        return bad(format!(
            "its surfels have SH degree {} and {} object channels, the run {} and {}",
            s.sh_degree, s.num_objects, opts.train.sh_degree, opts.num_objects
        ));
    }
    let mut seen = vec![false; num_views];
    for &v in &c.stack {
        if v >= num_views || std::mem::replace(&mut seen[v], true) {
            return bad(format!(
                "its view stack {:?} does not fit {num_views} views",
                c.stack
            ));
        }
    }
    c.poses
        .validate(num_views)
        .map_err(|e| PipelineError::Invalid(format!("checkpoint refused: {e}")))?;
    for m in [&c.adam.m, &c.adam.v] {
        m.validate().map_err(|e| {
            PipelineError::Invalid(format!("checkpoint refused: Adam moments: {e}"))
        })?;
    }
    Ok(())
}

/// [`reconstruct`] from any [`Start`]; `on_step` sees the whole loop state after every iteration
/// (write it with [`Snapshot::write`] to checkpoint). A run resumed from a checkpoint of iteration
/// `i` gives the same bits as the uninterrupted run.
pub fn reconstruct_from(
    seq: &Sequence,
    opts: &ReconstructOptions,
    start: Start,
    on_step: &mut dyn FnMut(&StepReport, &Snapshot<'_>),
    cancel: &AtomicBool,
) -> Result<Reconstruction> {
    opts.validate()?;
    let t0 = Instant::now();
    let mut tv = train_views(seq, opts)?;
    let support_applied = opts.init_mode == InitMode::VisualHull
        && opts.method.supervision() == Supervision::ObjectAware
        && support_test(&tv.views, opts)?.is_some();
    let table_alignment = align_on_table(&mut tv.views, &mut tv.coarse, opts, support_applied);
    let missed_masks = match start {
        Start::Surfels(..) => None,
        _ => redraw_missed_masks(
            seq,
            opts,
            &mut tv,
            table_alignment.as_ref(),
            support_applied,
            cancel,
        )?,
    };
    if opts.missed_fill == MissedFill::Unknown {
        leave_drawn_unknown(&mut tv);
    }
    let TrainViews {
        views,
        coarse,
        channels,
        identity,
        grown_to_image_edges,
    } = tv;
    let (mut openings, mut vessel_tops) = find_openings(&views, opts)?;
    let (mask_agreement, overhangs) = overhang_decision(&views, opts)?;
    let mut cfg = train_config(opts);
    let fingerprint = training_fingerprint(&views);
    let options = toml::to_string(opts)
        .map_err(|e| PipelineError::Invalid(format!("serialising the options: {e}")))?;
    let last = cfg.start_iteration + cfg.iterations;
    let (surfels, first, resume) = match start {
        Start::Init => (
            initial_surfels(&views, opts)?,
            cfg.start_iteration + 1,
            None,
        ),
        Start::Surfels(s, it) => (s, it + 1, None),
        Start::Resume(c) => {
            check_resume(&c, &fingerprint, &options, opts, views.len(), last)?;
            let c = *c;
            (
                c.surfels,
                c.iteration + 1,
                Some((
                    c.adam,
                    c.stats,
                    c.rng,
                    c.stack,
                    c.poses,
                    c.curve,
                    c.initial_surfels,
                )),
            )
        }
    };
    // A narrow baseline (the support prior's case) leaves the depth to parallax of a few pixels
    // between the views, which images reduced 2-4x do not resolve: such runs train at the training
    // resolution throughout (the real keypose capture's keypoints: within 0.77 cm, against 1.15 cm
    // with the coarse levels).
    let coarse = if support_applied { Vec::new() } else { coarse };
    // For the same reason the poses stay as given there: a correction of a fraction of a pixel trades
    // directly against that parallax (the keypose keypoints: 1.04 cm off with the poses refined).
    if support_applied {
        cfg.pose = trand_train::PoseRefinement::Fixed;
    }
    let extent = camera_extent(&views.iter().map(|v| v.camera).collect::<Vec<_>>());
    let preprocess_s = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let mut initial = surfels.len();
    let mut trainer =
        Trainer::new(surfels, cfg, &views, extent, opts.method.supervision()).with_coarse(&coarse);
    let mut curve = Vec::new();
    let mut openings_retaken = false;
    match resume {
        Some((adam, stats, rng, stack, poses, c, init)) => {
            trainer.restore(adam, stats, rng, stack);
            trainer.poses = poses;
            if let Some(v) = settled_views(&views, &trainer.poses)? {
                let (given, given_tops) = (openings, vessel_tops);
                (openings, vessel_tops) =
                    retake_openings(given.clone(), given_tops.clone(), &v, opts)?;
                // The checkpoint holds the surfels refilled already: only the report is marked.
                refill::closed_openings(&given, &given_tops, &mut vessel_tops);
                openings_retaken = true;
            }
            curve = c;
            initial = init;
        }
        None => carve(&mut trainer, &openings, overhangs),
    }
    for it in first..=last {
        let rep = trainer.step(it, it == last)?;
        if rep.densified {
            // The opening prior was decided from the given poses; once the corrections settle it is
            // decided again from the corrected ones (half a degree off, the hull loses the rims).
            if trainer.poses.settled.is_none() && trainer.cfg.pose.settled(it) {
                trainer.poses.settle();
                if let Some(v) = settled_views(&views, &trainer.poses)? {
                    let (given, given_tops) = (openings, vessel_tops);
                    (openings, vessel_tops) =
                        retake_openings(given.clone(), given_tops.clone(), &v, opts)?;
                    let closed = refill::closed_openings(&given, &given_tops, &mut vessel_tops);
                    refill_closed(&mut trainer, &v, &closed, &openings, opts)?;
                    openings_retaken = true;
                }
            }
            carve(&mut trainer, &openings, overhangs);
        }
        curve.push((it, rep.loss));
        let (rng, stack) = trainer.sampler();
        let snap = Snapshot {
            iteration: it,
            surfels: &trainer.surfels,
            adam: &trainer.adam,
            stats: &trainer.stats,
            rng,
            stack,
            poses: &trainer.poses,
            curve: &curve,
            initial_surfels: initial,
            fingerprint: &fingerprint,
            options: &options,
        };
        on_step(&rep, &snap);
        if cancel.load(Ordering::SeqCst) && it < last {
            return Err(PipelineError::Interrupted(it));
        }
        if trainer.cfg.early_stop.stops(&curve) {
            break;
        }
    }
    let mut poses = trainer.poses;
    let pose_refinement = trainer.cfg.pose;
    let mut surfels = trainer.surfels;
    let mut front_fill_added = 0;
    // Where the support prior applies (a narrow baseline, by default) the hull reaches far in front
    // of the objects: no fill. With the prior forced off, a narrow baseline is filled like any other
    // and the pit rule (`front_fill` module docs) keeps the fronts near the trained depth. The
    // ablations with object supervision are filled too: the fill reads only the object channels.
    if opts.front_fill == FrontFill::HullFront
        && opts.method.supervision() == Supervision::ObjectAware
        && !support_applied
    {
        let added = front_fill_surfels(&surfels, &views, &poses, &openings, &trainer.cfg)?;
        front_fill_added = added.len();
        surfels.append(&added);
    }
    let table = level_table(&mut surfels, &mut poses, &views, pose_refinement);
    let optimise_s = t1.elapsed().as_secs_f64();
    let num_trained = surfels.len();
    if opts.method.supervision() == Supervision::ObjectAware {
        let keep = object_filter(&surfels);
        surfels.retain(&keep);
    }
    Ok(Reconstruction {
        surfels,
        num_trained,
        channels,
        train_views: views.iter().map(|v| v.name.clone()).collect(),
        preprocess_s,
        optimise_s,
        curve,
        initial_surfels: initial,
        vessel_tops,
        identity,
        grown_to_image_edges,
        support_applied,
        openings_retaken,
        mask_agreement,
        overhangs,
        front_fill_added,
        pose_refinement,
        poses,
        table,
        table_alignment,
        missed_masks,
    })
}

/// [`missed_masks`]: where the association filled a mask a segmenter missed, `tv` rebuilt with the masks
/// associated again through corrected cameras (the table-aligned ones, or a first pass's), its views
/// keeping their own cameras (aligned by `alignment` where it was kept).
fn redraw_missed_masks(
    seq: &Sequence,
    opts: &ReconstructOptions,
    tv: &mut TrainViews,
    alignment: Option<&TableAlignment>,
    support_applied: bool,
    cancel: &AtomicBool,
) -> Result<Option<RedrawReport>> {
    let filled = |tv: &TrainViews| {
        tv.identity
            .association
            .as_ref()
            .map_or_else(Vec::new, Association::drawn)
    };
    let filled_given = filled(tv);
    let aligned = alignment.is_some_and(|a| a.kept);
    let refined = opts.train.pose.refines();
    let through =
        missed_masks::redraw_through(opts.missed_masks, aligned, refined, support_applied);
    let (Some(through), false) = (through, filled_given.is_empty()) else {
        return Ok(None);
    };
    let corrections = match through {
        Redrawn::TableAligned => Vec::new(),
        Redrawn::FirstPass => first_pass(tv, opts, cancel)?,
    };
    let cameras: Vec<trand_core::Camera> = tv
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| match corrections.get(i) {
            Some(x) => trand_train::pose::corrected(*x, &v.camera),
            None => v.camera,
        })
        .collect();
    let mut redrawn = train_views_associated_through(seq, opts, Some(&cameras))?;
    if let Some(a) = alignment {
        a.apply(&mut redrawn.views, &mut redrawn.coarse);
    }
    let filled_corrected = filled(&redrawn);
    *tv = redrawn;
    Ok(Some(RedrawReport {
        through,
        corrections,
        filled_given,
        filled_corrected,
    }))
}

/// [`MissedFill::Unknown`]: the pixels the association drew in for missed masks leave the losses at
/// every level ([`missed_masks::leave_unknown`]).
fn leave_drawn_unknown(tv: &mut TrainViews) {
    let Some(drawn) = tv.identity.association.as_ref().map(Association::drawn) else {
        return;
    };
    missed_masks::leave_unknown(&mut tv.views, &drawn);
    for level in &mut tv.coarse {
        missed_masks::leave_unknown(&mut level.views, &drawn);
    }
}

/// How well `views`' masks agree (measured where the opening prior applies) and the overhang rule
/// it decides. No opening prior (or no object-aware supervision): nothing is carved, overhangs
/// neither.
fn overhang_decision(
    views: &[TrainView],
    opts: &ReconstructOptions,
) -> Result<(Option<MaskAgreement>, Overhangs)> {
    let agreement = match opts.openings {
        OpeningPrior::Carve if opts.method.supervision() == Supervision::ObjectAware => {
            Some(crate::mask_agreement::measure(views, &openings_box(views)?))
        }
        _ => None,
    };
    let overhangs = match &agreement {
        Some(m) => opts.overhangs.decide(m.disagree()),
        None => Overhangs::Kept,
    };
    Ok((agreement, overhangs))
}

/// The training configuration of `opts`' method: without the object-aware 3D loss but for TRAN-D's.
fn train_config(opts: &ReconstructOptions) -> TrainConfig {
    let mut cfg = opts.train.clone();
    if opts.method != Method::Trand {
        cfg.object_loss.active = Activation::Never;
    }
    cfg
}

/// [`missed_masks`]'s first pass: the run's first iterations, up to the corrections' settling, trained
/// from the initial surfels and carved as the run itself would; each view's correction then.
fn first_pass(
    tv: &TrainViews,
    opts: &ReconstructOptions,
    cancel: &AtomicBool,
) -> Result<Vec<[f64; 6]>> {
    let cfg = train_config(opts);
    let trand_train::PoseRefinement::Refine { settled_at, .. } = cfg.pose else {
        return Ok(vec![[0.0; 6]; tv.views.len()]);
    };
    let (openings, _) = find_openings(&tv.views, opts)?;
    let (_, overhangs) = overhang_decision(&tv.views, opts)?;
    let views = &tv.views;
    let extent = camera_extent(&views.iter().map(|v| v.camera).collect::<Vec<_>>());
    let until = settled_at.min(cfg.iterations);
    let mut trainer = Trainer::new(
        initial_surfels(views, opts)?,
        cfg,
        views,
        extent,
        opts.method.supervision(),
    )
    .with_coarse(&tv.coarse);
    let mut cut = |t: &mut Trainer<'_>| carve(t, &openings, overhangs);
    cut(&mut trainer);
    missed_masks::train_until(trainer, until, &mut cut, cancel)
}

/// The training views' cameras aligned on the table ([`table_align`]) where `opts` ask for it, the
/// poses are refined and the support prior (a narrow baseline, whose poses stay as given) does not
/// apply; every level's views get the same correction. `None` where it was not tried.
fn align_on_table(
    views: &mut [TrainView],
    coarse: &mut [CoarseViews],
    opts: &ReconstructOptions,
    support_applied: bool,
) -> Option<TableAlignment> {
    let refined = opts.train.pose.refines();
    if opts.table_align == TableAlign::Off || !refined || support_applied {
        return None;
    }
    let alignment = table_align::align(views)?;
    alignment.apply(views, coarse);
    Some(alignment)
}

/// After training: the table's height seen through the (corrected) cameras ([`table_height`]).
/// With refined poses, where its texture or its shading shows it at least [`MIN_TABLE_SHIFT_M`] off
/// z = 0 ([`table_height::TableFit::reading`]), the frame is moved towards it by the reading's
/// [`table_height::TableFit::share`] of that height: cameras and surfels together, so no training
/// image changes. The surfels under the table are dropped after the move ([`object_filter`]).
/// Poses kept as given are the user's: measured only. Done once at the end, so that what training
/// decided (the opening prior above all, whose voxel grid is fixed to the world) is decided as
/// without it, and a resumed run does alike.
fn level_table(
    surfels: &mut Surfels,
    poses: &mut trand_train::PoseCorrections,
    views: &[TrainView],
    refinement: trand_train::PoseRefinement,
) -> TableLevel {
    let cameras: Vec<trand_core::Camera> = views
        .iter()
        .enumerate()
        .map(|(i, v)| poses.camera(i, &v.camera))
        .collect();
    let fit = table_height::measure(views, &cameras);
    let refined = refinement.refines();
    let reading = fit.and_then(|f| f.reading());
    let shift = match fit {
        Some(f) if refined && f.height_m.abs() >= MIN_TABLE_SHIFT_M => f.share() * f.height_m,
        _ => 0.0,
    };
    if shift != 0.0 {
        poses.shift_world([0.0, 0.0, shift]);
        for m in &mut surfels.means {
            m[2] -= shift as f32;
        }
    }
    TableLevel {
        fit,
        reading,
        shifted_m: shift,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::openings::Shape;

    fn top(id: u16, rim_z: Option<f64>) -> VesselTop {
        closed_as(id, rim_z, Closed::Leaning)
    }

    fn closed_as(id: u16, rim_z: Option<f64>, because: Closed) -> VesselTop {
        let top = match rim_z {
            Some(rim_z) => Top::Open {
                shape: Shape::Bowl,
                rim_z,
                rim_radius: 0.05,
            },
            None => Top::Closed { because },
        };
        VesselTop::new(id, 1000, top)
    }

    fn rim(t: &VesselTop) -> Option<f64> {
        match t.top {
            Top::Open { rim_z, .. } => Some(rim_z),
            Top::Closed { .. } => None,
        }
    }

    #[test]
    fn an_opening_either_pose_set_finds_is_kept_and_the_settled_one_wins_where_both_do() {
        // Openings are tagged by their rim height: 0.01·id from the given poses, 0.1·id settled.
        let given_tops = [top(1, Some(0.01)), top(2, Some(0.02)), top(3, None)];
        let settled_tops = vec![
            top(1, None),
            top(2, Some(0.2)),
            top(3, Some(0.3)),
            top(4, None),
        ];
        let (openings, tops) = keep_given_openings(
            vec![0.01, 0.02],
            &given_tops,
            vec![0.2, 0.3],
            settled_tops,
            |&z| top(0, Some(z)).top,
        );
        assert_eq!(openings, vec![0.01, 0.2, 0.3]);
        let rims: Vec<_> = tops.iter().map(rim).collect();
        assert_eq!(rims, vec![Some(0.01), Some(0.2), Some(0.3), None]);
        let kept: Vec<_> = tops.iter().map(|t| t.from_given_poses).collect();
        assert_eq!(kept, vec![Some(Closed::Leaning), None, None, None]);
    }

    #[test]
    fn a_round_top_the_settled_poses_see_closes_an_opening_the_given_poses_found() {
        let given_tops = [top(1, Some(0.01)), top(2, Some(0.02))];
        let settled_tops = vec![top(1, None), closed_as(2, None, Closed::RoundTop)];
        let (openings, tops) = keep_given_openings(
            vec![0.01, 0.02],
            &given_tops,
            Vec::new(),
            settled_tops,
            |&z| top(0, Some(z)).top,
        );
        assert_eq!(openings, vec![0.01]);
        let rims: Vec<_> = tops.iter().map(rim).collect();
        assert_eq!(rims, vec![Some(0.01), None]);
        assert_eq!(tops[0].from_given_poses, Some(Closed::Leaning));
        assert_eq!(tops[1].from_given_poses, None);
    }

    #[test]
    fn a_round_top_the_given_poses_see_keeps_closed_what_the_settled_poses_open() {
        let given_tops = [closed_as(1, None, Closed::RoundTop), top(2, None)];
        let settled_tops = vec![top(1, Some(0.1)), top(2, Some(0.2))];
        let (openings, tops) = keep_given_openings(
            Vec::new(),
            &given_tops,
            vec![0.1, 0.2],
            settled_tops,
            |&z| top(0, Some(z)).top,
        );
        assert_eq!(
            openings,
            vec![0.2],
            "a settled opening stands over a given leaning top"
        );
        let rims: Vec<_> = tops.iter().map(rim).collect();
        assert_eq!(rims, vec![None, Some(0.2)]);
        assert!(matches!(
            tops[0].top,
            Top::Closed {
                because: Closed::RoundTop
            }
        ));
        assert_eq!(tops[0].opened_when_settled, Some(Shape::Bowl));
        assert_eq!(tops[1].opened_when_settled, None);
    }

    #[test]
    fn where_the_pose_sets_disagree_on_the_flare_alone_the_given_reading_stands() {
        // Object 1: a bowl the settled poses' hull no longer sees flare; object 2: a hull the given
        // poses saw narrowing up, which the settled poses open.
        let given_tops = [top(1, Some(0.01)), closed_as(2, None, Closed::NoFlare)];
        let settled_tops = vec![closed_as(1, None, Closed::NoFlare), top(2, Some(0.2))];
        let (openings, tops) =
            keep_given_openings(vec![0.01], &given_tops, vec![0.2], settled_tops, |&z| {
                top(0, Some(z)).top
            });
        assert_eq!(openings, vec![0.01]);
        assert_eq!(tops[0].from_given_poses, Some(Closed::NoFlare));
        assert!(matches!(
            tops[1].top,
            Top::Closed {
                because: Closed::NoFlare
            }
        ));
        assert_eq!(tops[1].opened_when_settled, Some(Shape::Bowl));
    }

    /// `level_table` on six views of a table `height` below z = 0: where one surfel ends up, the
    /// move, and how the height was read.
    fn levelled(
        paint: fn(f64, f64) -> f32,
        pose: trand_train::PoseRefinement,
    ) -> (f32, TableLevel) {
        let height = -0.004;
        let views = crate::table_height::painted::views_of_table(height, paint);
        let mut surfels = Surfels::new(0, 2).expect("surfels");
        surfels.push(&trand_core::surfels::Surfel {
            mean: [0.0, 0.0, 0.05],
            log_scale: [-5.0, -5.0],
            quat: [1.0, 0.0, 0.0, 0.0],
            opacity_logit: 0.0,
            sh_dc: [0.0; 3],
            mask_dc: [0.0; 3],
            obj_logits: Vec::new(),
        });
        let mut poses = trand_train::PoseCorrections::new(views.len());
        let level = level_table(&mut surfels, &mut poses, &views, pose);
        (surfels.means[0][2], level)
    }

    #[test]
    fn a_refined_frame_moves_onto_a_textured_table_and_half_way_to_a_plain_one() {
        use crate::table_height::{BROAD_SHARE, Reading, painted};
        let refine = trand_train::PoseRefinement::refine();
        for (paint, reading, share) in [
            (
                painted::speckle as fn(f64, f64) -> f32,
                Reading::Textured,
                1.0,
            ),
            (painted::soft_shadows, Reading::Broad, BROAD_SHARE),
        ] {
            let (z, level) = levelled(paint, refine);
            let h = level.fit.expect("the views see the table").height_m;
            assert!((h + 0.004).abs() < 1e-3, "{level:?}");
            assert_eq!(level.reading, Some(reading));
            assert_eq!(level.shifted_m, share * h);
            assert!(
                (f64::from(z) - (0.05 - share * h)).abs() < 1e-6,
                "surfel at {z}"
            );
        }
        let (z, fixed) = levelled(painted::soft_shadows, trand_train::PoseRefinement::Fixed);
        assert_eq!(
            (fixed.shifted_m, z),
            (0.0, 0.05),
            "poses kept as given are not moved"
        );
    }
}
