//! Stage 1: per-surfel preprocess (forward) and its vector-Jacobian product (backward).
//!
//! For surfel `i` with mean `μ`, scales `s_u, s_v`, rotation columns `t_u, t_v, t_w` (2DGS eq. 1–5):
//!
//! * **Ray-splat transform** `T = K · [s_u R_cw t_u | s_v R_cw t_v | R_cw μ + t_cw]` (3×3, rows
//!   `T_u, T_v, T_w`). It maps splat-plane homogeneous coordinates `(u, v, 1)` to screen homogeneous
//!   coordinates `(x·z, y·z, z)`; `T_w · (u, v, 1)` is the camera depth of the disk point.
//! * **3σ bounding box** from the screen-space dual conic of the contour `u² + v² = 9`:
//!   `t = (9, 9, −1)`, `d = Σ t_k T_{w,k}²`, `f = t/d`, centre `p_x = Σ f_k T_{u,k} T_{w,k}` and half-width
//!   `h_x = √(p_x² − Σ f_k T_{u,k}²)` (likewise y). The centre is also the centre of the screen-space
//!   low-pass filter. When `d ≥ 0` the contour reaches the camera plane and the box is unbounded: such a
//!   surfel (a large disk grazing the camera) is culled, where the CUDA reference silently bins a
//!   meaningless box.
//! * **Binning radius** `r = ⌈max(h_x, h_y, 3·√2/2)⌉` and tile rectangle as the reference's `getRect`.
//! * **Evaluation box**: pixels where `α = o·G ≥ 1/255` satisfy `ρ ≤ 2 ln(255 o)`. The box of that
//!   region (object-space ellipse ∪ filter disc, plus one pixel of margin) bounds the pixels the
//!   rasterizer evaluates. It gives the same image as evaluating every pixel of every binned tile (what
//!   the reference does) at a fraction of the cost.
//! * **Normal** `n = R_cw t_w`, flipped to face the camera (`−p_view · n > 0`); `cos = 0` culls.
//! * **Colours**: SH evaluated along `normalize(μ − C)`, `+½`, clamped at 0 (clamped channels get no
//!   gradient); the same for the mask colours; **object probabilities** = softmax of the logits.

use trand_core::{
    Real,
    math::{normalize_vjp, quat_to_rotmat, rotmat_vjp, sigmoid, softmax_numerators8, softmax_vjp},
    sh::{basis, basis_jacobian, num_coeffs},
};

use crate::camera::CamR;
use crate::constants::{FILTER_INV_SQUARE, FILTER_RADIUS, MIN_ALPHA, SIGMA_CUTOFF, TILE};
use crate::params::{ParamsOf, SurfelParams};
use crate::vec3::{cross, dot};

/// A visible surfel after preprocess: everything the per-pixel kernels read.
#[derive(Clone, Copy, Debug)]
pub struct Proj<R> {
    /// Index of the surfel in the parameter arrays.
    pub index: u32,
    pub t_u: [R; 3],
    pub t_v: [R; 3],
    pub t_w: [R; 3],
    /// 3σ bounding-box centre in pixels (low-pass filter centre).
    pub center: [R; 2],
    /// Camera-space normal facing the camera.
    pub normal: [R; 3],
    pub opacity: R,
    pub rgb: [R; 3],
    pub mask: [R; 3],
    /// Camera z of the mean: the depth-sort key.
    pub depth: R,
    /// Binning radius in pixels (the reference's `radii`, used by densification).
    pub radius: f32,
    /// Tile rectangle `[x0, y0, x1, y1)`: the tiles of the 3σ box that the evaluation box `bbox` touches.
    pub tiles: [u32; 4],
    /// Pixel evaluation box `[x0, y0, x1, y1]`, inclusive.
    pub bbox: [i32; 4],
    /// Bits 0–2: RGB channel clamped at 0; bits 3–5: mask channel clamped.
    pub clamped: u8,
    /// +1 or −1: the sign applied to `R_cw t_w` to face the camera.
    pub normal_sign: R,
    /// Where on each pixel row `α ≥ 1/255` is possible (see [`RowCut`]).
    pub cut: RowCut,
}

/// The region of the image where a surfel can reach `α = o·G ≥ 1/255`, i.e. `ρ ≤ c = 2 ln(255 o)`,
/// in a form that gives each pixel row its columns cheaply ([`crate::intersect::row_columns`]).
///
/// * Object-space ellipse `u² + v² ≤ c`: with `h = T·(u, v, 1) = z·(x, y, 1)`, it is the image conic
///   `(x, y, 1) Q (x, y, 1)ᵀ ≤ 0`, `Q ∝ T⁻ᵀ diag(1, 1, −c) T⁻¹`. Using `adj T` for `T⁻¹` (a positive
///   factor `det²` apart), `Q_ij = c_i·c_j` weighted by `(1, 1, −c)`, with `c_0 = T_v × T_w`,
///   `c_1 = T_w × T_u`, `c_2 = T_u × T_v` the columns of `adj T`. On row `y` the conic's chord is
///   `x = −(q01 y + q02)/q00 ± √((q01 y + q02)² − q00 (q11 y² + 2 q12 y + q22))/q00`; in the frame
///   centred on the ellipse (centre `(x_c, y_0)`, `dy = y − y_0`) that is
///   `x = x_c − m·dy ± √(a·dy² + d)`: with `disc(y)/q00² = a y² + 2 b y + c'`, `a = (q01² − q00 q11)/q00²`
///   (< 0 for an ellipse), `b = (q01 q02 − q00 q12)/q00²`, `c' = (q02² − q00 q22)/q00²`, it is
///   `y_0 = −b/a`, `d = c' − b²/a`, `m = q01/q00`, `x_c = −(q01 y_0 + q02)/q00`; all computed here in
///   f64 and stored in f32. The centred form has no cancellation, so the kernels evaluate it in f32
///   without divisions.
///   `None` when the conic is not an ellipse (`q00 ≤ 0` or `a ≥ 0`: nearly edge-on surfels whose
///   region is open) or `T` is singular: no cut, the whole box is evaluated.
/// * Filter disc `2|c − x|² ≤ c`: radius `√(c/2)` around the filter centre (rows within it keep
///   the disc's bounding columns).
#[derive(Clone, Copy, Debug)]
pub struct RowCut {
    /// `(x_c, m, y_0, a, d)` of the chord formula above.
    pub ellipse: Option<[f32; 5]>,
    pub center: [f32; 2],
    pub filter_radius: f32,
}

impl RowCut {
    fn new<R: Real>(t_u: [R; 3], t_v: [R; 3], t_w: [R; 3], center: [R; 2], c: f64) -> Self {
        let f = |v: [R; 3]| v.map(R::to_f64);
        let (tu, tv, tw) = (f(t_u), f(t_v), f(t_w));
        let cols = [cross(&tv, &tw), cross(&tw, &tu), cross(&tu, &tv)];
        let det = tu[0] * cols[0][0] + tu[1] * cols[0][1] + tu[2] * cols[0][2];
        let q = |i: usize, j: usize| {
            cols[i][0] * cols[j][0] + cols[i][1] * cols[j][1] - c * cols[i][2] * cols[j][2]
        };
        let [q00, q01, q02, q11, q12, q22] = [q(0, 0), q(0, 1), q(0, 2), q(1, 1), q(1, 2), q(2, 2)];
        // disc(y)/q00² = A y² + 2 B y + C = a (y − y0)² + d.
        let inv = 1.0 / (q00 * q00);
        let a = (q01 * q01 - q00 * q11) * inv;
        let b = (q01 * q02 - q00 * q12) * inv;
        let cc = (q02 * q02 - q00 * q22) * inv;
        let y0 = -b / a;
        let d = cc - b * b / a;
        let m = q01 / q00;
        let xc = -(q01 * y0 + q02) / q00;
        let ellipse = [xc, m, y0, a, d];
        let usable = det != 0.0
            && q00 > 0.0
            && a < 0.0
            && ellipse.iter().all(|v| v.is_finite() && v.abs() < 1e12);
        Self {
            ellipse: usable.then(|| ellipse.map(|v| v as f32)),
            center: [center[0].to_f64() as f32, center[1].to_f64() as f32],
            filter_radius: (c.max(0.0) / FILTER_INV_SQUARE).sqrt() as f32,
        }
    }
}

/// Upstream gradient of one surfel's preprocess outputs (reduced over all its pixels).
#[derive(Clone, Copy, Debug, Default)]
pub struct ProjGrad<R> {
    /// ∂L/∂T, rows `T_u, T_v, T_w`.
    pub t: [R; 9],
    /// ∂L/∂(filter centre).
    pub center: [R; 2],
    pub rgb: [R; 3],
    pub mask: [R; 3],
    pub normal: [R; 3],
    pub opacity: R,
}

/// Transform rows and derived quantities shared by forward and backward.
struct Geometry<R> {
    rot: [[R; 3]; 3],
    qn: [R; 4],
    scale: [R; 2],
    pv: [R; 3],
    t_u: [R; 3],
    t_v: [R; 3],
    t_w: [R; 3],
}

// `!(a > b)` on purpose: NaN fails the test and is culled.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
fn geometry<R: Real, P: SurfelParams<R>>(p: &P, i: usize, cam: &CamR<R>) -> Option<Geometry<R>> {
    let mean = p.mean(i);
    let ls = p.log_scale(i);
    if !mean.iter().chain(&ls).all(|v| v.is_finite()) {
        return None;
    }
    let (rot, qn) = quat_to_rotmat(p.quat(i))?;
    let scale = [ls[0].exp(), ls[1].exp()];
    if !(scale[0].is_finite() && scale[1].is_finite()) {
        return None;
    }
    let tu = [rot[0][0], rot[1][0], rot[2][0]];
    let tv = [rot[0][1], rot[1][1], rot[2][1]];
    let ru = cam.rotate(tu);
    let rv = cam.rotate(tv);
    let cu = ru.map(|v| v * scale[0]);
    let cv = rv.map(|v| v * scale[1]);
    let rm = cam.rotate(mean);
    let pv = [
        rm[0] + cam.trans[0],
        rm[1] + cam.trans[1],
        rm[2] + cam.trans[2],
    ];
    let t_u = [
        cam.fx * cu[0] + cam.cx * cu[2],
        cam.fx * cv[0] + cam.cx * cv[2],
        cam.fx * pv[0] + cam.cx * pv[2],
    ];
    let t_v = [
        cam.fy * cu[1] + cam.cy * cu[2],
        cam.fy * cv[1] + cam.cy * cv[2],
        cam.fy * pv[1] + cam.cy * pv[2],
    ];
    let t_w = [cu[2], cv[2], pv[2]];
    Some(Geometry {
        rot,
        qn,
        scale,
        pv,
        t_u,
        t_v,
        t_w,
    })
}

/// Screen-space box of the contour `u² + v² = c2`: `(centre, half-extent)`, `None` when the contour is
/// not entirely in front of the camera.
#[inline]
// `!(a > b)` on purpose: NaN fails the test and is culled.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
fn conic_box<R: Real>(t_u: [R; 3], t_v: [R; 3], t_w: [R; 3], c2: R) -> Option<([R; 2], [R; 2], R)> {
    let t = [c2, c2, -R::ONE];
    let d = t[0] * t_w[0] * t_w[0] + t[1] * t_w[1] * t_w[1] + t[2] * t_w[2] * t_w[2];
    if !(d < R::ZERO) {
        return None;
    }
    let f = [t[0] / d, t[1] / d, t[2] / d];
    let px = f[0] * t_u[0] * t_w[0] + f[1] * t_u[1] * t_w[1] + f[2] * t_u[2] * t_w[2];
    let py = f[0] * t_v[0] * t_w[0] + f[1] * t_v[1] * t_w[1] + f[2] * t_v[2] * t_w[2];
    let qx = f[0] * t_u[0] * t_u[0] + f[1] * t_u[1] * t_u[1] + f[2] * t_u[2] * t_u[2];
    let qy = f[0] * t_v[0] * t_v[0] + f[1] * t_v[1] * t_v[1] + f[2] * t_v[2] * t_v[2];
    Some(([px, py], [px * px - qx, py * py - qy], d))
}

/// SH colour along `dir`, `+½`, clamped at zero; returns the colour and the clamp bits.
#[inline]
fn sh_colour<R: Real>(coeff: impl Fn(usize, usize) -> R, nc: usize, y: &[R; 16]) -> ([R; 3], u8) {
    let mut c = [R::from_f64(0.5); 3];
    let mut clamped = 0u8;
    for (ch, cc) in c.iter_mut().enumerate() {
        for (k, yk) in y.iter().enumerate().take(nc) {
            *cc += coeff(k, ch) * *yk;
        }
        if *cc < R::ZERO {
            *cc = R::ZERO;
            clamped |= 1 << ch;
        }
    }
    (c, clamped)
}

/// Unit view direction `normalize(μ − C)` and the distance `|μ − C|`.
#[inline]
fn view_dir<R: Real>(mean: [R; 3], cam: &CamR<R>) -> ([R; 3], R) {
    let d = [
        mean[0] - cam.center[0],
        mean[1] - cam.center[1],
        mean[2] - cam.center[2],
    ];
    let n = dot(d, d).sqrt();
    if n > R::ZERO {
        (d.map(|v| v / n), n)
    } else {
        ([R::ZERO, R::ZERO, R::ONE], R::ONE)
    }
}

/// What the preprocess VJP needs beyond [`Proj`], kept from the forward pass so that the backward does
/// not redo the rotation matrix, the scales' exponentials, the conic and the view direction (~200
/// instructions per visible surfel).
#[derive(Clone, Copy, Debug)]
pub struct Retained<R> {
    /// Rotation matrix of the normalised quaternion `qn`.
    pub rot: [[R; 3]; 3],
    pub qn: [R; 4],
    /// `exp` of the log-scales.
    pub scale: [R; 2],
    /// `d` of the 3σ conic box (`conic_box`): the denominator of the filter centre.
    pub conic_d: R,
    /// View direction `normalize(μ − C)` and the distance `|μ − C|`.
    pub dir: [R; 3],
    pub dist: R,
}

/// Forward preprocess of surfel `i`: `None` when the surfel is culled (behind the near plane,
/// off-screen, degenerate or non-finite, object logits included). Its object probabilities come from
/// [`softmax_block`].
pub fn preprocess_one<R: Real, P: SurfelParams<R>>(
    p: &P,
    i: usize,
    cam: &CamR<R>,
    sh_degree: u32,
) -> Option<Proj<R>> {
    preprocess_retained(p, i, cam, sh_degree).map(|(proj, _)| proj)
}

/// [`preprocess_one`] with what its backward needs ([`Retained`]).
// `!(a > b)` on purpose: NaN fails the test and is culled.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
pub fn preprocess_retained<R: Real, P: SurfelParams<R>>(
    p: &P,
    i: usize,
    cam: &CamR<R>,
    sh_degree: u32,
) -> Option<(Proj<R>, Retained<R>)> {
    let g = geometry(p, i, cam)?;
    if !(g.pv[2] > cam.near) {
        return None;
    }
    let ol = p.opacity_logit(i);
    if !ol.is_finite() {
        return None;
    }
    let opacity = sigmoid(ol);
    if opacity < R::from_f64(MIN_ALPHA) {
        return None;
    }
    // Normal facing the camera.
    let n = cam.rotate([g.rot[0][2], g.rot[1][2], g.rot[2][2]]);
    let cos = -dot(g.pv, n);
    if cos == R::ZERO {
        return None;
    }
    let normal_sign = if cos < R::ZERO { -R::ONE } else { R::ONE };
    let normal = n.map(|v| v * normal_sign);

    // 3σ box: binning and filter centre.
    let c2 = R::from_f64(SIGMA_CUTOFF * SIGMA_CUTOFF);
    let (center, h2, conic_d) = conic_box(g.t_u, g.t_v, g.t_w, c2)?;
    let floor = R::from_f64(1e-4);
    let (hx, hy) = (h2[0].max(floor).sqrt(), h2[1].max(floor).sqrt());
    let radius = hx.max(hy).max(R::from_f64(FILTER_RADIUS)).ceil();
    if !(radius.is_finite() && center[0].is_finite() && center[1].is_finite()) {
        return None;
    }
    let (cx, cy, r) = (center[0].to_f64(), center[1].to_f64(), radius.to_f64());
    let grid = [cam.tiles_x() as i64, cam.tiles_y() as i64];
    let tile = TILE as f64;
    let clamp_i = |v: f64, hi: i64| (v as i64).clamp(0, hi) as u32;
    let tiles = [
        clamp_i((cx - r) / tile, grid[0]),
        clamp_i((cy - r) / tile, grid[1]),
        clamp_i((cx + r + tile - 1.0) / tile, grid[0]),
        clamp_i((cy + r + tile - 1.0) / tile, grid[1]),
    ];
    if tiles[0] >= tiles[2] || tiles[1] >= tiles[3] {
        return None;
    }

    // Evaluation box: where o·G can reach 1/255.
    let r2 = 2.0 * (opacity.to_f64() / MIN_ALPHA).ln();
    let rf = (r2 / FILTER_INV_SQUARE).sqrt();
    let mut bb = [cx - rf, cy - rf, cx + rf, cy + rf];
    match conic_box(g.t_u, g.t_v, g.t_w, R::from_f64(r2)) {
        Some((c, h2, _)) => {
            let (hx, hy) = (
                h2[0].max(R::ZERO).sqrt().to_f64(),
                h2[1].max(R::ZERO).sqrt().to_f64(),
            );
            let (ex, ey) = (c[0].to_f64(), c[1].to_f64());
            bb = [
                bb[0].min(ex - hx),
                bb[1].min(ey - hy),
                bb[2].max(ex + hx),
                bb[3].max(ey + hy),
            ];
        }
        None => {
            bb = [
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::INFINITY,
            ]
        }
    }
    let t = TILE as i64;
    let bbox = [
        ((bb[0].floor() - 1.0).max((tiles[0] as i64 * t) as f64)) as i32,
        ((bb[1].floor() - 1.0).max((tiles[1] as i64 * t) as f64)) as i32,
        ((bb[2].ceil() + 1.0).min((tiles[2] as i64 * t - 1).min(cam.width as i64 - 1) as f64))
            as i32,
        ((bb[3].ceil() + 1.0).min((tiles[3] as i64 * t - 1).min(cam.height as i64 - 1) as f64))
            as i32,
    ];
    if bbox[0] > bbox[2] || bbox[1] > bbox[3] {
        return None;
    }
    // Bin only into the tiles the evaluation box touches: in the others every pixel fails the α gate,
    // so their pairs would change no output or gradient, only cost binning, sorting and kernel work.
    // For the low opacities of transparent objects the box is often much smaller than the 3σ box
    // (`√(2 ln(255 o))` instead of 3 standard deviations), which still sets `radius` and visibility.
    let t32 = TILE as i32;
    let tiles = [
        (bbox[0] / t32) as u32,
        (bbox[1] / t32) as u32,
        (bbox[2] / t32 + 1) as u32,
        (bbox[3] / t32 + 1) as u32,
    ];

    // Colours along the view direction.
    let nc = num_coeffs(sh_degree);
    let (dir, dist) = view_dir(p.mean(i), cam);
    let mut y = [R::ZERO; 16];
    basis(sh_degree, dir, &mut y);
    let (rgb, c1) = sh_colour(|k, ch| p.sh(i, k, ch), nc, &y);
    let (mask, c2) = sh_colour(|k, ch| p.mask_sh(i, k, ch), nc, &y);
    // Checked here: the fast softmax would turn a NaN or infinite logit into finite probabilities.
    if !(0..p.num_objects()).all(|j| p.obj_logit(i, j).is_finite()) {
        return None;
    }
    if !rgb.iter().chain(&mask).all(|v| v.is_finite()) {
        return None;
    }
    let proj = Proj {
        index: i as u32,
        t_u: g.t_u,
        t_v: g.t_v,
        t_w: g.t_w,
        center,
        normal,
        opacity,
        rgb,
        mask,
        depth: g.pv[2],
        radius: radius.to_f32(),
        tiles,
        bbox,
        clamped: c1 | (c2 << 3),
        normal_sign,
        cut: RowCut::new(g.t_u, g.t_v, g.t_w, center, r2),
    };
    let retained = Retained {
        rot: g.rot,
        qn: g.qn,
        scale: g.scale,
        conic_d,
        dir,
        dist,
    };
    Some((proj, retained))
}

/// Backward of [`preprocess_one`]: accumulates ∂L/∂(raw parameters) of surfel `proj.index` into `out`
/// (which must hold that surfel's slot; all other slots are untouched) and returns this surfel's share
/// of the camera gradient ([`camera_vjp`]).
#[allow(clippy::too_many_arguments)]
pub fn preprocess_backward_one<R: Real, P: SurfelParams<R>>(
    p: &P,
    cam: &CamR<R>,
    sh_degree: u32,
    proj: &Proj<R>,
    geo: &Retained<R>,
    probs: &[R],
    g: &ProjGrad<R>,
    dprobs: &[R],
    out: &mut SurfelGradSlot<'_, R>,
) -> [R; 6] {
    let i = proj.index as usize;
    let (t_u, t_v, t_w) = (proj.t_u, proj.t_v, proj.t_w);
    let mut d_tu = [g.t[0], g.t[1], g.t[2]];
    let mut d_tv = [g.t[3], g.t[4], g.t[5]];
    let mut d_tw = [g.t[6], g.t[7], g.t[8]];

    // Filter centre (3σ box centre) → T.
    let c2 = R::from_f64(SIGMA_CUTOFF * SIGMA_CUTOFF);
    let (center, d) = (proj.center, geo.conic_d);
    let tt = [c2, c2, -R::ONE];
    let (gx, gy) = (g.center[0], g.center[1]);
    let two = R::from_f64(2.0);
    let s = (gx * center[0] + gy * center[1]) / d;
    for k in 0..3 {
        let f = tt[k] / d;
        d_tu[k] += gx * f * t_w[k];
        d_tv[k] += gy * f * t_w[k];
        d_tw[k] += gx * f * t_u[k] + gy * f * t_v[k] - s * two * tt[k] * t_w[k];
    }

    // T = K·M → M (rows), then columns: M = [c_u | c_v | p_view].
    let dm0 = d_tu.map(|v| v * cam.fx);
    let dm1 = d_tv.map(|v| v * cam.fy);
    let dm2 = [
        d_tw[0] + cam.cx * d_tu[0] + cam.cy * d_tv[0],
        d_tw[1] + cam.cx * d_tu[1] + cam.cy * d_tv[1],
        d_tw[2] + cam.cx * d_tu[2] + cam.cy * d_tv[2],
    ];
    let a_u = cam.rotate_t([dm0[0], dm1[0], dm2[0]]);
    let a_v = cam.rotate_t([dm0[1], dm1[1], dm2[1]]);
    let mut d_mean = cam.rotate_t([dm0[2], dm1[2], dm2[2]]);
    let rot = geo.rot;
    let tu = [rot[0][0], rot[1][0], rot[2][0]];
    let tv = [rot[0][1], rot[1][1], rot[2][1]];
    let ds = [dot(a_u, tu), dot(a_v, tv)];
    let d_tw_world = cam.rotate_t(g.normal.map(|v| v * proj.normal_sign));
    let mut grot = [[R::ZERO; 3]; 3];
    for r in 0..3 {
        grot[r][0] = a_u[r] * geo.scale[0];
        grot[r][1] = a_v[r] * geo.scale[1];
        grot[r][2] = d_tw_world[r];
    }
    let dq = normalize_vjp(p.quat(i), rotmat_vjp(geo.qn, grot));

    // Colours: SH coefficients and the view-direction term.
    let nc = num_coeffs(sh_degree);
    let (dir, dist) = (geo.dir, geo.dist);
    let mut y = [R::ZERO; 16];
    basis(sh_degree, dir, &mut y);
    let mut jac = [[R::ZERO; 3]; 16];
    basis_jacobian(sh_degree, dir, &mut jac);
    let mut g_dir = [R::ZERO; 3];
    for (set, dc, shift) in [(0usize, g.rgb, 0u8), (1, g.mask, 3)] {
        for ch in 0..3 {
            if proj.clamped & (1 << (ch as u8 + shift)) != 0 {
                continue;
            }
            let gc = dc[ch];
            for k in 0..nc {
                let coeff = if set == 0 {
                    p.sh(i, k, ch)
                } else {
                    p.mask_sh(i, k, ch)
                };
                let slot = if set == 0 {
                    &mut *out.sh
                } else {
                    &mut *out.mask_sh
                };
                slot[k * 3 + ch] += y[k] * gc;
                for a in 0..3 {
                    g_dir[a] += coeff * gc * jac[k][a];
                }
            }
        }
    }
    let gd = dot(g_dir, dir);
    let d_mean_dir: [R; 3] = std::array::from_fn(|a| (g_dir[a] - gd * dir[a]) / dist);
    for a in 0..3 {
        d_mean[a] += d_mean_dir[a];
    }
    let cols = [
        cam.rotate(tu).map(|v| v * geo.scale[0]),
        cam.rotate(tv).map(|v| v * geo.scale[1]),
        {
            let rm = cam.rotate(p.mean(i));
            std::array::from_fn(|a| rm[a] + cam.trans[a])
        },
    ];
    let d_cols = [0, 1, 2].map(|j| [dm0[j], dm1[j], dm2[j]]);
    let camera = camera_vjp(cam, cols, d_cols, (proj.normal, g.normal), d_mean_dir);

    let o = proj.opacity;
    for (m, d) in out.mean.iter_mut().zip(d_mean) {
        *m += d;
    }
    out.log_scale[0] += ds[0] * geo.scale[0];
    out.log_scale[1] += ds[1] * geo.scale[1];
    for (q, d) in out.quat.iter_mut().zip(dq) {
        *q += d;
    }
    *out.opacity_logit += g.opacity * o * (R::ONE - o);
    let mut dl = [R::ZERO; 64];
    let dl = &mut dl[..probs.len()];
    softmax_vjp(probs, dprobs, dl);
    for (o, d) in out.obj_logits.iter_mut().zip(dl.iter()) {
        *o += *d;
    }
    camera
}

/// One surfel's share of `∂L/∂(ω, δ)`, the gradient with respect to a rigid motion applied in the camera
/// frame, `x_c ↦ exp([ω]×) x_c + δ` (world-to-camera `R ↦ exp([ω]×) R`, `t ↦ exp([ω]×) t + δ`), at
/// `ω = δ = 0`: what per-view pose refinement steps on.
///
/// The camera enters the preprocess through camera-frame vectors only: the columns `M_j` of
/// `T = K·M` (`c_u`, `c_v`, `p_view`), the normal `n`, and the camera centre in the colours' view
/// direction. Each vector rotates with `ω` (`∂(ω × v)` gives `v × ∂L/∂v`), `p_view` also moves with `δ`,
/// and the centre moves by `−Rᵀδ`, so with `g_μ` the view direction's share of `∂L/∂μ`:
/// `∂L/∂ω = Σ_j M_j × ∂L/∂M_j + n × ∂L/∂n`, `∂L/∂δ = ∂L/∂p_view + R·g_μ`.
fn camera_vjp<R: Real>(
    cam: &CamR<R>,
    cols: [[R; 3]; 3],
    d_cols: [[R; 3]; 3],
    (normal, d_normal): ([R; 3], [R; 3]),
    d_mean_dir: [R; 3],
) -> [R; 6] {
    let mut w = cross(&normal, &d_normal);
    for (c, d) in cols.iter().zip(&d_cols) {
        let x = cross(c, d);
        for a in 0..3 {
            w[a] += x[a];
        }
    }
    let rg = cam.rotate(d_mean_dir);
    [
        w[0],
        w[1],
        w[2],
        d_cols[2][0] + rg[0],
        d_cols[2][1] + rg[1],
        d_cols[2][2] + rg[2],
    ]
}

/// Mutable view of one surfel's slot in a [`ParamsOf`] gradient buffer.
pub struct SurfelGradSlot<'a, R> {
    pub mean: &'a mut [R; 3],
    pub log_scale: &'a mut [R; 2],
    pub quat: &'a mut [R; 4],
    pub opacity_logit: &'a mut R,
    pub sh: &'a mut [R],
    pub mask_sh: &'a mut [R],
    pub obj_logits: &'a mut [R],
}

impl<R: Real> ParamsOf<R> {
    /// The slot of surfel `i`.
    pub fn slot(&mut self, i: usize) -> SurfelGradSlot<'_, R> {
        let nc = num_coeffs(self.sh_degree) * 3;
        let k = self.num_objects;
        SurfelGradSlot {
            mean: &mut self.means[i],
            log_scale: &mut self.log_scales[i],
            quat: &mut self.quats[i],
            opacity_logit: &mut self.opacity_logits[i],
            sh: &mut self.sh[i * nc..(i + 1) * nc],
            mask_sh: &mut self.mask_sh[i * nc..(i + 1) * nc],
            obj_logits: &mut self.obj_logits[i * k..(i + 1) * k],
        }
    }
}

/// Softmax of the object logits of up to eight visible surfels `ps` at once, one surfel per lane
/// ([`softmax_numerators8`]: per surfel the same operations in the same order as a scalar softmax, so
/// the result does not depend on a surfel's neighbours in the block), into `out` (`ps.len() × k`,
/// surfel-major). The logits are finite ([`preprocess_one`] culls the rest), so every sum is ≥ 1. One surfel at
/// a time, the per-lane bookkeeping of fifteen channels cost ~600 instructions per surfel, a fifth of
/// the preprocess; across surfels the exponentials fill all lanes. The backward ([`softmax_vjp`]) is
/// written in the probabilities, so it stays the exact derivative of what was rendered.
pub fn softmax_block<R: Real, P: SurfelParams<R>>(
    params: &P,
    ps: &[Proj<R>],
    k: usize,
    out: &mut [R],
) {
    const L: usize = crate::lanes::LANES;
    let n = ps.len().min(L);
    let mut x = [[R::ZERO; L]; crate::MAX_OBJECTS];
    for (l, p) in ps.iter().take(n).enumerate() {
        let i = p.index as usize;
        for (c, xc) in x.iter_mut().enumerate().take(k) {
            xc[l] = params.obj_logit(i, c);
        }
    }
    let x = &mut x[..k];
    let s = softmax_numerators8(x);
    for l in 0..n {
        let inv = R::ONE / s[l];
        for (c, xc) in x.iter().enumerate() {
            out[l * k + c] = xc[l] * inv;
        }
    }
}
