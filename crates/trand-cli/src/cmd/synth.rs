//! `trand synth`: generate one synthetic transparent-object sequence (BOP layout, exact GT).

use std::path::PathBuf;
use trand_synth::cameras::Rig;
use trand_synth::{ExistingOutput, ObjectCount, Preset, Progress, SynthConfig};

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum PresetArg {
    /// 640x480, 4 objects (a stacked pair among random ones), 30 test views per state.
    Default,
    /// 160x120, 3 objects, 3 test views per state, few samples (seconds; for tests).
    Tiny,
    /// 640x480, 3-6 objects: upright open bowls, mugs and wine glasses, lying tumblers, and an
    /// object leaning against or stacked on the one removed at t=1; 10 test views per state.
    Containers,
    /// The containers scenes at 160x120, 3 test views per state (seconds; for tests).
    ContainersTiny,
}

impl PresetArg {
    pub fn preset(self) -> Preset {
        match self {
            PresetArg::Default => Preset::Default,
            PresetArg::Tiny => Preset::Tiny,
            PresetArg::Containers => Preset::Containers,
            PresetArg::ContainersTiny => Preset::ContainersTiny,
        }
    }
}

/// The training rig (see `trand_synth::cameras`).
#[derive(Clone, Copy, clap::ValueEnum)]
enum RigArg {
    /// Bird's-eye view and a 12-view ring at 38° elevation, 0.54 m.
    Fixed,
    /// The same ring at an elevation and distance drawn as the reference sequences vary.
    Varied,
    /// A robot's stereo rig or wrist camera: every training view within 6° of one axis, test views
    /// within 10°.
    Narrow,
}

impl RigArg {
    fn rig(self) -> Rig {
        match self {
            Self::Fixed => Rig::Fixed,
            Self::Varied => Rig::Varied,
            Self::Narrow => Rig::Narrow,
        }
    }
}

#[derive(clap::Args)]
pub struct Args {
    /// Random seed: the whole sequence is a function of it (and the settings).
    #[arg(long)]
    seed: u64,
    /// Output folder (must not exist or be empty, unless --force).
    #[arg(long)]
    out: PathBuf,
    #[arg(long, value_enum, default_value = "default")]
    preset: PresetArg,
    /// Number of objects (2 to 6; 3 to 6 for the containers presets); overrides the preset.
    #[arg(long)]
    objects: Option<u32>,
    /// Image width in pixels; overrides the preset.
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels; overrides the preset.
    #[arg(long)]
    height: Option<u32>,
    /// The training cameras; overrides the preset (`fixed` for default and tiny, `varied` for the
    /// containers presets).
    #[arg(long, value_enum)]
    rig: Option<RigArg>,
    /// Random test views per state; overrides the preset.
    #[arg(long)]
    test_views: Option<u32>,
    /// Colour samples per pixel; overrides the preset.
    #[arg(long)]
    spp: Option<u32>,
    /// Replace a non-empty output folder.
    #[arg(long)]
    force: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let mut c = SynthConfig::new(a.preset.preset(), a.seed, a.out);
    c.objects = a.objects.map_or(c.objects, ObjectCount::Exactly);
    c.width = a.width.unwrap_or(c.width);
    c.height = a.height.unwrap_or(c.height);
    c.test_views = a.test_views.unwrap_or(c.test_views);
    c.rig = a.rig.map_or(c.rig, RigArg::rig);
    c.samples_per_pixel = a.spp.unwrap_or(c.samples_per_pixel);
    c.existing = if a.force {
        ExistingOutput::Replace
    } else {
        ExistingOutput::Refuse
    };
    c.progress = if a.quiet {
        Progress::Hidden
    } else {
        Progress::Bar
    };
    let s = trand_synth::generate(&c)?;
    println!(
        "wrote {} views to {} (removed object {}, {} {}) in {:.1} s (physics {:.1} s, render+write {:.1} s)",
        s.views,
        s.out.display(),
        s.removed_obj_id,
        s.relation.name(),
        if s.relation_verified {
            "verified"
        } else {
            "not verified"
        },
        s.total_s,
        s.physics_s,
        s.render_s
    );
    Ok(())
}
