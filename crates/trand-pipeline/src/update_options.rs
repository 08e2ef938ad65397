//! Settings of the t = 1 update ([`crate::update`]) and the scale of the t = 0 scene it carries over.
//!
//! Apart from the update itself so that its stages ([`crate::simulate`], [`crate::update`]) read the
//! same settings without importing each other.

use trand_core::Camera;
use trand_physics::{InteriorFill, MpmConfig};
use trand_train::config::TrainConfig;

use crate::detect::Identity;
use crate::relocalise::Relocalise;
use crate::{PipelineError, Result};

/// Which depth of the rendered surfels feeds the TSDF.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum MeshDepth {
    /// `Σ w z / α`: the authors' code (depth_ratio 0).
    Expected,
    /// The median depth (what evaluation uses).
    Median,
}

/// Which objects the single-image refinement may change.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum RefineScope {
    /// Only the objects that may have moved (the simulation's, and those the relocalisation
    /// searched); every other object keeps its t = 0 surfels, which six views fixed better than one.
    Moved,
    /// Every object, as the paper.
    All,
}

/// Whether surfels also rotate with their particle.
///
/// One name per value in TOML, JSON and on the command line (`translate-rotate`,
/// `rigid-per-object`); the command line's former short names `rotate` and `rigid` are aliases
/// everywhere.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum SurfelMotion {
    /// Centres only (the authors' release).
    Translate,
    /// Centres and orientation (polar rotation of the particle's deformation gradient).
    #[serde(alias = "rotate")]
    #[cfg_attr(feature = "clap", value(alias = "rotate"))]
    TranslateRotate,
    /// Each object moves rigidly by the best fit (Kabsch) of its surfels' particle displacements:
    /// the simulation decides where an object falls, but the very soft material of the paper (it sags
    /// by a third of its height under gravity) does not squash its shape.
    #[serde(alias = "rigid")]
    #[cfg_attr(feature = "clap", value(alias = "rigid"))]
    RigidPerObject,
}

/// A stage that can be switched off for the ablations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Stage {
    On,
    Off,
}

/// Settings of the update.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct UpdateOptions {
    pub physics: Stage,
    pub refine: Stage,
    /// Which objects the refinement may change.
    pub refine_scope: RefineScope,
    /// The new photo's camera turned to fit the objects the removal cannot have moved
    /// ([`crate::new_camera`]). Off keeps the camera; the objects' fits, which find the ones knocked
    /// aside, are computed either way.
    pub correct_camera: Stage,
    /// Silhouette relocalisation after the simulation.
    pub relocalise: Stage,
    pub relocalise_settings: Relocalise,
    /// Removed object ids given by the user instead of detection.
    pub removed: Option<Vec<u16>>,
    pub identity: Identity,
    /// Weight of the centroid distance (in image diagonals) in the matching cost `1 − IoU + w·d`, so that
    /// an object that moved far (low IoU) still finds its new instance rather than being taken as removed.
    pub centroid_weight: f64,
    pub mesh_depth: MeshDepth,
    pub motion: SurfelMotion,
    pub fill: InteriorFill,
    /// Virtual views: elevations (degrees) × azimuths, at this image size and focal length. Default
    /// 2 × 8 + the view from below = 17 views (the authors fuse their 10 test views + 1 from below);
    /// three elevations (15°, 40°, 65°, 25 views) gave the same t=1 accuracy on both Blender sequences
    /// (MAE 0.0400 / 0.0379 m vs 0.0390 / 0.0385 m) at 0.4–0.7 s more meshing.
    pub ring_elevations_deg: Vec<f64>,
    pub ring_azimuths: usize,
    pub virtual_width: u32,
    pub virtual_height: u32,
    pub virtual_focal: f64,
    pub mpm: MpmConfig,
    /// The refinement: [`TrainConfig::t1`] with the keys a file gives replaced.
    #[serde(deserialize_with = "t1_with_overrides")]
    pub train: TrainConfig,
    /// Image downsampling for the refinement (`None`: the t = 0 run's).
    pub downsample: Option<u32>,
}

/// Reads a `[train]` table as overrides of [`TrainConfig::t1`]: the table's keys (nested tables key by
/// key) replace those of the refinement's defaults. Plain serde defaults would fill the keys a file
/// leaves out from [`TrainConfig::default`], the t = 0 optimisation.
fn t1_with_overrides<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<TrainConfig, D::Error> {
    use serde::de::Error;
    let given = <toml::Table as serde::Deserialize>::deserialize(d)?;
    let mut base = toml::Table::try_from(TrainConfig::t1()).map_err(D::Error::custom)?;
    merge(&mut base, given);
    base.try_into().map_err(D::Error::custom)
}

/// Replaces `base`'s keys by `over`'s, descending into a table of both whose keys in `over` are all
/// keys of `base` (a struct given in part); a table with other keys (another enum variant) replaces.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o))
                if o.keys().all(|key| b.contains_key(key)) =>
            {
                merge(b, o)
            }
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

impl UpdateOptions {
    /// Checks the ranges of the options read from a file (the error names the key).
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(PipelineError::Invalid(format!("invalid update option {m}")));
        self.train.validate()?;
        if self.downsample == Some(0) || self.downsample.is_some_and(|d| d > 64) {
            return bad(format!(
                "`downsample` = {:?}: must be 1 to 64",
                self.downsample
            ));
        }
        let side = trand_core::camera::MAX_IMAGE_SIDE;
        for (key, v) in [
            ("virtual_width", self.virtual_width),
            ("virtual_height", self.virtual_height),
        ] {
            if v == 0 || v > side {
                return bad(format!("`{key}` = {v}: must be 1 to {side}"));
            }
        }
        if !(self.virtual_focal.is_finite() && self.virtual_focal > 0.0) {
            return bad(format!(
                "`virtual_focal` = {}: must be positive",
                self.virtual_focal
            ));
        }
        if self.ring_azimuths > 360 || self.ring_elevations_deg.len() > 90 {
            return bad("`ring_azimuths` above 360 or more than 90 `ring_elevations_deg`".into());
        }
        if self.ring_elevations_deg.iter().any(|e| !e.is_finite()) {
            return bad("`ring_elevations_deg`: not finite".into());
        }
        if !self.centroid_weight.is_finite() || self.centroid_weight < 0.0 {
            return bad(format!(
                "`centroid_weight` = {}: must be ≥ 0",
                self.centroid_weight
            ));
        }
        Ok(())
    }
}

/// Scale of the t = 0 scene, carried into the update.
#[derive(Clone, Copy, Debug)]
pub struct SceneScale {
    /// 1.1 × the largest distance of a t = 0 training camera from their mean (densification unit).
    pub extent: f32,
    /// The scene radius ([`trand_physics::scene_radius`]) of the t = 0 training cameras, 0.5 m when
    /// they have no focus point: sets the TSDF voxel `2·radius/256` as the authors' code does with
    /// its camera radius.
    pub radius: f32,
    /// The t = 0 run's training downsampling.
    pub downsample: u32,
}

impl SceneScale {
    /// The scale of a t = 0 run trained on `cameras`.
    pub fn from_cameras(cameras: &[Camera], downsample: u32) -> Self {
        let extent = crate::trainer::camera_extent(cameras);
        let radius = trand_physics::scene_radius(cameras).unwrap_or(0.5) as f32;
        Self {
            extent,
            radius,
            downsample,
        }
    }
}

impl Default for UpdateOptions {
    fn default() -> Self {
        Self {
            physics: Stage::On,
            refine: Stage::On,
            refine_scope: RefineScope::Moved,
            correct_camera: Stage::On,
            relocalise: Stage::On,
            relocalise_settings: Relocalise::default(),
            removed: None,
            identity: Identity::Auto,
            centroid_weight: 0.5,
            mesh_depth: MeshDepth::Expected,
            motion: SurfelMotion::RigidPerObject,
            fill: InteriorFill::None,
            ring_elevations_deg: vec![20.0, 50.0],
            ring_azimuths: 8,
            virtual_width: 320,
            virtual_height: 240,
            virtual_focal: 300.0,
            mpm: MpmConfig::default(),
            train: TrainConfig::t1(),
            downsample: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_train::config::TrainConfig;
    use trand_train::optim::LrSchedule;

    fn read(text: &str) -> std::result::Result<UpdateOptions, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn a_partial_train_table_overrides_the_refinement_not_the_t0_optimisation() {
        let o = read("[train]\niterations = 50\n[train.lr]\nopacity = { log_linear = { from = 0.5, to = 0.05, max_steps = 1100 } }\n").unwrap();
        let mut want = TrainConfig::t1();
        want.iterations = 50;
        want.lr.opacity = LrSchedule::LogLinear {
            from: 0.5,
            to: 0.05,
            max_steps: 1100,
        };
        assert_eq!(o.train, want);
        let o = read("[train]\nresolution = { coarse_to_fine = [{ factor = 2, until = 0.7 }] }\n")
            .unwrap();
        assert_eq!(o.train.start_iteration, 1000);
        assert_eq!(o.train.iterations, 100);
        assert_eq!(o.train.resolution.factor_at(70, 100), 2);
        assert_eq!(read("").unwrap().train, TrainConfig::t1());
    }

    #[test]
    fn an_unknown_train_key_is_refused() {
        let e = read("[train]\niteratons = 50\n").unwrap_err();
        assert!(e.to_string().contains("iteratons"), "{e}");
    }
}
