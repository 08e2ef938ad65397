//! Surfel PLY round trips, mesh PLY layout, atomic writers and `.npy`/PNG round trips.

use proptest::prelude::*;
use trand_core::Mesh;
use trand_core::Surfels;
use trand_core::surfels::Surfel;
use trand_io::ply::{surfel_property_names, surfels_from_ply_bytes, surfels_to_ply_bytes};
use trand_io::{Image, IoError, RunDir, ScratchDir};

fn surfels_from(vals: &[f32], degree: u32, k: usize, n: usize) -> Surfels {
    let mut s = Surfels::new(degree, k).unwrap();
    let mut it = vals.iter().copied().cycle();
    let mut next = || it.next().unwrap();
    for _ in 0..n {
        s.push(&Surfel {
            mean: [next(), next(), next()],
            log_scale: [next(), next()],
            quat: [next(), next(), next(), next()],
            opacity_logit: next(),
            sh_dc: [next(), next(), next()],
            mask_dc: [next(), next(), next()],
            obj_logits: (0..k).map(|_| next()).collect(),
        });
    }
    for v in s.sh_rest.iter_mut().chain(s.mask_rest.iter_mut()) {
        *v = next();
    }
    s
}

fn bits(s: &Surfels) -> Vec<u32> {
    s.groups()
        .iter()
        .flat_map(|(_, v)| v.iter().map(|x| x.to_bits()))
        .collect()
}

proptest! {
    #[test]
    fn surfel_ply_round_trip_is_bit_exact(
        vals in prop::collection::vec(prop::num::f32::ANY, 1..64),
        degree in 0u32..=3, k in 1usize..20, n in 0usize..12,
    ) {
        let s = surfels_from(&vals, degree, k, n);
        let back = surfels_from_ply_bytes(&surfels_to_ply_bytes(&s), "mem.ply".as_ref()).unwrap();
        prop_assert_eq!((back.sh_degree, back.num_objects, back.len()), (degree, k, n));
        prop_assert_eq!(bits(&back), bits(&s));
    }
}

#[test]
fn surfel_ply_uses_2dgs_names_channel_major_rest_and_records_degree() {
    let mut s = surfels_from(&[0.5], 1, 3, 1);
    // sh_rest is [coeff][channel]: coefficient j of channel c at 3j + c.
    for j in 0..3 {
        for c in 0..3 {
            s.sh_rest[3 * j + c] = (10 * c + j) as f32;
        }
    }
    s.quats[0] = [1.0, 0.0, 0.0, 0.0];
    let bytes = surfels_to_ply_bytes(&s);
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.contains("format binary_little_endian 1.0"));
    assert!(header.contains("comment trand surfels sh_degree 1 num_objects 3"));
    let names = surfel_property_names(3, 3);
    let props: Vec<&str> = header
        .lines()
        .filter_map(|l| l.strip_prefix("property float "))
        .collect();
    assert_eq!(props, names.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(
        &props[..9],
        &[
            "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"
        ]
    );
    assert!(
        props.contains(&"f_seg_rest_8")
            && props.contains(&"obj_index2")
            && props.ends_with(&[
                "opacity", "scale_0", "scale_1", "rot_0", "rot_1", "rot_2", "rot_3"
            ])
    );
    let rec = &bytes[end..];
    let field = |name: &str| {
        let i = props.iter().position(|p| *p == name).unwrap();
        f32::from_le_bytes(rec[4 * i..4 * i + 4].try_into().unwrap())
    };
    // Channel-major: f_rest_{c·R + j}.
    assert_eq!(field("f_rest_0"), 0.0);
    assert_eq!(field("f_rest_1"), 1.0);
    assert_eq!(field("f_rest_3"), 10.0);
    assert_eq!(field("f_rest_8"), 22.0);
    // Identity rotation: the normal is +z.
    assert_eq!((field("nx"), field("ny"), field("nz")), (0.0, 0.0, 1.0));
    assert_eq!(bytes.len() - end, names.len() * 4);
}

#[test]
fn plain_2dgs_ply_reads_with_zero_mask_colour_and_logits() {
    // A 2DGS file: no comment, no f_seg_*, no obj_index*, degree from f_rest count, a double and a face element.
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    names.extend((0..9).map(|i| format!("f_rest_{i}")));
    names.extend(
        ["opacity", "scale_0", "scale_1", "rot_0", "rot_1", "rot_2"]
            .iter()
            .map(|s| s.to_string()),
    );
    let mut h = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 1\n");
    for n in &names {
        h += &format!("property float {n}\n");
    }
    h += "property double rot_3\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
    let mut b = h.into_bytes();
    for i in 0..names.len() {
        b.extend_from_slice(&(i as f32).to_le_bytes());
    }
    b.extend_from_slice(&7.5f64.to_le_bytes());
    let s = surfels_from_ply_bytes(&b, "2dgs.ply".as_ref()).unwrap();
    assert_eq!(
        (s.sh_degree, s.num_objects, s.len()),
        (1, trand_core::DEFAULT_NUM_OBJECTS, 1)
    );
    assert_eq!(s.means[0], [0.0, 1.0, 2.0]);
    assert_eq!(s.sh_rest[1], 12.0); // coefficient 0 of green = f_rest_3 (value 9 + 3)
    assert_eq!(s.quats[0], [21.0, 22.0, 23.0, 7.5]);
    assert_eq!((s.opacity_logits[0], s.log_scales[0]), (18.0, [19.0, 20.0]));
    assert!(s.mask_dc[0] == [0.0; 3] && s.obj_logits.iter().all(|&v| v == 0.0));
    s.validate().unwrap();
}

#[test]
fn truncated_or_ascii_ply_is_rejected_with_the_file_name() {
    let s = surfels_from(&[1.0, 2.0], 0, 2, 3);
    let bytes = surfels_to_ply_bytes(&s);
    let e = surfels_from_ply_bytes(&bytes[..bytes.len() - 1], "cut.ply".as_ref()).unwrap_err();
    assert!(
        matches!(e, IoError::Ply { .. })
            && e.to_string().contains("cut.ply")
            && e.to_string().contains("truncated"),
        "{e}"
    );
    let ascii = b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n";
    assert!(
        surfels_from_ply_bytes(ascii, "a.ply".as_ref())
            .unwrap_err()
            .to_string()
            .contains("ascii")
    );
}

#[test]
fn surfel_ply_file_round_trip_and_no_temp_file_left() {
    let dir = ScratchDir::new("io-ply").unwrap();
    let s = surfels_from(&[0.25, -3.0, 1e-7, 42.0], 3, 15, 50);
    let p = dir.path().join("sub/point_cloud.ply");
    trand_io::write_surfels_ply(&p, &s).unwrap();
    assert_eq!(bits(&trand_io::read_surfels_ply(&p).unwrap()), bits(&s));
    assert!(!dir.path().join("sub/point_cloud.ply.tmp").exists());
    let mut bad = s.clone();
    bad.opacity_logits.pop();
    assert!(matches!(
        trand_io::write_surfels_ply(&p, &bad),
        Err(IoError::Ply { .. })
    ));
}

#[test]
fn mesh_labels_above_255_are_written_as_ushort_not_truncated() {
    let m = Mesh {
        vertices: vec![[0.0; 3]; 2],
        labels: Some(vec![3, 300]),
        ..Mesh::default()
    };
    let b = trand_io::mesh::mesh_to_ply_bytes(&m);
    let end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    assert!(
        std::str::from_utf8(&b[..end])
            .unwrap()
            .contains("property ushort label\n")
    );
    assert_eq!(&b[end + 12..end + 14], &3u16.to_le_bytes());
    assert_eq!(&b[end + 26..end + 28], &300u16.to_le_bytes());
}

#[test]
fn mesh_ply_has_header_counts_and_exact_body_length() {
    let m = Mesh {
        vertices: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        colors: Some(vec![[255, 0, 0]; 3]),
        labels: Some(vec![1, 1, 2]),
        faces: vec![[0, 1, 2]],
        ..Mesh::default()
    };
    let b = trand_io::mesh::mesh_to_ply_bytes(&m);
    let end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let h = std::str::from_utf8(&b[..end]).unwrap();
    assert!(
        h.contains("element vertex 3\n")
            && h.contains("property uchar label\n")
            && h.contains("element face 1\nproperty list uchar int vertex_indices\n")
    );
    assert_eq!(b.len() - end, 3 * (12 + 3 + 1) + (1 + 12));
    assert_eq!(&b[b.len() - 13..], &[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]);
    let dir = ScratchDir::new("io-mesh").unwrap();
    let bad = Mesh {
        faces: vec![[0, 1, 3]],
        ..m
    };
    assert!(
        trand_io::write_mesh_ply(&dir.path().join("m.ply"), &bad)
            .unwrap_err()
            .to_string()
            .contains("face 0")
    );
}

#[test]
fn depth_png_in_mm_rounds_clamps_and_reads_back() {
    let dir = ScratchDir::new("io-depth").unwrap();
    let d = Image::from_vec(3, 2, 1, vec![0.0, 0.0014, 0.0016, 1.2345, 70.0, f32::NAN]).unwrap();
    let p = dir.path().join("d.png");
    trand_io::write_depth_png_mm(&p, &d).unwrap();
    let raw = trand_io::read_gray16(&p).unwrap();
    assert_eq!(raw.data, vec![0, 1, 2, 1235, 65535, 0]);
    let back = trand_io::read_depth_png(&p, 1.0).unwrap();
    assert!((back.get(0, 1, 0) - 1.235).abs() < 1e-6);
    assert!(!dir.path().join("d.png.tmp").exists());
}

#[test]
fn npy_round_trip_is_exact_and_shape_is_h_by_w() {
    let dir = ScratchDir::new("io-npy").unwrap();
    let d = Image::from_vec(
        3,
        2,
        1,
        vec![0.0, 1.5, f32::MIN_POSITIVE, -2.0, 1e30, 0.123_456_79],
    )
    .unwrap();
    let p = dir.path().join("x.npy");
    trand_io::write_npy_f32(&p, &d).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let header = String::from_utf8_lossy(&bytes[..bytes.len().min(128)]).to_string();
    assert!(header.contains("(2, 3"), "{header}");
    assert_eq!(trand_io::read_npy_f32(&p).unwrap(), d);
    std::fs::write(&p, b"not an npy").unwrap();
    assert!(matches!(
        trand_io::read_npy_f32(&p),
        Err(IoError::Npy { .. })
    ));
}

#[test]
fn rgb_and_label_pngs_round_trip() {
    let dir = ScratchDir::new("io-png").unwrap();
    let rgb = Image::from_vec(2, 2, 3, (0..12).map(|i| i * 20).collect()).unwrap();
    trand_io::write_rgb_png(&dir.path().join("c.png"), &rgb).unwrap();
    assert_eq!(trand_io::read_rgb8(&dir.path().join("c.png")).unwrap(), rgb);
    let prob = Image::from_vec(2, 1, 1, vec![0.5f32, 2.0]).unwrap();
    trand_io::write_probability_png(&dir.path().join("p.png"), &prob).unwrap();
    assert_eq!(
        trand_io::read_gray8(&dir.path().join("p.png"))
            .unwrap()
            .data,
        vec![128, 255]
    );
    assert!(matches!(
        trand_io::write_rgb_png(&dir.path().join("x.png"), &prob.to_owned_u8()),
        Err(IoError::PixelFormat { .. })
    ));
}

trait ToU8 {
    fn to_owned_u8(&self) -> Image<u8>;
}
impl ToU8 for Image<f32> {
    fn to_owned_u8(&self) -> Image<u8> {
        Image {
            width: self.width,
            height: self.height,
            channels: self.channels,
            data: vec![0; self.data.len()],
        }
    }
}

#[test]
fn run_dir_appears_only_on_commit() {
    let dir = ScratchDir::new("io-run").unwrap();
    let target = dir.path().join("run1");
    {
        let r = RunDir::create(&target).unwrap();
        std::fs::write(r.path().join("a.txt"), b"x").unwrap();
        assert!(!target.exists());
        // dropped without commit: nothing remains
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    let r = RunDir::create(&target).unwrap();
    std::fs::write(r.path().join("a.txt"), b"x").unwrap();
    assert_eq!(r.commit().unwrap(), target);
    assert_eq!(std::fs::read(target.join("a.txt")).unwrap(), b"x");
    assert!(RunDir::create(&target).is_err());
}
