//! One optimisation loop, shared by the t = 0 reconstruction and the t = 1 refinement.
//!
//! Per iteration `it` (1-based, official-code notes §2.1–2.2):
//! 1. learning rates for `it`; a training view drawn from a shuffled stack (each view once per epoch);
//! 2. render RGB, mask colour, object map and geometry;
//! 3. losses: `w_rgb·[(1−λ)L1 + λ(1−SSIM)]` on RGB, the same on the mask image, Dice on the object map,
//!    optionally the 2DGS normal-consistency and distortion terms; the object-aware 3D loss on the
//!    positions;
//! 4. backward through the rasterizer, densification statistics;
//! 5. every `interval` iterations densify and prune, every `reset` iterations reset opacities; as in the
//!    reference, parameters replaced by densification or reset are not stepped in that iteration;
//!    otherwise an Adam step. The last iteration takes no step (the reference saves before it).

use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;
use trand_core::Surfels;
use trand_render::{
    GeometryMaps, Maps, ObjectSumGrads, OutputGrads, RenderSettings, render, render_object_sums,
};
use trand_train::config::TrainConfig;
use trand_train::losses::{
    band, dice::dice_from_sums, geometry, object::object_aware_loss, photometric::photometric,
};
use trand_train::{Adam, DensifyStats, PoseCorrections, densify_and_prune, reset_opacity};

use crate::Result;
use crate::targets::{CoarseViews, Supervision, TrainView};

/// What one iteration did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StepReport {
    pub iteration: u32,
    pub view: usize,
    pub loss: f32,
    pub rgb: f32,
    pub mask: f32,
    pub dice: f32,
    pub object: f32,
    pub num_surfels: usize,
    pub densified: bool,
}

/// Optimiser state over a set of surfels and training views.
pub struct Trainer<'a> {
    pub surfels: Surfels,
    pub adam: Adam,
    pub stats: DensifyStats,
    pub cfg: TrainConfig,
    pub views: &'a [TrainView],
    /// The same views at the levels of `cfg.resolution` coarser than the training resolution.
    coarse: &'a [CoarseViews],
    /// Scene extent (1.1 × the largest camera distance from the cameras' mean), for densification.
    pub extent: f32,
    /// Extent that scales the position learning rate.
    pub lr_extent: f64,
    pub supervision: Supervision,
    /// Each training view's pose correction (`cfg.pose`); zero while the poses are fixed.
    pub poses: PoseCorrections,
    rng: Pcg64,
    stack: Vec<usize>,
}

/// `1.1 · max_i |C_i − mean(C)|` over the training cameras (2DGS `getNerfppNorm`).
pub fn camera_extent(cameras: &[trand_core::Camera]) -> f32 {
    let centres: Vec<glam::DVec3> = cameras.iter().map(|c| c.center()).collect();
    let mean = centres.iter().copied().sum::<glam::DVec3>() / centres.len().max(1) as f64;
    (1.1 * centres
        .iter()
        .map(|c| (*c - mean).length())
        .fold(0.0, f64::max)) as f32
}

impl<'a> Trainer<'a> {
    pub fn new(
        surfels: Surfels,
        cfg: TrainConfig,
        views: &'a [TrainView],
        extent: f32,
        supervision: Supervision,
    ) -> Self {
        let adam = Adam::new(&surfels, cfg.adam);
        let stats = DensifyStats::new(surfels.len());
        // Salted with "trand" in ASCII so the view order differs from the initialisation's stream.
        let rng = Pcg64::seed_from_u64(cfg.seed ^ 0x0074_7261_6e64);
        Self {
            surfels,
            adam,
            stats,
            lr_extent: extent as f64,
            extent,
            cfg,
            views,
            coarse: &[],
            supervision,
            poses: PoseCorrections::new(views.len()),
            rng,
            stack: Vec::new(),
        }
    }

    /// Gives the downsampled views the coarse levels of `cfg.resolution` train on. An iteration whose
    /// level has no views here (it is not coarser than the training resolution) trains on `views`.
    pub fn with_coarse(mut self, coarse: &'a [CoarseViews]) -> Self {
        self.coarse = coarse;
        self
    }

    /// View `vi` at the resolution iteration `it` trains on.
    fn view_at(&self, it: u32, vi: usize) -> &'a TrainView {
        let done = it.saturating_sub(self.cfg.start_iteration);
        let f = self.cfg.resolution.factor_at(done, self.cfg.iterations);
        match self.coarse.iter().find(|c| c.factor == f) {
            Some(c) => &c.views[vi],
            None => &self.views[vi],
        }
    }

    /// The view sampler's state: the random stream and the views left in the current epoch.
    pub fn sampler(&self) -> (&Pcg64, &[usize]) {
        (&self.rng, &self.stack)
    }

    /// Restores the optimiser, the densification statistics and the view sampler of a checkpoint,
    /// so that the next [`Trainer::step`] is the one an uninterrupted run would take. The caller
    /// has checked the shapes ([`crate::checkpoint`]).
    pub fn restore(&mut self, adam: Adam, stats: DensifyStats, rng: Pcg64, stack: Vec<usize>) {
        self.adam = adam;
        self.stats = stats;
        self.rng = rng;
        self.stack = stack;
    }

    fn next_view(&mut self) -> usize {
        if self.stack.is_empty() {
            self.stack = (0..self.views.len()).collect();
        }
        let i = self.rng.random_range(0..self.stack.len());
        self.stack.swap_remove(i)
    }

    /// Runs iteration `it`; `last` marks the final iteration (no optimiser step, no densification).
    pub fn step(&mut self, it: u32, last: bool) -> Result<StepReport> {
        let vi = self.next_view();
        let view = self.view_at(it, vi);
        let camera = self.poses.camera(vi, &view.camera);
        let cfg = &self.cfg;
        let k = self.surfels.num_objects;
        let object_aware = self.supervision == Supervision::ObjectAware;
        let geo = &cfg.geometry_loss;
        let geometry_on =
            geo.active.is_active(it) && (geo.lambda_normal > 0.0 || geo.lambda_dist > 0.0);
        let settings = RenderSettings {
            background: cfg.background,
            near: cfg.near as f64,
            sh_degree: Some(cfg.sh_degree),
            maps: if object_aware { Maps::All } else { Maps::Rgb },
            geometry: if geometry_on {
                GeometryMaps::Rendered
            } else {
                GeometryMaps::Skipped
            },
        };
        // The Dice loss reads the object map only through two sums per channel: rendered against the
        // target labels, without the K-channel map (trand_render::labels). The object-aware 3D loss
        // depends on the positions and logits alone, so it runs alongside the render: its per-object
        // work (five or so objects on two cores) leaves gaps that the render's tiles fill.
        let object_loss_on = object_aware && !last && cfg.object_loss.active.is_active(it);
        let (out, ol) = rayon::join(
            || {
                if object_aware {
                    render_object_sums::<f32, _>(&self.surfels, &camera, &settings, &view.labels)
                } else {
                    render::<f32, _>(&self.surfels, &camera, &settings)
                }
            },
            || {
                object_loss_on.then(|| {
                    object_aware_loss(
                        &self.surfels.means,
                        &self.surfels.obj_logits,
                        k,
                        &cfg.object_loss.params,
                    )
                })
            },
        );
        let out = out?;
        let (w, h) = (view.width, view.height);
        let il = &cfg.image_loss;
        let lam = il.lambda_dssim as f32;
        let mut g = OutputGrads::<f32>::default();
        let mut rep = StepReport {
            iteration: it,
            view: vi,
            ..Default::default()
        };

        let rgb_w = if object_aware { il.rgb as f32 } else { 1.0 };
        // The two photometric losses are independent: run together, each fills the other's gaps.
        let (p, pm) = rayon::join(
            || photometric(&out.rgb, &view.rgb, w, h, 3, lam),
            || object_aware.then(|| photometric(&out.mask, &view.mask, w, h, 3, lam)),
        );
        // A photometric gradient, weighted; a segmenter's boundary is a few pixels off, so the
        // background band (when there is one) is not fitted (losses::band).
        let weighted = |grad: Vec<f32>, weight: f32| {
            let mut grad: Vec<f32> = grad.into_iter().map(|v| v * weight).collect();
            if !view.band.is_empty() {
                band::clear_band(&mut grad, &view.band, 3);
            }
            grad
        };
        rep.rgb = p.value;
        g.rgb = Some(weighted(p.grad, rgb_w));
        let mut loss = rgb_w * p.value;
        if let Some(pm) = pm {
            rep.mask = pm.value;
            loss += il.mask as f32 * pm.value;
            g.mask = Some(weighted(pm.grad, il.mask as f32));
            let sums = out.object_sums.as_ref().expect("rendered with object sums");
            let (dv, g_total, g_on_label) =
                dice_from_sums(&sums.total, &sums.on_label, &view.label_counts);
            rep.dice = dv;
            loss += il.dice as f32 * dv;
            let scale = |v: Vec<f32>| v.into_iter().map(|x| x * il.dice as f32).collect();
            g.object_sums = Some(ObjectSumGrads {
                total: scale(g_total),
                on_label: scale(g_on_label),
            });
        }
        if geometry_on {
            let n = w * h;
            if geo.lambda_normal > 0.0 {
                let normals: Vec<[f32; 3]> = out
                    .normal
                    .chunks_exact(3)
                    .map(|c| [c[0], c[1], c[2]])
                    .collect();
                let pin = geometry::Pinhole::from_intrinsics(&view.camera.intrinsics);
                let nc =
                    geometry::normal_consistency(&normals, &out.median, &out.alpha, &pin, w, h);
                let lam_n = geo.lambda_normal as f32;
                loss += lam_n * nc.value;
                g.normal = Some(
                    nc.grad_normal
                        .iter()
                        .flat_map(|v| v.map(|x| x * lam_n))
                        .collect(),
                );
                g.median = Some(nc.grad_depth.iter().map(|v| v * lam_n).collect());
            }
            if geo.lambda_dist > 0.0 {
                let (dv, dgrad) = geometry::distortion(&out.distortion);
                let lam_d = geo.lambda_dist as f32;
                loss += lam_d * dv;
                g.distortion = Some(vec![dgrad * lam_d; n]);
            }
        }
        rep.loss = loss;
        if last {
            rep.num_surfels = self.surfels.len();
            return Ok(rep);
        }

        let grads = out.backward(&self.surfels, &g);
        let last_it = cfg.start_iteration + cfg.iterations;
        if let Some(rates) = cfg.pose.rates(it, last_it) {
            let gc = grads.camera.map(f64::from);
            self.poses.step(vi, &view.camera, gc, rates);
        }
        let mut gs = grads.params.into_surfels(&self.surfels);
        if let Some(ol) = ol {
            let wgt = cfg.object_loss.weight as f32;
            rep.object = ol.value;
            rep.loss += wgt * ol.value;
            for (gm, go) in gs.means.iter_mut().zip(&ol.grad) {
                for a in 0..3 {
                    gm[a] += wgt * go[a];
                }
            }
        }
        let d = &cfg.densify;
        if it < d.until_iteration {
            self.stats.add(&out.radii, &grads.densify);
        }
        let densify = d.densify_now(it);
        let reset = d.reset_opacity_now(it);
        if densify {
            densify_and_prune(
                &mut self.surfels,
                &mut self.adam,
                &mut self.stats,
                d,
                self.extent,
                d.size_threshold(it),
                &mut self.rng,
            );
            rep.densified = true;
        }
        if reset {
            reset_opacity(&mut self.surfels, &mut self.adam, d.opacity_reset_value);
        }
        if !densify && !reset {
            let lr = cfg.learning_rates(it, self.lr_extent);
            self.adam.step(&mut self.surfels, &gs, &lr);
        }
        rep.num_surfels = self.surfels.len();
        Ok(rep)
    }
}
