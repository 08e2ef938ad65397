//! The public entry points: [`render`] (stages 1–3) and [`Rendered::backward`] (stages 4–6).

use rayon::prelude::*;
use trand_core::{Camera, CameraError, Real};

use crate::backward::{GradMaps, rec, reduce_surfel};
use crate::binning::{Bins, bin};
use crate::camera::CamR;
use crate::constants::{DEFAULT_NEAR, TILE, TILE_PIXELS};
use crate::labels::{ObjectSumGrads, ObjectSums};
use crate::lanes::LANES;
use crate::layout::{GeometryMaps, INT_CHANNELS, Layout};
use crate::params::{ParamsOf, SurfelParams, par_zeros};
use crate::preprocess::{
    Proj, Retained, SurfelGradSlot, preprocess_backward_one, preprocess_retained, softmax_block,
};
use crate::simd::{backward_tile, raster_tile};

/// Surfels per preprocess task.
const PREPROCESS_CHUNK: usize = 512;

/// The largest number of object channels the kernels support (fixed-size stack buffers).
pub const MAX_OBJECTS: usize = trand_core::MAX_NUM_OBJECTS;

/// Which optional maps to render. RGB and the geometric maps (alpha, depth, median, normal,
/// distortion) are always produced; the mask colour and the K-channel object map cost extra work per
/// pixel and are rendered only when asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Maps {
    /// RGB and geometry only (evaluation, TSDF fusion).
    #[default]
    Rgb,
    /// Also the colour-coded mask image.
    RgbMask,
    /// Also the object-probability map.
    RgbObjects,
    /// Everything (TRAN-D training).
    All,
}

impl Maps {
    pub fn mask(self) -> bool {
        matches!(self, Maps::RgbMask | Maps::All)
    }
    pub fn objects(self) -> bool {
        matches!(self, Maps::RgbObjects | Maps::All)
    }
}

/// Render settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Background colour of the RGB and mask images.
    pub background: [f32; 3],
    /// Near plane (metres): surfel centres and per-pixel hits closer than this are ignored.
    pub near: f64,
    /// SH degree used for colours (at most the parameters' degree; `None` = the parameters' degree).
    pub sh_degree: Option<u32>,
    pub maps: Maps,
    pub geometry: GeometryMaps,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            background: [0.0; 3],
            near: DEFAULT_NEAR,
            sh_degree: None,
            maps: Maps::Rgb,
            geometry: GeometryMaps::Rendered,
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RenderError {
    #[error("invalid camera: {0}")]
    Camera(#[from] CameraError),
    #[error("{0} object channels requested; the rasterizer supports 1 to {MAX_OBJECTS}")]
    Objects(usize),
    #[error("near plane {0} must be finite and positive")]
    Near(f64),
    #[error("label map has {got} entries, the image {expected} pixels")]
    LabelsSize { got: usize, expected: usize },
    #[error("label {label} at pixel {pixel} is not one of the {num_objects} object channels")]
    Label {
        label: u8,
        pixel: usize,
        num_objects: usize,
    },
    #[error("object sums need the object channels (Maps::RgbObjects or Maps::All)")]
    SumsWithoutObjects,
}

/// Rendered maps (row-major, interleaved) plus the state the backward pass needs.
#[derive(Clone, Debug)]
pub struct Rendered<R> {
    pub width: u32,
    pub height: u32,
    pub num_objects: usize,
    /// `H·W·3`.
    pub rgb: Vec<R>,
    /// `H·W·3`, empty unless requested.
    pub mask: Vec<R>,
    /// `H·W·K`, empty unless requested (and empty when rendered as sums).
    pub objects: Vec<R>,
    /// The object map's sums against a label map ([`render_object_sums`]).
    pub object_sums: Option<ObjectSums<R>>,
    /// `H·W`: `1 − T_final`.
    pub alpha: Vec<R>,
    /// `H·W`: unnormalised depth `Σ w_i z_i`; see [`Rendered::expected_depth`].
    pub depth: Vec<R>,
    /// `H·W`: median depth (0 where nothing reached transmittance ½).
    pub median: Vec<R>,
    /// `H·W·3`: camera-space normal `Σ w_i n_i`.
    pub normal: Vec<R>,
    /// `H·W`: depth distortion.
    pub distortion: Vec<R>,
    /// Per surfel: binning radius in pixels, 0 when culled (densification statistics).
    pub radii: Vec<f32>,
    /// Number of (tile, surfel) pairs.
    pub num_pairs: usize,
    /// Number of (pixel, surfel) pairs inside the surfels' evaluation boxes: the work measure.
    pub pixel_pairs: usize,
    saved: Saved<R>,
}

#[derive(Clone, Debug)]
struct Saved<R> {
    cam: CamR<R>,
    settings: RenderSettings,
    sh_degree: u32,
    lay: Layout,
    projs: Vec<Proj<R>>,
    /// What the preprocess VJP needs beyond `projs` (same order).
    retained: Vec<Retained<R>>,
    probs: Vec<R>,
    bins: Bins,
    blocks: Vec<R>,
    iblocks: Vec<u32>,
    /// Per list entry (pair), the pixels of each of the 16 tile rows that the surfel blended.
    rows: Vec<u16>,
    labels: Option<Vec<u8>>,
    /// The tiles heaviest first ([`heaviest_first`]), the order both kernels take them in.
    tile_order: Vec<usize>,
}

/// Gradients of a scalar loss with respect to the rendered maps (row-major, `None` = zero).
#[derive(Clone, Debug, Default)]
pub struct OutputGrads<R> {
    pub rgb: Option<Vec<R>>,
    pub mask: Option<Vec<R>>,
    pub objects: Option<Vec<R>>,
    pub alpha: Option<Vec<R>>,
    /// Gradient with respect to the unnormalised depth `Σ w z` (see [`OutputGrads::add_expected_depth`]).
    pub depth: Option<Vec<R>>,
    pub median: Option<Vec<R>>,
    pub normal: Option<Vec<R>>,
    pub distortion: Option<Vec<R>>,
    /// Gradients of the object sums (renders from [`render_object_sums`] only).
    pub object_sums: Option<ObjectSumGrads<R>>,
}

/// Result of the backward pass.
#[derive(Clone, Debug)]
pub struct Gradients<R> {
    /// ∂L/∂(raw parameters), same layout as the input parameters.
    pub params: ParamsOf<R>,
    /// Per surfel: the 2DGS densification gradient `(∂L/∂T_{u,2}·z·W/2, ∂L/∂T_{v,2}·z·H/2)` (2DGS §3.4):
    /// the screen-space position gradient in NDC units, from the per-pixel kernel only.
    pub densify: Vec<[R; 2]>,
    /// `∂L/∂(ω, δ)` of the camera: a rigid motion `x_c ↦ exp([ω]×) x_c + δ` in the camera frame
    /// (see `preprocess::camera_vjp`), summed over the visible surfels in index order.
    pub camera: [R; 6],
}

impl<R: Real> Rendered<R> {
    /// Expected depth `D / α` (0 where α = 0).
    pub fn expected_depth(&self) -> Vec<R> {
        self.depth
            .iter()
            .zip(&self.alpha)
            .map(|(&d, &a)| if a > R::ZERO { d / a } else { R::ZERO })
            .collect()
    }

    /// A hash of every discrete decision of the forward pass (visible set, tile rectangles, last and
    /// median surfel per pixel). Finite-difference tests skip perturbations that change it.
    #[doc(hidden)]
    pub fn decision_signature(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        self.saved.iblocks.hash(&mut h);
        for p in &self.saved.projs {
            (p.index, p.tiles, p.clamped).hash(&mut h);
        }
        h.finish()
    }

    /// Visible surfel count.
    pub fn num_visible(&self) -> usize {
        self.saved.projs.len()
    }

    /// Stages 4–6: gradients of the loss with respect to every surfel parameter.
    pub fn backward<P: SurfelParams<R>>(&self, params: &P, grads: &OutputGrads<R>) -> Gradients<R> {
        let s = &self.saved;
        let n_pix = (self.width * self.height) as usize;
        let check = |v: &Option<Vec<R>>, ch: usize, name: &str| {
            if let Some(v) = v {
                assert_eq!(
                    v.len(),
                    n_pix * ch,
                    "gradient map `{name}` has the wrong size"
                );
            }
        };
        check(&grads.rgb, 3, "rgb");
        check(&grads.mask, 3, "mask");
        check(&grads.objects, self.num_objects, "objects");
        check(&grads.alpha, 1, "alpha");
        check(&grads.depth, 1, "depth");
        check(&grads.median, 1, "median");
        check(&grads.normal, 3, "normal");
        check(&grads.distortion, 1, "distortion");
        if let Some(g) = &grads.object_sums {
            assert!(
                s.labels.is_some(),
                "object-sum gradients need a render from render_object_sums"
            );
            assert!(
                g.total.len() == self.num_objects && g.on_label.len() == self.num_objects,
                "object-sum gradients have the wrong size"
            );
        }
        if s.settings.geometry == GeometryMaps::Skipped {
            assert!(
                grads.median.is_none() && grads.distortion.is_none(),
                "median or distortion gradients need a render with GeometryMaps::Rendered"
            );
        }
        let k = self.num_objects;
        // β_j = Σ_c π_{j,c} ∂L/∂P_c per visible surfel, for the object-sum backward.
        let betas: Vec<R> = grads.object_sums.as_ref().map_or_else(Vec::new, |g| {
            s.probs
                .par_chunks(k)
                .map(|pr| {
                    pr.iter()
                        .zip(&g.total)
                        .fold(R::ZERO, |b, (&p, &t)| b + p * t)
                })
                .collect()
        });
        let maps = GradMaps {
            rgb: grads.rgb.as_deref(),
            mask: grads.mask.as_deref(),
            objects: grads.objects.as_deref(),
            alpha: grads.alpha.as_deref(),
            depth: grads.depth.as_deref(),
            median: grads.median.as_deref(),
            normal: grads.normal.as_deref(),
            distortion: grads.distortion.as_deref(),
            object_sums: grads
                .object_sums
                .as_ref()
                .map(|g| (&g.total[..], &g.on_label[..], &betas[..])),
        };
        let stride = rec::stride(k);
        let bg = s.settings.background.map(R::from_f32);

        // Stage 4: per-tile backward into pair records.
        let mut pairs = par_zeros(s.bins.num_pairs() * stride);
        let chunks = split_by_tile(&mut pairs, &s.bins, stride);
        let block = s.lay.block();
        let tile_rows = TILE as usize;
        reorder(chunks, &s.tile_order)
            .into_par_iter()
            .with_max_len(1)
            .for_each(|(t, chunk)| {
                backward_tile(
                    t,
                    &s.bins,
                    &s.projs,
                    &s.probs,
                    &s.lay,
                    &s.cam,
                    bg,
                    &s.blocks[t * block..(t + 1) * block],
                    &s.iblocks
                        [t * INT_CHANNELS * TILE_PIXELS..(t + 1) * INT_CHANNELS * TILE_PIXELS],
                    &s.rows[s.bins.tile_start[t] as usize * tile_rows
                        ..s.bins.tile_start[t + 1] as usize * tile_rows],
                    s.labels.as_deref(),
                    &maps,
                    chunk,
                )
            });

        // Stages 5 and 6: reduce per surfel, then the preprocess VJP, in parallel over visible surfels.
        // One flat record per visible surfel: mean 3, log-scale 2, quat 4, opacity 1, densify 2, SH, mask
        // SH, object logits.
        let n = params.len();
        let sh_deg = s.sh_degree;
        let nc3 = trand_core::sh::num_coeffs(params.sh_degree()) * 3;
        let rs = 12 + 2 * nc3 + k;
        let mut recs = par_zeros(s.projs.len() * rs);
        let mut cams = vec![[R::ZERO; 6]; s.projs.len()];
        recs.par_chunks_mut(rs)
            .zip(cams.par_iter_mut())
            .zip(s.projs.par_iter())
            .enumerate()
            .with_min_len(64)
            .for_each(|(j, ((r, cam_grad), proj))| {
                let mut dprobs = [R::ZERO; MAX_OBJECTS];
                let dprobs = &mut dprobs[..k];
                let g = reduce_surfel(j, &s.bins, &pairs, k, dprobs);
                let probs = &s.probs[j * k..(j + 1) * k];
                let (geo, rest) = r.split_at_mut(12);
                let (sh, rest) = rest.split_at_mut(nc3);
                let (mask_sh, obj_logits) = rest.split_at_mut(nc3);
                let (mean, geo) = geo.split_at_mut(3);
                let (log_scale, geo) = geo.split_at_mut(2);
                let (quat, geo) = geo.split_at_mut(4);
                let (opacity, dens) = geo.split_at_mut(1);
                let mut slot = SurfelGradSlot {
                    mean: mean.try_into().expect("3"),
                    log_scale: log_scale.try_into().expect("2"),
                    quat: quat.try_into().expect("4"),
                    opacity_logit: &mut opacity[0],
                    sh,
                    mask_sh,
                    obj_logits,
                };
                *cam_grad = preprocess_backward_one(
                    params,
                    &s.cam,
                    sh_deg,
                    proj,
                    &s.retained[j],
                    probs,
                    &g,
                    dprobs,
                    &mut slot,
                );
                let z = proj.t_w[2];
                let half = R::from_f64(0.5);
                dens[0] = g.t[2] * z * R::from_f64(s.cam.width as f64) * half;
                dens[1] = g.t[5] * z * R::from_f64(s.cam.height as f64) * half;
            });
        // The parameter layout, filled in parallel over surfels from the visible surfels' records (zero
        // for culled surfels).
        let mut record_of = vec![u32::MAX; n];
        for (j, proj) in s.projs.iter().enumerate() {
            record_of[proj.index as usize] = j as u32;
        }
        let mut out = ParamsOf::<R>::zeros(n, params.sh_degree(), k);
        let mut densify = par_zeros(n);
        out.means
            .par_iter_mut()
            .zip(out.log_scales.par_iter_mut())
            .zip(out.quats.par_iter_mut())
            .zip(out.opacity_logits.par_iter_mut())
            .zip(out.sh.par_chunks_mut(nc3.max(1)))
            .zip(out.mask_sh.par_chunks_mut(nc3.max(1)))
            .zip(out.obj_logits.par_chunks_mut(k.max(1)))
            .zip(densify.par_iter_mut())
            .zip(record_of.par_iter())
            .with_min_len(256)
            .for_each(|((((((((m, ls), q), o), sh), msh), obj), dens), &j)| {
                if j == u32::MAX {
                    return;
                }
                let r = &recs[j as usize * rs..(j as usize + 1) * rs];
                m.copy_from_slice(&r[0..3]);
                ls.copy_from_slice(&r[3..5]);
                q.copy_from_slice(&r[5..9]);
                *o = r[9];
                *dens = [r[10], r[11]];
                sh.copy_from_slice(&r[12..12 + nc3]);
                msh.copy_from_slice(&r[12 + nc3..12 + 2 * nc3]);
                obj.copy_from_slice(&r[12 + 2 * nc3..]);
            });
        let camera = cams.iter().fold([R::ZERO; 6], |mut acc, c| {
            for (a, v) in acc.iter_mut().zip(c) {
                *a += *v;
            }
            acc
        });
        Gradients {
            params: out,
            densify,
            camera,
        }
    }
}

impl<R: Real> OutputGrads<R> {
    /// Adds the gradient `g` of a loss on the *expected* depth `D/α` (0 where α = 0): chains it into the
    /// unnormalised depth and alpha gradients.
    pub fn add_expected_depth(&mut self, out: &Rendered<R>, g: &[R]) {
        let n = out.alpha.len();
        let gd = self.depth.get_or_insert_with(|| vec![R::ZERO; n]);
        let ga = self.alpha.get_or_insert_with(|| vec![R::ZERO; n]);
        for i in 0..n {
            let a = out.alpha[i];
            if a > R::ZERO {
                gd[i] += g[i] / a;
                ga[i] -= g[i] * out.depth[i] / (a * a);
            }
        }
    }
}

/// The tiles, heaviest first: by list length (descending, ties by tile index).
///
/// Tiles differ in cost by two orders of magnitude (an object's silhouette against the empty table),
/// so handing them out in raster order let the last heavy tiles run on one thread while the other
/// idled. Taken heaviest first, one at a time, the threads finish within about one light tile of each
/// other (longest-processing-time-first list scheduling). Each tile still writes only its own outputs:
/// the order changes timing, never results.
fn heaviest_first(bins: &Bins) -> Vec<usize> {
    let mut order: Vec<usize> = (0..bins.num_tiles()).collect();
    order.sort_by_key(|&t| std::cmp::Reverse(bins.tile_start[t + 1] - bins.tile_start[t]));
    order
}

/// `items` (one per tile) reordered as `order`.
fn reorder<T>(items: Vec<T>, order: &[usize]) -> Vec<(usize, T)> {
    let mut slots: Vec<Option<T>> = items.into_iter().map(Some).collect();
    order
        .iter()
        .map(|&t| (t, slots[t].take().expect("a permutation")))
        .collect()
}

/// Splits a pair-indexed buffer (`per_pair` values per pair) into one slice per tile.
fn split_by_tile<'a, T>(buf: &'a mut [T], bins: &Bins, per_pair: usize) -> Vec<&'a mut [T]> {
    let mut chunks = Vec::with_capacity(bins.num_tiles());
    let mut rest = buf;
    for t in 0..bins.num_tiles() {
        let len = (bins.tile_start[t + 1] - bins.tile_start[t]) as usize * per_pair;
        let (a, b) = rest.split_at_mut(len);
        chunks.push(a);
        rest = b;
    }
    chunks
}

/// Renders surfels from a camera (stages 1–3: preprocess, binning, tile rasterization).
///
/// Non-finite or degenerate surfels (NaN parameters, zero quaternions, infinite scales) are culled, so
/// they never poison the image; an invalid camera is an error.
pub fn render<R: Real, P: SurfelParams<R>>(
    params: &P,
    camera: &Camera,
    settings: &RenderSettings,
) -> Result<Rendered<R>, RenderError> {
    render_impl(params, camera, settings, None)
}

/// [`render`] with the object channels reduced against `labels` (row-major, one object channel per
/// pixel) to the two sums per channel of [`ObjectSums`] instead of the K-channel map: what the Dice loss
/// needs, at a fraction of the map's cost ([`crate::labels`]). `settings.maps` must include the objects.
pub fn render_object_sums<R: Real, P: SurfelParams<R>>(
    params: &P,
    camera: &Camera,
    settings: &RenderSettings,
    labels: &[u8],
) -> Result<Rendered<R>, RenderError> {
    if !settings.maps.objects() {
        return Err(RenderError::SumsWithoutObjects);
    }
    let expected = camera.intrinsics.num_pixels();
    if labels.len() != expected {
        return Err(RenderError::LabelsSize {
            got: labels.len(),
            expected,
        });
    }
    let k = params.num_objects();
    if let Some(pixel) = labels.iter().position(|&l| l as usize >= k) {
        return Err(RenderError::Label {
            label: labels[pixel],
            pixel,
            num_objects: k,
        });
    }
    render_impl(params, camera, settings, Some(labels))
}

/// The chunks' elements in order, in one vector of exactly their total length.
fn concat<T>(chunks: Vec<Vec<T>>) -> Vec<T> {
    let mut out = Vec::with_capacity(chunks.iter().map(Vec::len).sum());
    for c in chunks {
        out.extend(c);
    }
    out
}

/// The rendered maps, row-major.
struct RowMajor<R> {
    rgb: Vec<R>,
    mask: Vec<R>,
    objects: Vec<R>,
    object_sums: Option<ObjectSums<R>>,
    alpha: Vec<R>,
    depth: Vec<R>,
    median: Vec<R>,
    normal: Vec<R>,
    distortion: Vec<R>,
}

/// Tile blocks (layout `lay`) → row-major maps; the maps the layout lacks come back empty.
fn row_major<R: Real>(blocks: &[R], lay: &Layout, cam: &CamR<R>) -> RowMajor<R> {
    let k = lay.num_objects;
    let block = lay.block();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let tiles_x = cam.tiles_x() as usize;
    // One slab of 16 image rows per tile row, in parallel: each tile's planes are read front to back
    // while they are contiguous (reading image row by image row instead jumped between forty blocks
    // for every row and took three times as long).
    let gather = |ch0: usize, nch: usize| -> Vec<R> {
        let mut out = par_zeros(w * h * nch);
        out.par_chunks_mut(w * TILE as usize * nch)
            .enumerate()
            .for_each(|(ty, slab)| {
                let rows = slab.len() / (w * nch);
                for tx in 0..tiles_x {
                    let x0 = tx * TILE as usize;
                    let nx = (w - x0).min(TILE as usize);
                    let b = &blocks[(ty * tiles_x + tx) * block..(ty * tiles_x + tx + 1) * block];
                    for ly in 0..rows {
                        let row = &mut slab[(ly * w + x0) * nch..(ly * w + x0 + nx) * nch];
                        let src =
                            |c: usize| &b[(ch0 + c) * TILE_PIXELS + ly * TILE as usize..][..nx];
                        match nch {
                            1 => row.copy_from_slice(src(0)),
                            3 => {
                                let (r, g, bl) = (src(0), src(1), src(2));
                                for (x, d) in row.chunks_exact_mut(3).enumerate() {
                                    d.copy_from_slice(&[r[x], g[x], bl[x]]);
                                }
                            }
                            _ => {
                                for (x, d) in row.chunks_exact_mut(nch).enumerate() {
                                    for (c, v) in d.iter_mut().enumerate() {
                                        *v = src(c)[x];
                                    }
                                }
                            }
                        }
                    }
                }
            });
        out
    };
    let rgb = gather(lay.rgb, 3);
    let mask = if lay.has_mask {
        gather(lay.mask, 3)
    } else {
        Vec::new()
    };
    let objects = if lay.has_objects {
        gather(lay.obj, k)
    } else {
        Vec::new()
    };
    let object_sums = lay.sums.map(|sp| {
        let mut sums = vec![R::ZERO; 2 * k];
        for b in blocks.chunks_exact(block) {
            for (s, &v) in sums.iter_mut().zip(&b[sp * TILE_PIXELS..]) {
                *s += v;
            }
        }
        let on_label = sums.split_off(k);
        ObjectSums {
            total: sums,
            on_label,
        }
    });
    let alpha = gather(lay.alpha, 1);
    let maybe = |ch0: usize, nch: usize| {
        if lay.has_geometry() {
            gather(ch0, nch)
        } else {
            Vec::new()
        }
    };
    let depth = maybe(lay.depth, 1);
    let median = maybe(lay.median, 1);
    let normal = maybe(lay.normal, 3);
    let distortion = maybe(lay.dist, 1);
    RowMajor {
        rgb,
        mask,
        objects,
        object_sums,
        alpha,
        depth,
        median,
        normal,
        distortion,
    }
}

fn render_impl<R: Real, P: SurfelParams<R>>(
    params: &P,
    camera: &Camera,
    settings: &RenderSettings,
    labels: Option<&[u8]>,
) -> Result<Rendered<R>, RenderError> {
    camera.validate()?;
    let k = params.num_objects();
    if k == 0 || k > MAX_OBJECTS {
        return Err(RenderError::Objects(k));
    }
    if !(settings.near.is_finite() && settings.near > 0.0) {
        return Err(RenderError::Near(settings.near));
    }
    let cam = CamR::<R>::new(camera, settings.near);
    let sh_degree = settings
        .sh_degree
        .map_or(params.sh_degree(), |d| d.min(params.sh_degree()));
    let n = params.len();

    // Stage 1: preprocess, in parallel, kept in surfel order. Each chunk of surfels fills vectors of
    // its own length (no growth), then they are joined once: rayon's `filter_map(..).unzip()` grew its
    // vectors by reallocation and appended them again, ~35 MB of copies per training step at 55 k
    // surfels (callgrind).
    let (proj_chunks, retained_chunks): (Vec<Vec<_>>, Vec<Vec<_>>) = (0..n
        .div_ceil(PREPROCESS_CHUNK))
        .into_par_iter()
        .map(|c| {
            let range = c * PREPROCESS_CHUNK..((c + 1) * PREPROCESS_CHUNK).min(n);
            let mut ps = Vec::with_capacity(range.len());
            let mut rs = Vec::with_capacity(range.len());
            for i in range {
                if let Some((p, r)) = preprocess_retained(params, i, &cam, sh_degree) {
                    ps.push(p);
                    rs.push(r);
                }
            }
            (ps, rs)
        })
        .unzip();
    let projs = concat(proj_chunks);
    // Stage 2, binning, is serial (a radix sort and a scatter); the visible surfels' object
    // probabilities (eight surfels at a time) and the joining of the retained values (for the
    // backward) need only the preprocess too, so the other threads do them meanwhile.
    let (bins, (probs, retained)) = rayon::join(
        || bin(&projs, cam.tiles_x(), cam.tiles_y()),
        || {
            rayon::join(
                || {
                    let mut probs = par_zeros(projs.len() * k);
                    probs
                        .par_chunks_mut(LANES * k)
                        .zip(projs.par_chunks(LANES))
                        .with_min_len(32)
                        .for_each(|(out, ps)| softmax_block(params, ps, k, out));
                    probs
                },
                || concat(retained_chunks),
            )
        },
    );
    let mut radii = vec![0.0f32; n];
    for p in &projs {
        radii[p.index as usize] = p.radius;
    }

    // Stage 3: per-tile rasterization into tile blocks.
    let lay = match labels {
        Some(_) => Layout::with_sums(k, settings.maps.mask(), settings.geometry),
        None => Layout::new(
            k,
            settings.maps.mask(),
            settings.maps.objects(),
            settings.geometry,
        ),
    };
    let block = lay.block();
    let n_tiles = bins.num_tiles();
    let mut blocks = par_zeros(n_tiles * block);
    let mut iblocks = par_zeros(n_tiles * INT_CHANNELS * TILE_PIXELS);
    let mut rows = par_zeros(bins.num_pairs() * TILE as usize);
    let row_chunks = split_by_tile(&mut rows, &bins, TILE as usize);
    let bg = settings.background.map(R::from_f32);
    let tiles: Vec<_> = blocks
        .chunks_mut(block)
        .zip(iblocks.chunks_mut(INT_CHANNELS * TILE_PIXELS))
        .zip(row_chunks)
        .collect();
    let tile_order = heaviest_first(&bins);
    reorder(tiles, &tile_order)
        .into_par_iter()
        .with_max_len(1)
        .for_each(|(t, ((b, ib), rw))| {
            raster_tile(t, &bins, &projs, &probs, &lay, &cam, bg, labels, b, ib, rw)
        });

    let RowMajor {
        rgb,
        mask,
        objects,
        object_sums,
        alpha,
        depth,
        median,
        normal,
        distortion,
    } = row_major(&blocks, &lay, &cam);
    let num_pairs = bins.num_pairs();
    let pixel_pairs = projs
        .par_iter()
        .map(|p| ((p.bbox[2] - p.bbox[0] + 1) * (p.bbox[3] - p.bbox[1] + 1)) as usize)
        .sum();
    Ok(Rendered {
        width: cam.width,
        height: cam.height,
        num_objects: k,
        rgb,
        mask,
        objects,
        object_sums,
        alpha,
        depth,
        median,
        normal,
        distortion,
        radii,
        num_pairs,
        pixel_pairs,
        saved: Saved {
            cam,
            settings: *settings,
            sh_degree,
            lay,
            projs,
            retained,
            probs,
            bins,
            blocks,
            iblocks,
            rows,
            labels: labels.map(<[u8]>::to_vec),
            tile_order,
        },
    })
}
