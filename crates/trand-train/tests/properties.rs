//! Property tests of the discrete pieces (kNN, FPS, Dice range, SSIM symmetry) on random inputs.

use proptest::prelude::*;
use trand_train::losses::dice::dice;
use trand_train::losses::object::{farthest_point_sampling, k_nearest};
use trand_train::losses::photometric::ssim;

fn cloud() -> impl Strategy<Value = Vec<[f64; 3]>> {
    prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), 1..80)
}

fn d2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn knn_is_the_sorted_prefix_of_all_points(pts in cloud(), k_frac in 0.0f64..1.0, q in 0usize..1000) {
        let k = 1 + ((pts.len() - 1) as f64 * k_frac) as usize;
        let q = pts[q % pts.len()];
        let got = k_nearest(&pts, &q, k);
        let mut all: Vec<usize> = (0..pts.len()).collect();
        all.sort_by(|&a, &b| d2(&pts[a], &q).partial_cmp(&d2(&pts[b], &q)).unwrap().then(a.cmp(&b)));
        prop_assert_eq!(got, all[..k].to_vec());
    }

    #[test]
    fn fps_picks_distinct_points_and_is_prefix_consistent(pts in cloud(), frac in 0.0f64..1.0) {
        let g = 1 + ((pts.len() - 1) as f64 * frac) as usize;
        let all = farthest_point_sampling(&pts, pts.len());
        let got = farthest_point_sampling(&pts, g);
        prop_assert_eq!(&got[..], &all[..g]);
        let mut seen = vec![false; pts.len()];
        for &i in &got {
            // A repeat is only possible among coincident points.
            prop_assert!(!seen[i] || got.iter().any(|&j| j != i && d2(&pts[i], &pts[j]) == 0.0));
            seen[i] = true;
        }
    }

    #[test]
    fn dice_lies_in_the_unit_interval(
        probs in prop::collection::vec(0.0f64..1.0, 4 * 30),
        labels in prop::collection::vec(0usize..4, 30),
    ) {
        let mut t = vec![0.0; 4 * 30];
        for (i, &l) in labels.iter().enumerate() {
            t[4 * i + l] = 1.0;
        }
        let (v, g) = dice(&probs, &t, 4);
        prop_assert!((0.0..=1.0).contains(&v));
        prop_assert!(g.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn ssim_is_symmetric_and_at_most_one(
        a in prop::collection::vec(0.0f64..1.0, 7 * 5 * 2),
        b in prop::collection::vec(0.0f64..1.0, 7 * 5 * 2),
    ) {
        let (sab, _) = ssim(&a, &b, 7, 5, 2);
        let (sba, _) = ssim(&b, &a, 7, 5, 2);
        prop_assert!((sab - sba).abs() < 1e-12);
        prop_assert!(sab <= 1.0 + 1e-12);
    }
}
