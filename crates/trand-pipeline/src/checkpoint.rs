//! Training checkpoints that resume exactly.
//!
//! A resumed run must take the very steps the uninterrupted run would have taken, so a checkpoint
//! holds everything the optimisation loop carries from one iteration to the next, not just the
//! surfels: Adam's moments and per-group step counts (which set the bias corrections), the
//! densification statistics accumulated since the last densification, the view sampler (its random
//! stream, which densification also draws from, and the views left in the current epoch), and the
//! loss curve so far. Learning-rate schedules are functions of the iteration number, which is stored.
//! Two more fields guard against resuming the wrong thing: a fingerprint of the training views
//! (cameras, images and labels as trained on) and the run's options as TOML; a checkpoint whose
//! fingerprint or options differ from the run's is refused.
//!
//! One file, written atomically (so a killed write leaves the previous checkpoint):
//!
//! ```text
//! TRAND-CHECKPOINT\n          magic
//! u64 LE                      header length H
//! H bytes                     header, JSON (format, iteration, fingerprint, options, Adam constants
//!                             and step counts, sampler, curve as f32 bits, section lengths)
//! sections                    surfels, Adam m, Adam v (surfel PLY, exact bits);
//!                             grad_accum (f32 LE), denom (u32 LE), max_radii (f32 LE)
//! ```
//! The reader checks every length against the bytes present before it allocates, so a corrupt or
//! crafted file gives an error naming the file and field, never a panic or a huge allocation.

use std::path::Path;

use rand_pcg::Pcg64;
use serde::{Deserialize, Serialize};
use trand_core::Surfels;
use trand_io::IoError;
use trand_io::ply::{surfels_from_ply_bytes, surfels_to_ply_bytes};
use trand_train::optim::AdamParams;
use trand_train::{Adam, DensifyStats, PoseCorrections};

const MAGIC: &[u8] = b"TRAND-CHECKPOINT\n";
const FORMAT: u32 = 2;
const SECTIONS: [&str; 6] = [
    "surfels",
    "adam_m",
    "adam_v",
    "grad_accum",
    "denom",
    "max_radii",
];

/// The loop's state after an iteration, borrowed (what is written).
pub struct Snapshot<'a> {
    /// The last completed iteration.
    pub iteration: u32,
    pub surfels: &'a Surfels,
    pub adam: &'a Adam,
    pub stats: &'a DensifyStats,
    pub rng: &'a Pcg64,
    /// Views left in the sampler's current epoch.
    pub stack: &'a [usize],
    /// The training views' pose corrections and their optimiser state.
    pub poses: &'a PoseCorrections,
    pub curve: &'a [(u32, f32)],
    pub initial_surfels: usize,
    /// Fingerprint of the training views ([`crate::reconstruct::training_fingerprint`]).
    pub fingerprint: &'a str,
    /// The run's options as TOML.
    pub options: &'a str,
}

/// A checkpoint read back (owned).
#[derive(Clone, Debug)]
pub struct Checkpoint {
    pub iteration: u32,
    pub surfels: Surfels,
    pub adam: Adam,
    pub stats: DensifyStats,
    pub rng: Pcg64,
    pub stack: Vec<usize>,
    pub poses: PoseCorrections,
    pub curve: Vec<(u32, f32)>,
    pub initial_surfels: usize,
    pub fingerprint: String,
    pub options: String,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: u32,
    iteration: u32,
    fingerprint: String,
    options: String,
    adam_params: AdamParams,
    adam_steps: [u64; 9],
    rng: Pcg64,
    stack: Vec<usize>,
    poses: PoseCorrections,
    /// `(iteration, loss bits)`: bits, so the curve comes back exactly.
    curve: Vec<(u32, u32)>,
    initial_surfels: usize,
    /// Byte length of each section, in [`SECTIONS`] order.
    sections: Vec<u64>,
}

fn le_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

impl Snapshot<'_> {
    /// The checkpoint file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let sections: [Vec<u8>; 6] = [
            surfels_to_ply_bytes(self.surfels),
            surfels_to_ply_bytes(&self.adam.m),
            surfels_to_ply_bytes(&self.adam.v),
            le_f32(&self.stats.grad_accum),
            self.stats
                .denom
                .iter()
                .flat_map(|x| x.to_le_bytes())
                .collect(),
            le_f32(&self.stats.max_radii),
        ];
        let header = Header {
            format: FORMAT,
            iteration: self.iteration,
            fingerprint: self.fingerprint.into(),
            options: self.options.into(),
            adam_params: self.adam.params,
            adam_steps: self.adam.steps,
            rng: self.rng.clone(),
            stack: self.stack.to_vec(),
            poses: self.poses.clone(),
            curve: self.curve.iter().map(|&(i, l)| (i, l.to_bits())).collect(),
            initial_surfels: self.initial_surfels,
            sections: sections.iter().map(|s| s.len() as u64).collect(),
        };
        let h = serde_json::to_vec(&header).expect("the header serialises");
        let mut out = Vec::with_capacity(
            MAGIC.len() + 8 + h.len() + sections.iter().map(Vec::len).sum::<usize>(),
        );
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(h.len() as u64).to_le_bytes());
        out.extend_from_slice(&h);
        for s in &sections {
            out.extend_from_slice(s);
        }
        out
    }

    /// Writes the checkpoint to `path` atomically.
    pub fn write(&self, path: &Path) -> Result<(), IoError> {
        trand_io::write_atomic(path, &self.encode())
    }
}

fn field(path: &Path, field: &str, reason: impl Into<String>) -> IoError {
    IoError::Field {
        path: path.into(),
        field: field.into(),
        reason: reason.into(),
    }
}

/// Splits `n` bytes off the front of `rest`, or says which field ran past the end.
fn take<'b>(rest: &mut &'b [u8], n: u64, path: &Path, what: &str) -> Result<&'b [u8], IoError> {
    let n = usize::try_from(n)
        .ok()
        .filter(|&n| n <= rest.len())
        .ok_or_else(|| {
            field(
                path,
                what,
                format!("needs {n} bytes, only {} left (truncated?)", rest.len()),
            )
        })?;
    let (a, b) = rest.split_at(n);
    *rest = b;
    Ok(a)
}

fn words<const N: usize>(b: &[u8], path: &Path, what: &str) -> Result<Vec<[u8; N]>, IoError> {
    if !b.len().is_multiple_of(N) {
        return Err(field(
            path,
            what,
            format!("{} bytes is not a multiple of {N}", b.len()),
        ));
    }
    Ok(b.chunks_exact(N)
        .map(|c| c.try_into().expect("chunks of N"))
        .collect())
}

impl Checkpoint {
    /// Parses checkpoint bytes; `path` names the source in errors.
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Self, IoError> {
        let mut rest = bytes;
        if take(&mut rest, MAGIC.len() as u64, path, "magic")? != MAGIC {
            return Err(field(path, "magic", "not a trand checkpoint"));
        }
        let hlen = u64::from_le_bytes(
            take(&mut rest, 8, path, "header length")?
                .try_into()
                .expect("8 bytes"),
        );
        let h: Header = serde_json::from_slice(take(&mut rest, hlen, path, "header")?)
            .map_err(|e| field(path, "header", e.to_string()))?;
        if h.format != FORMAT {
            return Err(field(
                path,
                "format",
                format!("format {} is not {FORMAT}; start the run afresh", h.format),
            ));
        }
        if h.sections.len() != SECTIONS.len() {
            return Err(field(
                path,
                "sections",
                format!("{} sections, expected {}", h.sections.len(), SECTIONS.len()),
            ));
        }
        let mut sec = Vec::with_capacity(SECTIONS.len());
        for (&len, name) in h.sections.iter().zip(SECTIONS) {
            sec.push(take(&mut rest, len, path, name)?);
        }
        if !rest.is_empty() {
            return Err(field(
                path,
                "sections",
                format!("{} trailing bytes", rest.len()),
            ));
        }
        let ply = |i: usize| {
            surfels_from_ply_bytes(sec[i], path)
                .map_err(|e| field(path, SECTIONS[i], e.to_string()))
        };
        let surfels = ply(0)?;
        let (m, v) = (ply(1)?, ply(2)?);
        let f32s = |i: usize| -> Result<Vec<f32>, IoError> {
            Ok(words::<4>(sec[i], path, SECTIONS[i])?
                .into_iter()
                .map(f32::from_le_bytes)
                .collect())
        };
        let stats = DensifyStats {
            grad_accum: f32s(3)?,
            denom: words::<4>(sec[4], path, SECTIONS[4])?
                .into_iter()
                .map(u32::from_le_bytes)
                .collect(),
            max_radii: f32s(5)?,
        };
        let n = surfels.len();
        let shape = (surfels.sh_degree, surfels.num_objects, n);
        for (name, s) in [("adam_m", &m), ("adam_v", &v)] {
            if (s.sh_degree, s.num_objects, s.len()) != shape {
                return Err(field(path, name, "shape differs from the surfels"));
            }
        }
        if [
            stats.grad_accum.len(),
            stats.denom.len(),
            stats.max_radii.len(),
        ] != [n; 3]
        {
            return Err(field(
                path,
                "grad_accum/denom/max_radii",
                format!("lengths differ from the {n} surfels"),
            ));
        }
        Ok(Self {
            iteration: h.iteration,
            surfels,
            adam: Adam {
                params: h.adam_params,
                m,
                v,
                steps: h.adam_steps,
            },
            stats,
            rng: h.rng,
            stack: h.stack,
            poses: h.poses,
            curve: h
                .curve
                .into_iter()
                .map(|(i, b)| (i, f32::from_bits(b)))
                .collect(),
            initial_surfels: h.initial_surfels,
            fingerprint: h.fingerprint,
            options: h.options,
        })
    }

    /// Reads a checkpoint file.
    pub fn read(path: &Path) -> Result<Self, IoError> {
        let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
        Self::decode(&bytes, path)
    }

    /// Borrows the checkpoint as a [`Snapshot`] (to write it again).
    pub fn snapshot(&self) -> Snapshot<'_> {
        Snapshot {
            iteration: self.iteration,
            surfels: &self.surfels,
            adam: &self.adam,
            stats: &self.stats,
            rng: &self.rng,
            stack: &self.stack,
            poses: &self.poses,
            curve: &self.curve,
            initial_surfels: self.initial_surfels,
            fingerprint: &self.fingerprint,
            options: &self.options,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn sample() -> Checkpoint {
        let mut s = Surfels::new(1, 3).unwrap();
        for i in 0..4 {
            s.push(&trand_core::surfels::Surfel {
                mean: [i as f32 * 0.1, -0.2, 0.3],
                log_scale: [-3.0, -2.5],
                quat: [1.0, 0.1, 0.0, 0.0],
                opacity_logit: 0.25,
                sh_dc: [0.1, 0.2, 0.3],
                mask_dc: [0.3, 0.2, 0.1],
                obj_logits: vec![0.5, -1.0, 2.0],
            });
        }
        let mut adam = Adam::new(&s, AdamParams::default());
        adam.m.means[2][1] = 1.5e-7;
        adam.v.obj_logits[5] = 3.25e-9;
        adam.steps[4] = 17;
        Checkpoint {
            iteration: 123,
            adam,
            stats: DensifyStats {
                grad_accum: vec![0.5, 0.0, 1e-9, 7.0],
                denom: vec![1, 0, 3, 9],
                max_radii: vec![2.0, 0.0, 0.5, 1.0],
            },
            surfels: s,
            rng: Pcg64::seed_from_u64(99),
            stack: vec![2, 0],
            poses: {
                let mut p = PoseCorrections::new(3);
                p.xi[1] = [1e-3, -2e-4, 3.5e-5, 1e-3, 0.0, -7e-4];
                p
            },
            curve: vec![(1, 0.75), (2, f32::from_bits(0x3e99_999a))],
            initial_surfels: 4,
            fingerprint: "00ff".into(),
            options: "views = 6\n".into(),
        }
    }

    #[test]
    fn checkpoint_round_trips_every_bit() {
        let c = sample();
        let bytes = c.snapshot().encode();
        let d = Checkpoint::decode(&bytes, Path::new("c")).unwrap();
        assert_eq!(d.snapshot().encode(), bytes);
        assert_eq!(d.adam, c.adam);
        assert_eq!(d.surfels, c.surfels);
        assert_eq!(d.rng, c.rng);
        assert_eq!(d.stats.denom, c.stats.denom);
        assert_eq!(d.curve, c.curve);
        assert_eq!(d.poses, c.poses);
    }

    #[test]
    fn truncated_or_padded_checkpoints_are_refused() {
        let bytes = sample().snapshot().encode();
        for n in [0, 5, MAGIC.len() + 3, bytes.len() / 2, bytes.len() - 1] {
            assert!(
                Checkpoint::decode(&bytes[..n], Path::new("c")).is_err(),
                "{n} bytes"
            );
        }
        let mut padded = bytes.clone();
        padded.push(0);
        assert!(Checkpoint::decode(&padded, Path::new("c")).is_err());
    }
}
