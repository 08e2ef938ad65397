//! TRAN-D's soft Dice loss on the rendered K-channel object map (official code, `dice_loss`).
//!
//! For channel k with rendered values `p` and one-hot target `t` over all pixels:
//!
//! `L_k = 1 − (2·Σ p t + 1) / (Σ p + Σ t + 1)`,  `L = (1/K)·Σ_k L_k`,
//!
//! summed over **all** K channels, including the background channel 0 and channels of absent objects
//! (the `+1` smoothing makes an absent channel with an empty render cost 0), divided by K. The gradient is
//!
//! `∂L/∂p_{pixel,k} = −(1/K)·[2 t / D_k − (2 I_k + 1) / D_k²]`, `I_k = Σ p t`, `D_k = Σ p + Σ t + 1`.
//!
//! Maps are row-major, channel-fastest: `[(row·W + col)·K + k]`.

use rayon::prelude::*;
use trand_core::Real;

/// Why a one-hot target cannot be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DiceError {
    #[error(
        "instance id {id} maps to channel {channel}, but the object map has only {num_channels} channels"
    )]
    ChannelOutOfRange {
        id: u16,
        channel: usize,
        num_channels: usize,
    },
    #[error("instance id {id} at pixel {pixel} is not in the id → channel table")]
    UnknownId { id: u16, pixel: usize },
    #[error("object map needs at least one channel")]
    NoChannels,
}

/// Pixels per reduction chunk (fixed, so sums do not depend on the thread count).
const CHUNK_PIXELS: usize = 2048;

/// Dice loss of `pred` (K-channel rendered object map) against `target` (one-hot, same layout) and its
/// gradient with respect to `pred`.
pub fn dice<R: Real>(pred: &[R], target: &[R], num_channels: usize) -> (R, Vec<R>) {
    assert!(num_channels > 0, "dice: no channels");
    assert_eq!(pred.len(), target.len(), "dice: map sizes differ");
    assert_eq!(
        pred.len() % num_channels,
        0,
        "dice: length is not a multiple of the channel count"
    );
    let k = num_channels;
    // Per chunk: [Σ p t, Σ p, Σ t] for every channel, then reduced in chunk order.
    let partial: Vec<Vec<R>> = pred
        .par_chunks(CHUNK_PIXELS * k)
        .zip(target.par_chunks(CHUNK_PIXELS * k))
        .map(|(p, t)| {
            let mut s = vec![R::ZERO; 3 * k];
            for (pp, tp) in p.chunks_exact(k).zip(t.chunks_exact(k)) {
                for c in 0..k {
                    s[c] += pp[c] * tp[c];
                    s[k + c] += pp[c];
                    s[2 * k + c] += tp[c];
                }
            }
            s
        })
        .collect();
    let mut sums = vec![R::ZERO; 3 * k];
    for s in &partial {
        for (a, &b) in sums.iter_mut().zip(s) {
            *a += b;
        }
    }
    let (value, g_total, g_on_label) = dice_from_sums(&sums[k..2 * k], &sums[..k], &sums[2 * k..]);
    let grad = pred
        .par_iter()
        .zip(target.par_iter())
        .enumerate()
        .map(|(i, (_, &t))| {
            let c = i % k;
            g_on_label[c] * t + g_total[c]
        })
        .collect();
    (value, grad)
}

/// The Dice loss from the object map's per-channel sums (what the rasterizer's label mode renders):
/// `total[k] = Σ p`, `on_label[k] = I_k = Σ p t`, `counts[k] = Σ t`. Returns the loss and its gradients
/// with respect to `total` and `on_label`:
///
/// `∂L/∂total_k = (1/K)(2 I_k + 1)/D_k²`, `∂L/∂I_k = −(2/K)/D_k`, `D_k = Σ p + Σ t + 1`,
///
/// so that the per-pixel gradient of [`dice`] is `∂L/∂I_k·t + ∂L/∂total_k`.
pub fn dice_from_sums<R: Real>(total: &[R], on_label: &[R], counts: &[R]) -> (R, Vec<R>, Vec<R>) {
    let k = total.len();
    assert!(k > 0, "dice: no channels");
    assert!(
        on_label.len() == k && counts.len() == k,
        "dice: sums of different lengths"
    );
    let inv_k = R::ONE / R::from_f64(k as f64);
    let two = R::from_f64(2.0);
    let mut value = R::ZERO;
    let mut g_total = vec![R::ZERO; k];
    let mut g_on_label = vec![R::ZERO; k];
    for c in 0..k {
        let num = two * on_label[c] + R::ONE;
        let den = total[c] + counts[c] + R::ONE;
        value += R::ONE - num / den;
        g_on_label[c] = -two * inv_k / den;
        g_total[c] = inv_k * num / (den * den);
    }
    (value * inv_k, g_total, g_on_label)
}

/// One-hot target (`num_channels` channels, channel-fastest) from an instance-id map.
///
/// `id_to_channel` lists `(instance id, channel)` pairs. Id 0 is the background and maps to channel 0
/// unless the table says otherwise; any other id missing from the table is an error (a silently dropped
/// object would train towards "background").
pub fn one_hot_target(
    ids: &[u16],
    id_to_channel: &[(u16, usize)],
    num_channels: usize,
) -> Result<Vec<f32>, DiceError> {
    if num_channels == 0 {
        return Err(DiceError::NoChannels);
    }
    let mut lut: Vec<Option<usize>> = vec![None; u16::MAX as usize + 1];
    lut[0] = Some(0);
    for &(id, channel) in id_to_channel {
        if channel >= num_channels {
            return Err(DiceError::ChannelOutOfRange {
                id,
                channel,
                num_channels,
            });
        }
        lut[id as usize] = Some(channel);
    }
    let mut out = vec![0.0f32; ids.len() * num_channels];
    for (pixel, (&id, px)) in ids
        .iter()
        .zip(out.chunks_exact_mut(num_channels))
        .enumerate()
    {
        let c = lut[id as usize].ok_or(DiceError::UnknownId { id, pixel })?;
        px[c] = 1.0;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{assert_grad_matches_fd, rand_vec};

    #[test]
    fn dice_gradient_matches_finite_differences() {
        let k = 4;
        let n_pix = 23;
        let p = rand_vec(20, n_pix * k, 0.0, 1.0);
        let labels = rand_vec(21, n_pix, 0.0, k as f64);
        let mut t = vec![0.0; n_pix * k];
        for (i, l) in labels.iter().enumerate() {
            t[i * k + *l as usize] = 1.0;
        }
        let (_, g) = dice(&p, &t, k);
        assert_grad_matches_fd(&p, &g, |p| dice(p, &t, k).0, 1e-6, 1e-9);
    }

    #[test]
    fn dice_from_sums_equals_the_per_pixel_dice_and_its_gradient() {
        let k = 3;
        let n_pix = 31;
        let p = rand_vec(7, n_pix * k, 0.0, 1.0);
        let labels: Vec<usize> = rand_vec(8, n_pix, 0.0, k as f64)
            .iter()
            .map(|&l| l as usize)
            .collect();
        let mut t = vec![0.0; n_pix * k];
        let (mut total, mut on, mut counts) = (vec![0.0; k], vec![0.0; k], vec![0.0; k]);
        for (i, &l) in labels.iter().enumerate() {
            t[i * k + l] = 1.0;
            on[l] += p[i * k + l];
            counts[l] += 1.0;
            for c in 0..k {
                total[c] += p[i * k + c];
            }
        }
        let (v, g) = dice(&p, &t, k);
        let (vs, gt, gi) = dice_from_sums(&total, &on, &counts);
        assert!((v - vs).abs() < 1e-14);
        for (i, &l) in labels.iter().enumerate() {
            for c in 0..k {
                let want = gt[c] + if c == l { gi[c] } else { 0.0 };
                assert!((g[i * k + c] - want).abs() < 1e-15);
            }
        }
        // And the sums' gradients by finite differences.
        let mut x = total.clone();
        x.extend_from_slice(&on);
        let mut gx = gt.clone();
        gx.extend_from_slice(&gi);
        assert_grad_matches_fd(
            &x,
            &gx,
            |x| dice_from_sums(&x[..k], &x[k..], &counts).0,
            1e-6,
            1e-9,
        );
    }

    #[test]
    fn perfect_prediction_costs_only_the_smoothing() {
        // p = t: L_k = 1 − (2n_k + 1)/(2n_k + 1) = 0 for every channel, present or absent.
        let ids = [0u16, 3, 3, 7, 0, 7];
        let t = one_hot_target(&ids, &[(3, 1), (7, 2)], 4).unwrap();
        let (v, _) = dice(&t, &t, 4);
        assert_eq!(v, 0.0);
    }

    #[test]
    fn empty_render_costs_one_per_present_channel_over_k() {
        let ids = [0u16, 3, 3, 0];
        let t = one_hot_target(&ids, &[(3, 1)], 5).unwrap();
        let p = vec![0.0f64; t.len()];
        let t64: Vec<f64> = t.iter().map(|&v| v as f64).collect();
        let (v, _) = dice(&p, &t64, 5);
        // channel 0: 1 − 1/3, channel 1: 1 − 1/3, absent channels: 0.
        assert!((v - 2.0 * (2.0 / 3.0) / 5.0).abs() < 1e-15);
    }

    #[test]
    fn one_hot_rejects_unknown_ids_and_bad_channels() {
        assert_eq!(
            one_hot_target(&[0, 5], &[(3, 1)], 4),
            Err(DiceError::UnknownId { id: 5, pixel: 1 })
        );
        assert_eq!(
            one_hot_target(&[0], &[(3, 4)], 4),
            Err(DiceError::ChannelOutOfRange {
                id: 3,
                channel: 4,
                num_channels: 4
            })
        );
        let t = one_hot_target(&[2, 0], &[(2, 3)], 4).unwrap();
        assert_eq!(t, vec![0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
    }
}
