use super::*;
use crate::table_height::painted::{speckle, views_of_table};

/// Each view's camera off by half a degree and a few millimetres, a different way per view.
fn perturbed(views: &mut [TrainView]) -> Vec<Camera> {
    let exact: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    for (k, v) in views.iter_mut().enumerate() {
        let a = k as f64 * 2.1 + 0.3;
        let axis = DVec3::new(a.cos(), a.sin(), 0.6 * (1.7 * a).cos()).normalize();
        let w = axis * 0.5f64.to_radians();
        let c = v.camera.center();
        // A turn about the camera's own centre, then its centre moved 3 mm.
        let shift = DVec3::new((2.0 * a).sin(), (2.0 * a).cos(), 0.5).normalize() * 0.003;
        let d = -w.cross(c) - shift;
        v.camera = corrected([w.x, w.y, w.z, d.x, d.y, d.z], &v.camera);
    }
    exact
}

/// Largest disagreement (px) between where `a` and `b` map view `i`'s table pixels into view `j`.
fn transfer_error(a: &[Camera], b: &[Camera]) -> f64 {
    let mut worst: f64 = 0.0;
    for i in 0..a.len() {
        for j in 0..a.len() {
            if i == j {
                continue;
            }
            for (x, y) in [
                (80.0, 150.0),
                (160.0, 180.0),
                (240.0, 150.0),
                (160.0, 130.0),
            ] {
                let on_table = |c: &Camera| {
                    let (o, d) = (c.center(), c.ray_direction(x, y));
                    o - o.z / d.z * d
                };
                let (pa, pb) = (on_table(&a[i]), on_table(&b[i]));
                let (Some(qa), Some(qb)) = (a[j].project(pa), b[j].project(pb)) else {
                    continue;
                };
                worst = worst.max((qa.0 - qb.0).hypot(qa.1 - qb.1));
            }
        }
    }
    worst
}

#[test]
fn a_textured_table_brings_the_views_back_into_agreement_on_the_plane() {
    let mut views = views_of_table(0.0, speckle);
    let exact = perturbed(&mut views);
    let given: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    let before = transfer_error(&given, &exact);
    let a = align(&views).expect("the views see the table");
    assert!(a.kept, "{a:?}");
    let aligned: Vec<Camera> = (0..views.len()).map(|i| a.camera(i, &given[i])).collect();
    let after = transfer_error(&aligned, &exact);
    assert!(
        before > 2.0,
        "the perturbation moves the table by pixels: {before}"
    );
    assert!(
        after < 0.3,
        "aligned views still disagree by {after} px (given {before})"
    );
}

#[test]
fn cameras_that_already_agree_on_the_table_are_kept_as_given() {
    let views = views_of_table(0.0, speckle);
    let a = align(&views).expect("the views see the table");
    assert!(!a.kept, "{a:?}");
}

#[test]
fn a_table_without_texture_keeps_the_given_cameras() {
    let mut views = views_of_table(0.0, |x, y| (0.5 + 0.4 * x - 0.2 * y) as f32);
    perturbed(&mut views);
    let a = align(&views).expect("the views see the table");
    assert!(!a.kept, "{a:?}");
    let c = views[2].camera;
    assert_eq!(a.camera(2, &c), c);
}

#[test]
fn a_common_motion_within_the_plane_is_taken_out_and_nothing_else() {
    let centres: Vec<DVec3> = (0..6)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 6.0;
            DVec3::new(0.6 * a.cos(), 0.6 * a.sin(), 0.45)
        })
        .collect();
    let common = [0.0, 0.0, 0.004, 0.002, -0.003, 0.0];
    let mut xi = vec![common; 6];
    hold_in_plane_gauge(&mut xi, &centres);
    assert!(xi.iter().flatten().all(|v| v.abs() < 1e-12), "{xi:?}");
    // A common vertical move is no in-plane motion: it stays.
    let mut up = vec![[0.0, 0.0, 0.0, 0.0, 0.0, 0.002]; 6];
    hold_in_plane_gauge(&mut up, &centres);
    assert!(
        up.iter()
            .all(|x| (x[5] - 0.002).abs() < 1e-12 && x[3].abs() < 1e-12)
    );
}

#[test]
fn the_six_by_six_solve_inverts_a_known_system() {
    let mut h = [[0.0; 6]; 6];
    for (i, row) in h.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = 1.0 / (1.0 + i as f64 + j as f64) + if i == j { 2.0 } else { 0.0 };
        }
    }
    let x = [1.0, -2.0, 0.5, 3.0, 0.0, -1.0];
    let b: Vec<f64> = h
        .iter()
        .map(|r| r.iter().zip(&x).map(|(a, b)| a * b).sum())
        .collect();
    let got = solve6(h, b.try_into().unwrap()).expect("regular");
    for (g, e) in got.iter().zip(&x) {
        assert!((g - e).abs() < 1e-10, "{got:?}");
    }
}
