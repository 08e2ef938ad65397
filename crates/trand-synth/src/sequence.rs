//! `sequence.json`: what was generated and why (field names as in the reference data).

use crate::cameras::RingInfo;
use crate::layout::{Orientation, RelationKind};
use crate::material::Material;
use crate::physics::{PhysicsParams, SettleStats};
use crate::scene::Environment;
use crate::shapes::ShapeKind;
use serde::Serialize;
use std::collections::BTreeMap;

#[derive(Serialize)]
pub struct Sequence {
    pub format: &'static str,
    pub generator: String,
    pub seed: u64,
    pub resolution: Resolution,
    pub intrinsics: IntrinsicsInfo,
    pub units: Units,
    pub depth: &'static str,
    pub mask_visib_naming: &'static str,
    pub states: serde_json::Value,
    pub objects: Vec<ObjectInfo>,
    pub relation_t0: Relation,
    pub removed_obj_id: u32,
    pub removed_obj_kind: ShapeKind,
    pub displacement_t0_to_t1: BTreeMap<String, Displacement>,
    pub workspace_center_m: [f64; 3],
    pub cameras: CamerasInfo,
    pub environment: Environment,
    pub physics: PhysicsInfo,
    pub render: RenderInfo,
}

#[derive(Serialize)]
pub struct Resolution {
    pub width: u32,
    pub height: u32,
}

#[derive(Serialize)]
pub struct IntrinsicsInfo {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    #[serde(rename = "cam_K")]
    pub cam_k: [f64; 9],
    pub convention: &'static str,
}

#[derive(Serialize)]
pub struct Units {
    pub world: &'static str,
    pub poses_t: &'static str,
    pub depth_png: &'static str,
}

#[derive(Serialize)]
pub struct PoseInfo {
    #[serde(rename = "R_m2w")]
    pub r_m2w: [f64; 9],
    pub t_m2w_mm: [f64; 3],
}

#[derive(Serialize)]
pub struct ObjectInfo {
    pub id: u32,
    pub kind: ShapeKind,
    pub transparent: bool,
    pub model: String,
    pub material: Material,
    pub mass_kg: f32,
    pub params_m: ParamsInfo,
    pub initial_mode: Orientation,
    pub pose_t0: PoseInfo,
    pub pose_t1: Option<PoseInfo>,
    pub removed_at_t1: bool,
}

/// An object's dimensions and how it starts (the reference data keeps both in `params_m`).
#[derive(Serialize)]
pub struct ParamsInfo {
    #[serde(flatten)]
    pub dimensions_m: BTreeMap<&'static str, f32>,
    pub initial_mode: Orientation,
}

/// How the supported object of the t = 1 event rests on its support at t = 0.
#[derive(Clone, Serialize)]
pub struct Relation {
    #[serde(rename = "type")]
    pub kind: RelationKind,
    pub support_obj_id: u32,
    pub supported_obj_id: u32,
    /// Signed distance between the collision hulls (negative: they overlap).
    pub contact_distance_mm: f32,
    /// Gap between the render meshes.
    pub mesh_distance_mm: f32,
    pub supported_min_z_mm: f32,
    /// Angle between the supported object's axis and the vertical.
    pub supported_tilt_deg: f32,
    pub all_on_table: bool,
    pub verified: bool,
    /// Restoring over overturning moment of a free support under the leaning object (leans:
    /// [`crate::lean::support_tipping_margin`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub support_tipping_margin: Option<f32>,
}

#[derive(Serialize)]
pub struct Displacement {
    pub translation_mm: f32,
    pub rotation_deg: f32,
    pub max_vertex_displacement_mm: f32,
    pub static_snapped: bool,
}

#[derive(Serialize)]
pub struct CamerasInfo {
    pub train_ring: RingInfo,
    pub test: &'static str,
    pub test_views_per_state: u32,
}

#[derive(Serialize)]
pub struct PhysicsInfo {
    pub engine: &'static str,
    pub collision_shape: &'static str,
    pub params: PhysicsParams,
    pub static_snap_max_vertex_mm: f32,
    pub t0: SettleStats,
    pub t1: SettleStats,
    pub layout_attempts: Vec<Relation>,
    pub static_snapped_t1: Vec<u32>,
    /// The objects simulated at t = 1 when only those touched by a moving one are
    /// ([`crate::T1Motion::SpreadByContact`]); all others kept their t = 0 pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub t1_simulated_obj_ids: Option<Vec<u32>>,
    /// Contact projection applied to the supported object at t = 0 (null if none).
    pub t0_seat_correction: Option<SeatCorrection>,
}

/// How far the supported object was turned and moved to sit exactly on its support.
#[derive(Clone, Copy, Serialize)]
pub struct SeatCorrection {
    pub tilt_deg: f32,
    pub shift_mm: f32,
}

#[derive(Serialize)]
pub struct RenderInfo {
    pub engine: &'static str,
    pub spp: u32,
    pub rgb_filter: &'static str,
    pub data_passes: &'static str,
    pub max_depth: u32,
    pub lathe_slices: u32,
}
