//! Views, sequences, what to load, and the paper's training-view selection.

use std::path::{Path, PathBuf};

use trand_core::Camera;

use crate::error::IoError;
use crate::image::{DepthMap, InstanceMap, Rgb8Image};

/// One calibrated image of a sequence with whatever of its images was loaded.
#[derive(Clone, Debug)]
pub struct View {
    /// `"{split folder}/{frame:06}"`, e.g. `"train_0/000003"`; unique within a sequence.
    pub name: String,
    pub frame: u32,
    pub camera: Camera,
    pub rgb: Option<Rgb8Image>,
    /// Object id per pixel, 0 = background.
    pub instance: Option<InstanceMap>,
    /// Metres, 0 = no value.
    pub depth: Option<DepthMap>,
}

/// The scene state: before (`T0`) or after (`T1`) an object was removed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum State {
    T0,
    T1,
}

impl State {
    pub fn as_str(self) -> &'static str {
        match self {
            State::T0 => "t0",
            State::T1 => "t1",
        }
    }
}

impl std::str::FromStr for State {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "t0" | "0" => Ok(State::T0),
            "t1" | "1" => Ok(State::T1),
            _ => Err(format!("unknown state `{s}` (expected t0 or t1)")),
        }
    }
}

/// Training or held-out test views.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Split {
    Train,
    Test,
}

impl Split {
    /// BOP folder name of a split and state: `train_0`, `test_1`, ...
    pub fn folder(self, state: State) -> &'static str {
        match (self, state) {
            (Split::Train, State::T0) => "train_0",
            (Split::Train, State::T1) => "train_1",
            (Split::Test, State::T0) => "test_0",
            (Split::Test, State::T1) => "test_1",
        }
    }
}

/// A whole sequence: both states, train and test views.
#[derive(Clone, Debug, Default)]
pub struct Sequence {
    pub root: PathBuf,
    pub train_t0: Vec<View>,
    pub train_t1: Vec<View>,
    pub test_t0: Vec<View>,
    pub test_t1: Vec<View>,
    /// Every object id seen at t=0 (train or test), sorted.
    pub object_ids: Vec<u16>,
    /// Objects removed between t=0 and t=1, when the dataset says (BOP `sequence.json`).
    pub removed_ids: Option<Vec<u16>>,
    /// Which t=0 training views a reconstruction uses.
    pub train_selection: TrainSelection,
}

/// How the t=0 training views are chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TrainSelection {
    /// The paper's rig: frame 0 a bird's-eye view, frames 1..=12 a ring; `--views` picks 3, 6 or
    /// 12 of the ring ([`select_train_views`]). BOP and the authors' transforms files.
    #[default]
    Ring,
    /// The layout lists its training images (nerfstudio): every one of them is used.
    Listed,
}

impl Sequence {
    pub fn views(&self, split: Split, state: State) -> &[View] {
        match (split, state) {
            (Split::Train, State::T0) => &self.train_t0,
            (Split::Train, State::T1) => &self.train_t1,
            (Split::Test, State::T0) => &self.test_t0,
            (Split::Test, State::T1) => &self.test_t1,
        }
    }

    pub fn views_mut(&mut self, split: Split, state: State) -> &mut Vec<View> {
        match (split, state) {
            (Split::Train, State::T0) => &mut self.train_t0,
            (Split::Train, State::T1) => &mut self.train_t1,
            (Split::Test, State::T0) => &mut self.test_t0,
            (Split::Test, State::T1) => &mut self.test_t1,
        }
    }

    /// All views of all splits and states.
    pub fn all_views(&self) -> impl Iterator<Item = &View> {
        self.train_t0
            .iter()
            .chain(&self.train_t1)
            .chain(&self.test_t0)
            .chain(&self.test_t1)
    }
}

/// Whether an image kind is decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Load {
    Yes,
    No,
}

impl Load {
    pub fn yes(self) -> bool {
        self == Load::Yes
    }
}

/// What a reader decodes besides the cameras, and the object-channel budget to check ids against.
#[derive(Clone, Copy, Debug)]
pub struct LoadOptions {
    pub rgb: Load,
    pub masks: Load,
    pub depth: Load,
    /// Object channels of the model (background included, TRAN-D's `NUM_OBJ`); every object id must be
    /// below it. `None` skips the check.
    pub object_channels: Option<usize>,
}

impl Default for LoadOptions {
    /// Everything, checked against [`trand_core::DEFAULT_NUM_OBJECTS`].
    fn default() -> Self {
        Self {
            rgb: Load::Yes,
            masks: Load::Yes,
            depth: Load::Yes,
            object_channels: Some(trand_core::DEFAULT_NUM_OBJECTS),
        }
    }
}

impl LoadOptions {
    /// Masks and depth only: what the evaluation needs.
    pub fn for_eval() -> Self {
        Self {
            rgb: Load::No,
            ..Self::default()
        }
    }

    /// The same options with depth loading switched.
    pub fn with_depth(self, depth: Load) -> Self {
        Self { depth, ..self }
    }

    /// Cameras only.
    pub fn cameras_only() -> Self {
        Self {
            rgb: Load::No,
            masks: Load::No,
            depth: Load::No,
            object_channels: None,
        }
    }

    /// Fails with [`IoError::TooManyObjects`] if an id does not fit the channel budget.
    pub(crate) fn check_ids(&self, ids: &[u16], path: &Path, field: &str) -> Result<(), IoError> {
        if let Some(k) = self.object_channels
            && let Some(&id) = ids.iter().find(|&&id| id as usize >= k)
        {
            return Err(IoError::TooManyObjects {
                path: path.into(),
                field: field.into(),
                id: id as u32,
                channels: k,
            });
        }
        Ok(())
    }
}

/// How many training views to use at t=0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewCount {
    Three,
    Six,
    Twelve,
}

impl ViewCount {
    pub fn from_count(n: usize) -> Option<Self> {
        match n {
            3 => Some(Self::Three),
            6 => Some(Self::Six),
            12 => Some(Self::Twelve),
            _ => None,
        }
    }

    pub fn count(self) -> usize {
        match self {
            Self::Three => 3,
            Self::Six => 6,
            Self::Twelve => 12,
        }
    }

    /// The ring frames used, in order.
    pub fn frames(self) -> Vec<u32> {
        match self {
            Self::Three => vec![1, 5, 9],
            Self::Six => vec![1, 3, 5, 7, 9, 11],
            Self::Twelve => (1..=12).collect(),
        }
    }
}

/// First and last frame of the t=0 training ring (frame 0 is the bird's-eye view).
pub const RING_FRAMES: std::ops::RangeInclusive<u32> = 1..=12;

/// The paper's t=0 training views among `views` (the t=0 training set).
///
/// Frame 0 is the bird's-eye view and is never a t=0 training view (the authors' `idx % 2 == 1` rule);
/// frames 1..=12 are a ring at 30° azimuth steps. Six views are the odd frames 1, 3, 5, 7, 9, 11 (60°
/// apart, the paper's default); twelve are all of 1..=12; three are frames 1, 5, 9 (every fourth ring
/// view, 120° apart). Views are returned in frame order; a frame that is absent is skipped.
pub fn select_train_views(views: &[View], n: ViewCount) -> Vec<View> {
    let frames = n.frames();
    let mut out: Vec<View> = views
        .iter()
        .filter(|v| frames.contains(&v.frame))
        .cloned()
        .collect();
    out.sort_by_key(|v| v.frame);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::Intrinsics;

    fn views(frames: impl IntoIterator<Item = u32>) -> Vec<View> {
        let cam = Camera::look_at(
            Intrinsics::centered(10.0, 4, 3),
            glam::DVec3::Z,
            glam::DVec3::ZERO,
            glam::DVec3::Y,
        );
        frames
            .into_iter()
            .map(|frame| View {
                name: format!("train_0/{frame:06}"),
                frame,
                camera: cam,
                rgb: None,
                instance: None,
                depth: None,
            })
            .collect()
    }

    #[test]
    fn train_view_selection_follows_the_paper() {
        let all = views((0..=12).rev());
        let frames = |n| {
            select_train_views(&all, n)
                .iter()
                .map(|v| v.frame)
                .collect::<Vec<_>>()
        };
        assert_eq!(frames(ViewCount::Six), vec![1, 3, 5, 7, 9, 11]);
        assert_eq!(frames(ViewCount::Twelve), (1..=12).collect::<Vec<_>>());
        assert_eq!(frames(ViewCount::Three), vec![1, 5, 9]);
        for n in [ViewCount::Three, ViewCount::Six, ViewCount::Twelve] {
            assert_eq!(ViewCount::from_count(n.count()), Some(n));
            assert!(n.frames().iter().all(|f| RING_FRAMES.contains(f)));
        }
        assert_eq!(ViewCount::from_count(4), None);
    }

    #[test]
    fn absent_frames_are_skipped_not_invented() {
        let some = views([0, 1, 2, 3]);
        assert_eq!(
            select_train_views(&some, ViewCount::Six)
                .iter()
                .map(|v| v.frame)
                .collect::<Vec<_>>(),
            vec![1, 3]
        );
    }

    #[test]
    fn state_parses_from_cli_words() {
        assert_eq!("t1".parse::<State>(), Ok(State::T1));
        assert!("t2".parse::<State>().is_err());
        assert_eq!(Split::Test.folder(State::T1), "test_1");
    }
}
