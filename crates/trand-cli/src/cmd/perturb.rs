//! `trand perturb`: a copy of a sequence whose training inputs are perturbed the way a robot's
//! segmenter and calibration perturb them (per-image ids, boundary errors, a missed mask, pose error),
//! seeded and reproducible; the test views stay exact. See `trand_io::perturb`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use trand_io::perturb::{IdMode, Perturbation, write_perturbed};
use trand_io::{LoadOptions, read_sequence_with};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (any layout trand reads).
    #[arg(long)]
    pub data: PathBuf,
    /// Output sequence folder (BOP layout; must not exist).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Instance ids of the training masks: consistent (as given) or per-view (a random permutation
    /// of 1..N in every view).
    #[arg(long, value_parser = parse_ids, default_value = "consistent")]
    pub ids: IdMode,
    /// Erode or dilate every training mask by a random 1..=PX pixels and stick two small blobs to
    /// its edge (0 = untouched).
    #[arg(long, default_value_t = 0)]
    pub boundary: u32,
    /// Remove this many (view, object) masks from the t=0 training views.
    #[arg(long, default_value_t = 0)]
    pub miss: u32,
    /// Pose error of every training camera: DEG,MM (turned by DEG degrees about a random axis,
    /// moved MM millimetres in a random direction), e.g. 0.5,3.
    #[arg(long, value_parser = parse_pose)]
    pub pose: Option<(f64, f64)>,
    /// A calibration error every training camera shares: X,Y,Z millimetres (each camera sees the
    /// world moved by it), e.g. 4,0,0. No image shows it; it measures what such a bias costs.
    #[arg(long, value_parser = parse_shift, allow_hyphen_values = true)]
    pub shift: Option<[f64; 3]>,
}

fn parse_ids(s: &str) -> Result<IdMode, String> {
    match s {
        "consistent" => Ok(IdMode::Consistent),
        "per-view" => Ok(IdMode::PerView),
        _ => Err(format!("unknown id mode `{s}` (consistent, per-view)")),
    }
}

fn parse_pose(s: &str) -> Result<(f64, f64), String> {
    let (d, m) = s
        .split_once(',')
        .ok_or_else(|| format!("`{s}`: expected DEG,MM, e.g. 0.5,3"))?;
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| format!("`{t}` is not a non-negative number"))
    };
    Ok((num(d)?, num(m)?))
}

fn parse_shift(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| format!("`{s}`: expected X,Y,Z in millimetres, e.g. 4,0,0"))?;
    v.try_into()
        .map_err(|_| format!("`{s}`: expected three numbers X,Y,Z"))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if a.out.exists() {
        bail!("{}: output folder already exists", a.out.display());
    }
    let opts = LoadOptions {
        object_channels: None,
        ..Default::default()
    };
    let seq = read_sequence_with(&a.data, &opts)
        .with_context(|| format!("reading {}", a.data.display()))?;
    let p = Perturbation {
        seed: a.seed,
        ids: a.ids,
        boundary_px: a.boundary,
        miss: a.miss,
        pose: a.pose,
        shift_mm: a.shift,
    };
    let reports = write_perturbed(&seq, &a.out, &p)?;
    let missed: usize = reports.iter().map(|r| r.missed.len()).sum();
    println!(
        "perturbed {} training views of {} (ids {:?}, boundary {} px, {missed} masks missed, pose {:?}, shift {:?} mm) -> {} (see perturbation.json)",
        reports.len(),
        a.data.display(),
        p.ids,
        p.boundary_px,
        p.pose,
        p.shift_mm,
        a.out.display()
    );
    Ok(())
}
