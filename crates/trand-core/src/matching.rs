//! Mask IoU and minimum-cost assignment: matching objects across views and before and after the
//! removal (`trand-pipeline`) and predicted to ground-truth objects (`trand-eval`), here so that
//! neither crate imports the other.

/// Intersection over union of two binary masks of equal length; 0 when both are empty.
pub fn iou(a: &[bool], b: &[bool]) -> f64 {
    assert_eq!(a.len(), b.len(), "masks of different sizes");
    let (mut inter, mut union) = (0u64, 0u64);
    for (&x, &y) in a.iter().zip(b) {
        inter += (x && y) as u64;
        union += (x || y) as u64;
    }
    if union == 0 {
        0.0
    } else {
        inter as f64 / union as f64
    }
}

/// Minimum-cost assignment for a rectangular `rows × cols` cost matrix (Kuhn–Munkres with potentials,
/// O(n²m)). Returns, per row, its column; with more rows than columns, `rows − cols` rows get `None`.
/// Every cost must be finite (use a large constant for forbidden pairs).
pub fn hungarian(cost: &[Vec<f64>]) -> Vec<Option<usize>> {
    let rows = cost.len();
    if rows == 0 {
        return Vec::new();
    }
    let cols = cost[0].len();
    assert!(cost.iter().all(|r| r.len() == cols), "ragged cost matrix");
    assert!(
        cost.iter().flatten().all(|c| c.is_finite()),
        "costs must be finite"
    );
    if cols == 0 {
        return vec![None; rows];
    }
    // The algorithm needs n ≤ m; solve the transpose otherwise.
    if rows > cols {
        let t: Vec<Vec<f64>> = (0..cols)
            .map(|j| (0..rows).map(|i| cost[i][j]).collect())
            .collect();
        let col_of_row = hungarian(&t);
        let mut out = vec![None; rows];
        for (j, i) in col_of_row.into_iter().enumerate() {
            if let Some(i) = i {
                out[i] = Some(j);
            }
        }
        return out;
    }
    let (n, m) = (rows, cols);
    // 1-based potentials u (rows), v (cols); p[j] = row matched to column j (0 = none).
    let mut u = vec![0.0f64; n + 1];
    let mut v = vec![0.0f64; m + 1];
    let mut p = vec![0usize; m + 1];
    let mut way = vec![0usize; m + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0usize;
        let mut minv = vec![f64::INFINITY; m + 1];
        let mut used = vec![false; m + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0usize;
            for j in 1..=m {
                if !used[j] {
                    let cur = cost[i0 - 1][j - 1] - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut out = vec![None; n];
    for j in 1..=m {
        if p[j] != 0 {
            out[p[j] - 1] = Some(j - 1);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn total(cost: &[Vec<f64>], a: &[Option<usize>]) -> f64 {
        a.iter()
            .enumerate()
            .filter_map(|(i, j)| j.map(|j| cost[i][j]))
            .sum()
    }

    /// Minimum over all injective assignments of min(rows, cols) pairs.
    fn brute_force(cost: &[Vec<f64>]) -> f64 {
        let (rows, cols) = (cost.len(), cost[0].len());
        let k = rows.min(cols);
        fn rec(
            cost: &[Vec<f64>],
            i: usize,
            used: &mut Vec<bool>,
            left: usize,
            acc: f64,
            best: &mut f64,
        ) {
            if left == 0 {
                *best = best.min(acc);
                return;
            }
            if cost.len() - i < left {
                return;
            }
            // Row i unassigned (possible when rows > cols).
            rec(cost, i + 1, used, left, acc, best);
            for j in 0..used.len() {
                if !used[j] {
                    used[j] = true;
                    rec(cost, i + 1, used, left - 1, acc + cost[i][j], best);
                    used[j] = false;
                }
            }
        }
        let mut best = f64::INFINITY;
        rec(cost, 0, &mut vec![false; cols], k, 0.0, &mut best);
        best
    }

    #[test]
    fn hungarian_matches_brute_force_on_random_rectangular_matrices() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for trial in 0..400 {
            let rows = rng.random_range(1..=6usize);
            let cols = rng.random_range(1..=6usize);
            let integer = trial % 2 == 0; // ties stress the tie handling
            let cost: Vec<Vec<f64>> = (0..rows)
                .map(|_| {
                    (0..cols)
                        .map(|_| {
                            if integer {
                                rng.random_range(0..4) as f64
                            } else {
                                rng.random_range(-1.0..1.0)
                            }
                        })
                        .collect()
                })
                .collect();
            let a = hungarian(&cost);
            assert_eq!(a.len(), rows);
            assert_eq!(
                a.iter().flatten().count(),
                rows.min(cols),
                "{cost:?} -> {a:?}"
            );
            let mut seen = vec![false; cols];
            for &j in a.iter().flatten() {
                assert!(!seen[j], "column {j} used twice");
                seen[j] = true;
            }
            assert!(
                (total(&cost, &a) - brute_force(&cost)).abs() < 1e-9,
                "{cost:?} -> {a:?}"
            );
        }
    }

    #[test]
    fn hungarian_handles_empty_and_obvious_cases() {
        assert!(hungarian(&[]).is_empty());
        assert_eq!(hungarian(&[vec![], vec![]]), vec![None, None]);
        let c = vec![vec![1.0, 0.0], vec![0.0, 1.0], vec![5.0, 5.0]];
        assert_eq!(hungarian(&c), vec![Some(1), Some(0), None]);
    }

    #[test]
    fn iou_is_intersection_over_union() {
        let a = [true, true, false, false];
        let b = [true, false, true, false];
        assert_eq!(iou(&a, &b), 1.0 / 3.0);
        assert_eq!(iou(&a, &a), 1.0);
        assert_eq!(iou(&[false; 3], &[false; 3]), 0.0);
    }
}
