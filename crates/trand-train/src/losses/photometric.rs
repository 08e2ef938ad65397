//! Photometric loss of 3DGS/2DGS/TRAN-D: `L = (1 − λ)·L1 + λ·(1 − SSIM)`, λ = 0.2.
//!
//! * `L1 = mean |x − y|` over all pixels and channels; `∂L1/∂x = sign(x − y)/N` (0 where equal, as
//!   PyTorch's `abs` backward).
//! * SSIM (Wang et al. 2004) with the 3DGS settings: 11×11 Gaussian window, σ = 1.5, **zero padding 5**
//!   ("same" output size), per channel, `C1 = 0.01²`, `C2 = 0.03²`, mean of the SSIM map:
//!
//!   `μx = G∗x`, `σx² = G∗x² − μx²`, `σxy = G∗(xy) − μx μy`,
//!   `S = (2 μx μy + C1)(2 σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))`.
//!
//! Backward: with `A1 = 2μxμy + C1`, `A2 = 2σxy + C2`, `B1 = μx² + μy² + C1`, `B2 = σx² + σy² + C2`,
//! the map gradients with respect to the three filtered quantities that depend on `x` are
//!
//! * `∂S/∂(G∗x)   = 2μy (A2 − A1)/(B1 B2) + 2μx S (1/B2 − 1/B1)`,
//! * `∂S/∂(G∗x²)  = −S/B2`,
//! * `∂S/∂(G∗xy)  = 2 A1/(B1 B2)`,
//!
//! and `∂mean S/∂x = Gᵀ∗a + 2x·(Gᵀ∗b) + y·(Gᵀ∗c)` for those maps `a, b, c` (divided by N). The zero-padded
//! correlation with a symmetric kernel is its own adjoint, so `Gᵀ∗ = G∗`.
//!
//! Images are row-major, channel-fastest (`[(row·W + col)·C + ch]`). The work is split over rows with
//! rayon; every output value is computed by one task from the same inputs in the same order, and the
//! means are reduced row by row in a fixed order, so results do not depend on the thread count.

use rayon::prelude::*;
use trand_core::Real;

/// SSIM window radius: 11×11 window.
pub const SSIM_RADIUS: usize = 5;
/// SSIM window size.
pub const SSIM_WINDOW: usize = 2 * SSIM_RADIUS + 1;
/// Gaussian σ of the SSIM window (pixels).
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM stabiliser for the luminance term, `(0.01·L)²` with dynamic range L = 1.
pub const SSIM_C1: f64 = 0.01 * 0.01;
/// SSIM stabiliser for the contrast/structure term, `(0.03·L)²`.
pub const SSIM_C2: f64 = 0.03 * 0.03;
/// Weight of `1 − SSIM` in the photometric loss (3DGS / 2DGS / TRAN-D `lambda_dssim`).
pub const DEFAULT_LAMBDA_DSSIM: f64 = 0.2;

/// The normalised 1D Gaussian of the separable SSIM window.
pub fn ssim_kernel<R: Real>() -> [R; SSIM_WINDOW] {
    let mut k = [0.0f64; SSIM_WINDOW];
    for (i, v) in k.iter_mut().enumerate() {
        let d = i as f64 - SSIM_RADIUS as f64;
        *v = (-(d * d) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f64 = k.iter().sum();
    k.map(|v| R::from_f64(v / s))
}

/// Mean absolute error and its gradient with respect to `pred`.
pub fn l1<R: Real>(pred: &[R], gt: &[R]) -> (R, Vec<R>) {
    assert_eq!(pred.len(), gt.len(), "l1: image sizes differ");
    if pred.is_empty() {
        return (R::ZERO, Vec::new());
    }
    let inv_n = R::ONE / R::from_f64(pred.len() as f64);
    let mut grad = vec![R::ZERO; pred.len()];
    // One pass: gradient and per-chunk |·| sums (8 interleaved accumulators, then the chunks in order:
    // deterministic regardless of the thread count, and not bound by one add chain).
    let partial: Vec<R> = grad
        .par_chunks_mut(L1_CHUNK)
        .zip(pred.par_chunks(L1_CHUNK))
        .zip(gt.par_chunks(L1_CHUNK))
        .map(|((o, p), g)| {
            // Fixed-width lanes so the loop vectorises (selects become blends; random signs would
            // defeat a branch predictor).
            let sign = |p: R, g: R| {
                let up = if p > g { inv_n } else { R::ZERO };
                let down = if p < g { inv_n } else { R::ZERO };
                up - down
            };
            let mut acc = [R::ZERO; 8];
            let mut oc = o.chunks_exact_mut(8);
            let (mut pc, mut gc) = (p.chunks_exact(8), g.chunks_exact(8));
            for ((o, p), g) in (&mut oc).zip(&mut pc).zip(&mut gc) {
                for l in 0..8 {
                    o[l] = sign(p[l], g[l]);
                    acc[l] += (p[l] - g[l]).abs();
                }
            }
            let mut tail = R::ZERO;
            for ((o, &p), &g) in oc
                .into_remainder()
                .iter_mut()
                .zip(pc.remainder())
                .zip(gc.remainder())
            {
                *o = sign(p, g);
                tail += (p - g).abs();
            }
            acc.iter().fold(tail, |a, &b| a + b)
        })
        .collect();
    let sum = partial.into_iter().fold(R::ZERO, |a, b| a + b);
    (sum * inv_n, grad)
}

/// Chunk length of the deterministic L1 reduction.
const L1_CHUNK: usize = 4096;

/// Checks the image buffer length against its shape.
fn check_shape(len: usize, width: usize, height: usize, channels: usize, what: &str) {
    assert_eq!(
        len,
        width * height * channels,
        "{what}: buffer length {len} is not {width}×{height}×{channels}"
    );
}

/// Splits an interleaved image into channel planes (`[ch][row·W + col]`).
fn to_planes<R: Real>(img: &[R], n_pix: usize, channels: usize) -> Vec<R> {
    let mut out = vec![R::ZERO; n_pix * channels];
    for (p, px) in img.chunks_exact(channels).enumerate() {
        for (c, &v) in px.iter().enumerate() {
            out[c * n_pix + p] = v;
        }
    }
    out
}

/// `dst += a·src`.
#[inline]
fn axpy<R: Real>(a: R, src: &[R], dst: &mut [R]) {
    for (d, &s) in dst.iter_mut().zip(src) {
        *d += a * s;
    }
}

/// Columns per register block of the filters: 5 quantities × 8 lanes of accumulators fit the SSE
/// register file, so the 11 taps accumulate in registers and each output is stored once.
const BLOCK: usize = 8;

/// Horizontal zero-padded correlation of a padded row (`src.len() = W + 2r`, zeros at both ends)
/// written to `dst` (`W` values).
#[inline]
fn hconv<R: Real>(k: &[R; SSIM_WINDOW], src: &[R], dst: &mut [R]) {
    let w = dst.len();
    debug_assert_eq!(src.len(), w + 2 * SSIM_RADIUS);
    let mut x = 0;
    while x + BLOCK <= w {
        let mut acc = [R::ZERO; BLOCK];
        for (t, &kt) in k.iter().enumerate() {
            let s: &[R; BLOCK] = src[x + t..x + t + BLOCK].try_into().expect("block");
            for l in 0..BLOCK {
                acc[l] += kt * s[l];
            }
        }
        dst[x..x + BLOCK].copy_from_slice(&acc);
        x += BLOCK;
    }
    for (i, d) in dst.iter_mut().enumerate().skip(x) {
        let mut acc = R::ZERO;
        for (t, &kt) in k.iter().enumerate() {
            acc += kt * src[i + t];
        }
        *d = acc;
    }
}

/// Vertical zero-padded correlation at output row `row` of the five SSIM quantities
/// `x, y, x², y², xy` of the planes `xp, yp` (`W` wide, `H` high), written into the centres of the
/// padded rows `out[q][r..r + W]` (the pads stay zero).
#[inline]
fn vconv5<R: Real>(
    k: &[R; SSIM_WINDOW],
    xp: &[R],
    yp: &[R],
    w: usize,
    h: usize,
    row: usize,
    out: &mut [&mut [R]; 5],
) {
    let r = SSIM_RADIUS;
    let t0 = r.saturating_sub(row);
    let t1 = SSIM_WINDOW.min(h + r - row);
    let mut x = 0;
    while x + BLOCK <= w {
        let mut acc = [[R::ZERO; BLOCK]; 5];
        for (t, &kt) in k.iter().enumerate().take(t1).skip(t0) {
            let base = (row + t - r) * w + x;
            let xs: &[R; BLOCK] = xp[base..base + BLOCK].try_into().expect("block");
            let ys: &[R; BLOCK] = yp[base..base + BLOCK].try_into().expect("block");
            for l in 0..BLOCK {
                let (a, b) = (xs[l], ys[l]);
                let (ka, kb) = (kt * a, kt * b);
                acc[0][l] += ka;
                acc[1][l] += kb;
                acc[2][l] += ka * a;
                acc[3][l] += kb * b;
                acc[4][l] += ka * b;
            }
        }
        for (o, a) in out.iter_mut().zip(&acc) {
            o[r + x..r + x + BLOCK].copy_from_slice(a);
        }
        x += BLOCK;
    }
    for i in x..w {
        let mut acc = [R::ZERO; 5];
        for (t, &kt) in k.iter().enumerate().take(t1).skip(t0) {
            let idx = (row + t - r) * w + i;
            let (a, b) = (xp[idx], yp[idx]);
            let (ka, kb) = (kt * a, kt * b);
            acc[0] += ka;
            acc[1] += kb;
            acc[2] += ka * a;
            acc[3] += kb * b;
            acc[4] += ka * b;
        }
        for (o, &a) in out.iter_mut().zip(&acc) {
            o[r + i] = a;
        }
    }
}

/// Which rows of the channel planes are zero in both images. Where every row within the window
/// radius of an output row is blank, the five filtered quantities are exactly 0 there, so the SSIM
/// map is exactly 1 and the map gradients `a, b, c` are the constants of [`blank_window_values`];
/// where every row within twice the radius is blank, the gradient is exactly 0 (`x = y = 0` and
/// `a = 0` under the window). Those rows are filled in instead of filtered: the same bits as
/// filtering them, for a fraction of the work on images whose objects leave rows empty.
struct BlankRows {
    /// Per channel, `prefix[ch·(h+1) + i]` = blank rows among the first `i`.
    prefix: Vec<u32>,
    h: usize,
}

impl BlankRows {
    fn new<R: Real>(x: &[R], y: &[R], w: usize, h: usize, channels: usize) -> Self {
        let mut prefix = Vec::with_capacity(channels * (h + 1));
        for ch in 0..channels {
            let mut n = 0u32;
            prefix.push(0);
            for row in 0..h {
                let at = (ch * h + row) * w..(ch * h + row + 1) * w;
                let zero = |p: &[R]| p[at.clone()].iter().all(|&v| v == R::ZERO);
                n += u32::from(zero(x) && zero(y));
                prefix.push(n);
            }
        }
        Self { prefix, h }
    }

    /// Whether rows `row − radius ..= row + radius` of channel `ch` (those inside the image) are
    /// all blank.
    fn all(&self, ch: usize, row: usize, radius: usize) -> bool {
        let (lo, hi) = (row.saturating_sub(radius), (row + radius + 1).min(self.h));
        let p = &self.prefix[ch * (self.h + 1)..];
        (p[hi] - p[lo]) as usize == hi - lo
    }
}

/// `(a, b, c, S)` of an all-zero window, evaluated with the same operations as the filtered rows.
fn blank_window_values<R: Real>(c1: R, c2: R, two: R, inv_n: R) -> [R; 4] {
    let (mx, my, exx, eyy, exy) = (R::ZERO, R::ZERO, R::ZERO, R::ZERO, R::ZERO);
    let sxx = exx - mx * mx;
    let syy = eyy - my * my;
    let sxy = exy - mx * my;
    let a1 = two * mx * my + c1;
    let a2 = two * sxy + c2;
    let inv_b1 = R::ONE / (mx * mx + my * my + c1);
    let inv_b2 = R::ONE / (sxx + syy + c2);
    let inv_b = inv_b1 * inv_b2;
    let s = a1 * a2 * inv_b;
    [
        inv_n * (two * my * (a2 - a1) * inv_b + two * mx * s * (inv_b2 - inv_b1)),
        -inv_n * s * inv_b2,
        inv_n * two * a1 * inv_b,
        s,
    ]
}

/// What [`ssim_rows`] does with rows whose windows see only blank rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum BlankRowWork {
    /// Fill in their known values ([`BlankRows`]).
    Fill,
    /// Filter them like any other row (the reference the filled values are tested against).
    #[cfg(test)]
    Filter,
}

/// Mean SSIM of `pred` against `gt` and the gradient of that mean with respect to `pred`.
pub fn ssim<R: Real>(
    pred: &[R],
    gt: &[R],
    width: usize,
    height: usize,
    channels: usize,
) -> (R, Vec<R>) {
    ssim_rows(pred, gt, width, height, channels, BlankRowWork::Fill)
}

fn ssim_rows<R: Real>(
    pred: &[R],
    gt: &[R],
    width: usize,
    height: usize,
    channels: usize,
    work: BlankRowWork,
) -> (R, Vec<R>) {
    check_shape(pred.len(), width, height, channels, "ssim pred");
    check_shape(gt.len(), width, height, channels, "ssim gt");
    let n_pix = width * height;
    if n_pix * channels == 0 {
        return (R::ZERO, Vec::new());
    }
    let k = ssim_kernel::<R>();
    let c1 = R::from_f64(SSIM_C1);
    let c2 = R::from_f64(SSIM_C2);
    let two = R::from_f64(2.0);
    let inv_n = R::ONE / R::from_f64((n_pix * channels) as f64);
    let x = to_planes(pred, n_pix, channels);
    let y = to_planes(gt, n_pix, channels);
    let (w, h, r) = (width, height, SSIM_RADIUS);

    // Forward, fused per output row: vertical pass of the five products into padded rows, horizontal
    // pass, SSIM and the three map gradients (a, b, c), already scaled by 1/N.
    let blank = BlankRows::new(&x, &y, w, h, channels);
    let [blank_a, blank_b, blank_c, blank_s] = blank_window_values(c1, c2, two, inv_n);
    let mut abc = vec![R::ZERO; 3 * n_pix * channels];
    let row_sums: Vec<R> = abc
        .par_chunks_mut(3 * w)
        .enumerate()
        .map(|(task, out)| {
            let (ch, row) = (task / h, task % h);
            if work == BlankRowWork::Fill && blank.all(ch, row, r) {
                let (oa, rest) = out.split_at_mut(w);
                let (ob, oc) = rest.split_at_mut(w);
                oa.fill(blank_a);
                ob.fill(blank_b);
                oc.fill(blank_c);
                return (0..w).fold(R::ZERO, |acc, _| acc + blank_s);
            }
            let xp = &x[ch * n_pix..(ch + 1) * n_pix];
            let yp = &y[ch * n_pix..(ch + 1) * n_pix];
            let mut v = vec![R::ZERO; 5 * (w + 2 * r)];
            let (vx, rest) = v.split_at_mut(w + 2 * r);
            let (vy, rest) = rest.split_at_mut(w + 2 * r);
            let (vxx, rest) = rest.split_at_mut(w + 2 * r);
            let (vyy, vxy) = rest.split_at_mut(w + 2 * r);
            let mut vs = [vx, vy, vxx, vyy, vxy];
            vconv5(&k, xp, yp, w, h, row, &mut vs);
            let [vx, vy, vxx, vyy, vxy] = vs;
            let mut f = vec![R::ZERO; 5 * w];
            let (mx, rest) = f.split_at_mut(w);
            let (my, rest) = rest.split_at_mut(w);
            let (exx, rest) = rest.split_at_mut(w);
            let (eyy, exy) = rest.split_at_mut(w);
            hconv(&k, vx, mx);
            hconv(&k, vy, my);
            hconv(&k, vxx, exx);
            hconv(&k, vyy, eyy);
            hconv(&k, vxy, exy);
            let (oa, rest) = out.split_at_mut(w);
            let (ob, oc) = rest.split_at_mut(w);
            // Equal-length slices: the bounds checks vanish and the loop vectorises. The SSIM values
            // replace `exx` (each is read before it is overwritten) and are summed afterwards, in the
            // same order: a running sum in this loop kept it scalar (a float reduction cannot be
            // reordered), which was a third of the SSIM's time.
            let (mx, my, exx, eyy, exy) = (&mx[..w], &my[..w], &mut exx[..w], &eyy[..w], &exy[..w]);
            let (oa, ob, oc) = (&mut oa[..w], &mut ob[..w], &mut oc[..w]);
            for i in 0..w {
                let (mx, my) = (mx[i], my[i]);
                let sxx = exx[i] - mx * mx;
                let syy = eyy[i] - my * my;
                let sxy = exy[i] - mx * my;
                let a1 = two * mx * my + c1;
                let a2 = two * sxy + c2;
                let inv_b1 = R::ONE / (mx * mx + my * my + c1);
                let inv_b2 = R::ONE / (sxx + syy + c2);
                let inv_b = inv_b1 * inv_b2;
                let s = a1 * a2 * inv_b;
                exx[i] = s;
                oa[i] = inv_n * (two * my * (a2 - a1) * inv_b + two * mx * s * (inv_b2 - inv_b1));
                ob[i] = -inv_n * s * inv_b2;
                oc[i] = inv_n * two * a1 * inv_b;
            }
            exx.iter().fold(R::ZERO, |acc, &s| acc + s)
        })
        .collect();
    let mean = row_sums.into_iter().fold(R::ZERO, |acc, s| acc + s) * inv_n;

    // Backward: filter a, b, c with G (self-adjoint) and combine, one output row per task.
    let mut grad_planes = vec![R::ZERO; n_pix * channels];
    grad_planes
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(task, out)| {
            let (ch, row) = (task / h, task % h);
            if work == BlankRowWork::Fill && blank.all(ch, row, 2 * r) {
                // x = y = 0 here and a = 0 within the window: the gradient is exactly 0.
                return;
            }
            let mut v = vec![R::ZERO; 3 * (w + 2 * r)];
            let (va, rest) = v.split_at_mut(w + 2 * r);
            let (vb, vc) = rest.split_at_mut(w + 2 * r);
            for (t, &kt) in k.iter().enumerate() {
                let iy = row as isize + t as isize - r as isize;
                if iy < 0 || iy >= h as isize {
                    continue;
                }
                let src = &abc[(ch * h + iy as usize) * 3 * w..(ch * h + iy as usize + 1) * 3 * w];
                axpy(kt, &src[..w], &mut va[r..r + w]);
                axpy(kt, &src[w..2 * w], &mut vb[r..r + w]);
                axpy(kt, &src[2 * w..], &mut vc[r..r + w]);
            }
            let mut f = vec![R::ZERO; 3 * w];
            {
                let (ga, rest) = f.split_at_mut(w);
                let (gb, gc) = rest.split_at_mut(w);
                hconv(&k, va, ga);
                hconv(&k, vb, gb);
                hconv(&k, vc, gc);
            }
            let base = ch * n_pix + row * w;
            let (xs, ys) = (&x[base..base + w], &y[base..base + w]);
            let (ga, rest) = f.split_at(w);
            let (gb, gc) = rest.split_at(w);
            for ((((o, &xv), &yv), (&a, &b)), &c) in out
                .iter_mut()
                .zip(xs)
                .zip(ys)
                .zip(ga.iter().zip(gb))
                .zip(gc)
            {
                *o = a + two * xv * b + yv * c;
            }
        });
    let mut grad = vec![R::ZERO; n_pix * channels];
    for (p, px) in grad.chunks_exact_mut(channels).enumerate() {
        for (c, g) in px.iter_mut().enumerate() {
            *g = grad_planes[c * n_pix + p];
        }
    }
    (mean, grad)
}

/// The parts of a photometric loss evaluation.
#[derive(Clone, Debug)]
pub struct Photometric<R> {
    /// `(1 − λ)·L1 + λ·(1 − SSIM)`.
    pub value: R,
    pub l1: R,
    pub ssim: R,
    /// Gradient of `value` with respect to the predicted image (same layout).
    pub grad: Vec<R>,
}

/// `(1 − λ)·L1 + λ·(1 − SSIM)` and its gradient with respect to `pred`.
pub fn photometric<R: Real>(
    pred: &[R],
    gt: &[R],
    width: usize,
    height: usize,
    channels: usize,
    lambda_dssim: R,
) -> Photometric<R> {
    let (l1v, g1) = l1(pred, gt);
    let (sv, gs) = ssim(pred, gt, width, height, channels);
    let wl1 = R::ONE - lambda_dssim;
    let grad = g1
        .iter()
        .zip(&gs)
        .map(|(&a, &b)| wl1 * a - lambda_dssim * b)
        .collect();
    Photometric {
        value: wl1 * l1v + lambda_dssim * (R::ONE - sv),
        l1: l1v,
        ssim: sv,
        grad,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{assert_grad_matches_fd, rand_vec};

    /// Direct 2D zero-padded SSIM (no separability, no fusion): the reference for the fast path.
    fn ssim_naive(x: &[f64], y: &[f64], w: usize, h: usize, c: usize) -> f64 {
        let k = ssim_kernel::<f64>();
        let filt = |f: &dyn Fn(usize) -> f64, ch: usize, row: usize, col: usize| {
            let mut s = 0.0;
            for dy in 0..SSIM_WINDOW {
                for dx in 0..SSIM_WINDOW {
                    let (iy, ix) = (
                        row as isize + dy as isize - 5,
                        col as isize + dx as isize - 5,
                    );
                    if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                        continue;
                    }
                    s += k[dy] * k[dx] * f(((iy as usize) * w + ix as usize) * c + ch);
                }
            }
            s
        };
        let mut total = 0.0;
        for ch in 0..c {
            for row in 0..h {
                for col in 0..w {
                    let mx = filt(&|i| x[i], ch, row, col);
                    let my = filt(&|i| y[i], ch, row, col);
                    let sxx = filt(&|i| x[i] * x[i], ch, row, col) - mx * mx;
                    let syy = filt(&|i| y[i] * y[i], ch, row, col) - my * my;
                    let sxy = filt(&|i| x[i] * y[i], ch, row, col) - mx * my;
                    total += (2.0 * mx * my + SSIM_C1) * (2.0 * sxy + SSIM_C2)
                        / ((mx * mx + my * my + SSIM_C1) * (sxx + syy + SSIM_C2));
                }
            }
        }
        total / (w * h * c) as f64
    }

    /// An image with content in the rows of `bands` (per channel `ch`, shifted by `ch` rows), zero
    /// elsewhere; `seed` varies the values.
    fn banded<R: Real>(
        w: usize,
        h: usize,
        c: usize,
        bands: &[(usize, usize)],
        seed: u64,
    ) -> Vec<R> {
        let mut state = seed;
        let mut img = vec![R::ZERO; w * h * c];
        for row in 0..h {
            for col in 0..w {
                for ch in 0..c {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let v = (state >> 40) as f64 / (1u64 << 24) as f64;
                    if bands.iter().any(|&(a, b)| (a + ch..b + ch).contains(&row)) {
                        img[(row * w + col) * c + ch] = R::from_f64(v);
                    }
                }
            }
        }
        img
    }

    fn bits_of<R: Real>(v: &[R]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits_u64()).collect()
    }

    #[test]
    fn filling_blank_rows_gives_the_bits_of_filtering_them() {
        let (w, h, c) = (21, 64, 3);
        // Content bands near the edges, bands closer than one and two window radii, one row alone.
        type Bands = &'static [(usize, usize)];
        let cases: [(Bands, Bands); 4] = [
            (&[(0, 3), (30, 34)], &[(31, 35)]),
            (&[(12, 13)], &[(20, 26), (60, 64)]),
            (&[], &[(40, 41)]),
            (&[], &[]),
        ];
        fn check<R: Real>(i: usize, bx: Bands, by: Bands, (w, h, c): (usize, usize, usize)) {
            let x = banded::<R>(w, h, c, bx, 1 + i as u64);
            let y = banded::<R>(w, h, c, by, 100 + i as u64);
            let fill = ssim_rows(&x, &y, w, h, c, BlankRowWork::Fill);
            let filter = ssim_rows(&x, &y, w, h, c, BlankRowWork::Filter);
            let what = std::any::type_name::<R>();
            assert_eq!(
                fill.0.to_bits_u64(),
                filter.0.to_bits_u64(),
                "case {i} ({what}): mean"
            );
            assert_eq!(
                bits_of(&fill.1),
                bits_of(&filter.1),
                "case {i} ({what}): gradient"
            );
        }
        for (i, &(bx, by)) in cases.iter().enumerate() {
            check::<f32>(i, bx, by, (w, h, c));
            check::<f64>(i, bx, by, (w, h, c));
        }
    }

    #[test]
    fn ssim_kernel_is_normalised_and_symmetric() {
        let k = ssim_kernel::<f64>();
        assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        for i in 0..SSIM_WINDOW {
            assert_eq!(k[i], k[SSIM_WINDOW - 1 - i]);
        }
    }

    #[test]
    fn ssim_of_identical_images_is_one_with_zero_gradient() {
        let x = rand_vec(1, 13 * 9 * 3, 0.0, 1.0);
        let (s, g) = ssim(&x, &x, 13, 9, 3);
        assert!((s - 1.0).abs() < 1e-12, "{s}");
        assert!(g.iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn ssim_matches_direct_2d_convolution() {
        let (w, h, c) = (17, 12, 3);
        let x = rand_vec(2, w * h * c, 0.0, 1.0);
        let y = rand_vec(3, w * h * c, 0.0, 1.0);
        let (s, _) = ssim(&x, &y, w, h, c);
        let r = ssim_naive(&x, &y, w, h, c);
        assert!((s - r).abs() < 1e-12, "fast {s} naive {r}");
    }

    #[test]
    fn ssim_gradient_matches_finite_differences() {
        // Smaller than the window on one axis and larger on the other: both padding cases.
        let (w, h, c) = (14, 6, 2);
        let x = rand_vec(4, w * h * c, 0.0, 1.0);
        let y = rand_vec(5, w * h * c, 0.0, 1.0);
        let (_, g) = ssim(&x, &y, w, h, c);
        assert_grad_matches_fd(&x, &g, |x| ssim(x, &y, w, h, c).0, 1e-6, 1e-7);
    }

    #[test]
    fn l1_gradient_matches_finite_differences() {
        let x = rand_vec(6, 40, 0.0, 1.0);
        let y = rand_vec(7, 40, 0.0, 1.0);
        let (v, g) = l1(&x, &y);
        let direct: f64 = x.iter().zip(&y).map(|(a, b)| (a - b).abs()).sum::<f64>() / 40.0;
        assert!((v - direct).abs() < 1e-15);
        assert_grad_matches_fd(&x, &g, |x| l1(x, &y).0, 1e-7, 1e-8);
    }

    #[test]
    fn photometric_combines_l1_and_dssim_with_its_gradient() {
        let (w, h, c) = (9, 8, 3);
        let x = rand_vec(8, w * h * c, 0.0, 1.0);
        let y = rand_vec(9, w * h * c, 0.0, 1.0);
        let p = photometric(&x, &y, w, h, c, 0.2);
        assert!((p.value - (0.8 * p.l1 + 0.2 * (1.0 - p.ssim))).abs() < 1e-15);
        assert_grad_matches_fd(
            &x,
            &p.grad,
            |x| photometric(x, &y, w, h, c, 0.2).value,
            1e-7,
            1e-7,
        );
    }

    #[test]
    fn f32_and_f64_agree() {
        let (w, h, c) = (20, 15, 3);
        let x = rand_vec(10, w * h * c, 0.0, 1.0);
        let y = rand_vec(11, w * h * c, 0.0, 1.0);
        let xf: Vec<f32> = x.iter().map(|&v| v as f32).collect();
        let yf: Vec<f32> = y.iter().map(|&v| v as f32).collect();
        let p64 = photometric(&x, &y, w, h, c, 0.2);
        let p32 = photometric(&xf, &yf, w, h, c, 0.2);
        assert!((p64.value - p32.value as f64).abs() < 1e-5);
        let gmax = p64.grad.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for (a, b) in p64.grad.iter().zip(&p32.grad) {
            assert!((a - *b as f64).abs() < 1e-4 * gmax);
        }
    }
}
