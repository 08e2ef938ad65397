//! Shared helpers of the rasterizer tests: fixture loading and random scenes.
#![allow(dead_code)]

use std::path::PathBuf;

use rand::{RngExt, SeedableRng};
use trand_core::{Camera, Intrinsics, math::logit, sh::SH_C0};
use trand_render::ParamsOf;

pub struct Fixture {
    pub camera: Camera,
    pub params: ParamsOf<f64>,
    pub scales: Vec<[f64; 2]>,
    pub opacities: Vec<f64>,
    pub arrays: std::collections::HashMap<String, Vec<f64>>,
}

/// Loads a `surfel-raster` fixture from `tests/data/surfel-raster` (committed; see its README).
pub fn load_fixture(name: &str) -> Fixture {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/surfel-raster")
        .join(name);
    let file =
        std::fs::File::open(&path).unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
    let mut npz = zip::ZipArchive::new(std::io::BufReader::new(file))
        .unwrap_or_else(|e| panic!("read {} as a zip archive: {e}", path.display()));
    let mut arrays = std::collections::HashMap::new();
    for i in 0..npz.len() {
        let entry = npz.by_index(i).expect("zip entry");
        let n = entry.name().trim_end_matches(".npy").to_owned();
        let a = npyz::NpyFile::new(entry)
            .unwrap_or_else(|e| panic!("{}: array {n}: {e}", path.display()));
        let v = if a.dtype() == npyz::DType::new_scalar("<i8".parse().expect("type string")) {
            a.into_vec::<i64>()
                .expect("i64")
                .into_iter()
                .map(|v| v as f64)
                .collect()
        } else {
            a.into_vec::<f64>().expect("f64")
        };
        arrays.insert(n, v);
    }
    let s = |k: &str| arrays[k][0];
    let (w, h) = (s("W") as u32, s("H") as u32);
    let vm = &arrays["viewmat"];
    let r = [
        [vm[0], vm[1], vm[2]],
        [vm[4], vm[5], vm[6]],
        [vm[8], vm[9], vm[10]],
    ];
    let t = [vm[3], vm[7], vm[11]];
    let camera = Camera::new(
        Intrinsics {
            fx: s("fx"),
            fy: s("fy"),
            cx: s("cx"),
            cy: s("cy"),
            width: w,
            height: h,
        },
        r,
        t,
    );
    let n = arrays["opacities"].len();
    let mut p = ParamsOf::<f64>::zeros(n, 0, 1);
    let mut scales = Vec::new();
    for i in 0..n {
        let m = &arrays["means"][i * 3..i * 3 + 3];
        p.means[i] = [m[0], m[1], m[2]];
        let q = &arrays["quats"][i * 4..i * 4 + 4];
        p.quats[i] = [q[0], q[1], q[2], q[3]];
        let sc = [arrays["scales"][i * 2], arrays["scales"][i * 2 + 1]];
        scales.push(sc);
        p.log_scales[i] = [sc[0].ln(), sc[1].ln()];
        let o = arrays["opacities"][i];
        p.opacity_logits[i] = (o / (1.0 - o)).ln();
        for c in 0..3 {
            p.sh[i * 3 + c] = (arrays["colors"][i * 3 + c] - 0.5) / SH_C0;
        }
    }
    let opacities = arrays["opacities"].clone();
    Fixture {
        camera,
        params: p,
        scales,
        opacities,
        arrays,
    }
}

/// A camera looking at the origin from `dist` metres, tilted, small image.
pub fn test_camera(w: u32, h: u32, dist: f64) -> Camera {
    Camera::look_at(
        Intrinsics::centered(w as f64 * 0.9, w, h),
        glam::DVec3::new(0.3 * dist, -0.5 * dist, 0.8 * dist).normalize() * dist,
        glam::DVec3::ZERO,
        glam::DVec3::Z,
    )
}

/// A random scene of `n` surfels around the origin (radius `extent`), SH degree `deg`, `k` objects.
pub fn random_scene(n: usize, deg: u32, k: usize, extent: f64, seed: u64) -> ParamsOf<f64> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut p = ParamsOf::<f64>::zeros(n, deg, k);
    let nc = trand_core::sh::num_coeffs(deg);
    for i in 0..n {
        p.means[i] = [0, 1, 2].map(|_| rng.random_range(-extent..extent));
        p.log_scales[i] = [0, 1].map(|_| (extent * rng.random_range(0.15..0.5)).ln());
        p.quats[i] = [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0));
        p.opacity_logits[i] = logit(rng.random_range(0.3..0.9) as f32) as f64;
        for c in 0..nc * 3 {
            let amp = if c < 3 { 1.0 } else { 0.3 };
            p.sh[i * nc * 3 + c] = rng.random_range(-amp..amp);
            p.mask_sh[i * nc * 3 + c] = rng.random_range(-amp..amp);
        }
        for c in 0..k {
            p.obj_logits[i * k + c] = rng.random_range(-2.0..2.0);
        }
    }
    p
}

/// Random cotangent of the given length.
pub fn cotangent(len: usize, seed: u64) -> Vec<f64> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    (0..len).map(|_| rng.random_range(-1.0..1.0)).collect()
}
