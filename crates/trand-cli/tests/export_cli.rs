//! `trand export` as a user runs it: the PLY files have standard headers whose element counts and
//! property types account for every byte of the body, the points are the object surfels of a
//! hand-made run, the splats read back as the run's surfels, and bad input is refused with the file
//! named and nothing written.

mod common;

use std::path::Path;

use common::{ok, tiny_run, trand_in};
use glam::{Quat, Vec3};
use trand_core::Surfels;
use trand_core::surfels::Surfel;
use trand_io::ScratchDir;

/// One element of a PLY header: name, count, and its properties as (type, name); a list property
/// has type `list uchar int`.
struct Element {
    name: String,
    count: usize,
    props: Vec<(String, String)>,
}

/// One point record: position, normal, colour, object id.
type Point = ([f32; 3], [f32; 3], [u8; 3], Option<u16>);

/// A binary PLY split into its header elements and the body of each element.
struct Ply {
    elements: Vec<Element>,
    bodies: Vec<Vec<u8>>,
}

fn size(ty: &str) -> usize {
    match ty {
        "uchar" => 1,
        "ushort" => 2,
        "float" | "int" => 4,
        t => panic!("unexpected type {t}"),
    }
}

/// Parses a PLY written by trand: binary little endian, and the body exactly the size the header
/// announces (faces are triangles: 1 + 3·4 bytes).
fn read_ply(path: &Path) -> Ply {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let mut lines = header.lines();
    assert_eq!(lines.next(), Some("ply"));
    assert_eq!(lines.next(), Some("format binary_little_endian 1.0"));
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["element", name, n] => elements.push(Element {
                name: name.to_string(),
                count: n.parse().unwrap(),
                props: Vec::new(),
            }),
            ["property", "list", a, b, name] => {
                assert_eq!((*a, *b, *name), ("uchar", "int", "vertex_indices"));
                let e = elements.last_mut().unwrap();
                e.props.push(("list uchar int".into(), name.to_string()));
            }
            ["property", ty, name] => {
                let e = elements.last_mut().unwrap();
                e.props.push((ty.to_string(), name.to_string()));
            }
            ["comment", ..] | ["end_header"] => {}
            other => panic!("{}: unexpected header line {other:?}", path.display()),
        }
    }
    let mut at = end;
    let mut bodies = Vec::new();
    for e in &elements {
        let stride: usize = e
            .props
            .iter()
            .map(|(t, _)| if t.starts_with("list") { 13 } else { size(t) })
            .sum();
        bodies.push(bytes[at..at + e.count * stride].to_vec());
        at += e.count * stride;
    }
    assert_eq!(at, bytes.len(), "{}: body size", path.display());
    Ply { elements, bodies }
}

impl Ply {
    fn element(&self, name: &str) -> (&Element, &[u8]) {
        let i = self.elements.iter().position(|e| e.name == name).unwrap();
        (&self.elements[i], &self.bodies[i])
    }

    fn count(&self, name: &str) -> usize {
        self.elements
            .iter()
            .find(|e| e.name == name)
            .map_or(0, |e| e.count)
    }

    /// The names of the vertex properties.
    fn vertex_props(&self) -> Vec<String> {
        self.element("vertex")
            .0
            .props
            .iter()
            .map(|p| p.1.clone())
            .collect()
    }

    /// Faces, checked to be triangles.
    fn faces(&self) -> Vec<[i32; 3]> {
        let (e, body) = self.element("face");
        (0..e.count)
            .map(|i| {
                let r = &body[13 * i..13 * (i + 1)];
                assert_eq!(r[0], 3);
                [0, 1, 2].map(|k| i32::from_le_bytes(r[1 + 4 * k..5 + 4 * k].try_into().unwrap()))
            })
            .collect()
    }

    /// Point records of a point-cloud PLY: position, normal, colour, object id.
    fn points(&self) -> Vec<Point> {
        let (e, body) = self.element("vertex");
        let with_id = e.props.len() == 10;
        let stride = if with_id { 29 } else { 27 };
        let f = |r: &[u8], k: usize| f32::from_le_bytes(r[4 * k..4 * k + 4].try_into().unwrap());
        (0..e.count)
            .map(|i| {
                let r = &body[stride * i..stride * (i + 1)];
                (
                    [f(r, 0), f(r, 1), f(r, 2)],
                    [f(r, 3), f(r, 4), f(r, 5)],
                    [r[24], r[25], r[26]],
                    with_id.then(|| u16::from_le_bytes([r[27], r[28]])),
                )
            })
            .collect()
    }
}

/// A flat square of surfels (4 mm apart) facing `normal`, centred at `c`, every surfel in `channel`.
fn square(s: &mut Surfels, c: Vec3, normal: Vec3, channel: usize) {
    let q = Quat::from_rotation_arc(Vec3::Z, normal);
    let mut logits = vec![-3.0; s.num_objects];
    logits[channel] = 3.0;
    for i in -6..=6 {
        for j in -6..=6 {
            let p = c + q * Vec3::new(i as f32 * 0.004, j as f32 * 0.004, 0.0);
            s.push(&Surfel {
                mean: p.to_array(),
                log_scale: [(0.003f32).ln(); 2],
                quat: [q.w, q.x, q.y, q.z],
                opacity_logit: if (i + j) % 4 == 0 { -4.0 } else { 3.0 },
                sh_dc: [0.8, -0.3 * channel as f32, 0.1],
                mask_dc: [0.0; 3],
                obj_logits: logits.clone(),
            });
        }
    }
}

/// A run folder by hand: two objects (ids 4 and 6 in channels 1 and 2), each a tent of two squares
/// over the table; object 8 (channel 0) has no surfels, as one removed at t = 1.
fn hand_made_run(dir: &Path) -> Surfels {
    let mut s = Surfels::new(1, 3).unwrap();
    for (x, c) in [(-0.06f32, 1), (0.06, 2)] {
        square(
            &mut s,
            Vec3::new(x, 0.0, 0.05),
            Vec3::new(0.0, 0.3, 1.0).normalize(),
            c,
        );
        square(&mut s, Vec3::new(x, 0.03, 0.03), Vec3::Y, c);
    }
    std::fs::create_dir_all(dir).unwrap();
    trand_io::write_surfels_ply(&dir.join("surfels.ply"), &s).unwrap();
    std::fs::write(
        dir.join("run.json"),
        r#"{"state": "t0", "object_channels": [[4, 1], [6, 2], [8, 0]], "depth_clamp_m": null}"#,
    )
    .unwrap();
    std::fs::write(
        dir.join("config.toml"),
        "[train]\nbackground = [0.0, 0.0, 0.0]\nnear = 0.2\nsh_degree = 1\n",
    )
    .unwrap();
    s
}

#[test]
fn exported_points_meshes_and_splats_round_trip_a_hand_made_run() {
    let tmp = ScratchDir::new("cli-export").unwrap();
    let dir = tmp.path();
    let s = hand_made_run(&dir.join("run"));
    ok(trand_in(
        dir,
        &["export", "--run", "run", "--out", "out", "--splats"],
    ));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/export.json")).unwrap())
            .unwrap();

    // Points: exactly the surfels of each object at or above the opacity threshold, in order.
    let mut all = Vec::new();
    for (id, channel) in [(4u16, 1usize), (6, 2)] {
        let ply = read_ply(&dir.join(format!("out/object_{id}.ply")));
        assert_eq!(
            ply.vertex_props(),
            ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
        );
        let want: Vec<usize> = (0..s.len())
            .filter(|&i| s.obj_logits[3 * i + channel] > 0.0 && s.opacity_logits[i] > 0.0)
            .collect();
        let got = ply.points();
        assert_eq!(got.len(), want.len());
        for (p, &i) in got.iter().zip(&want) {
            assert_eq!(p.0, s.means[i]);
            let q = s.quats[i];
            let n = Quat::from_xyzw(q[1], q[2], q[3], q[0]) * Vec3::Z;
            assert!((Vec3::from(p.1) - n).length() < 1e-5);
            let rgb =
                s.sh_dc[i].map(|d| ((0.5 + 0.282_094_8 * d).clamp(0.0, 1.0) * 255.0).round() as u8);
            assert_eq!(p.2, rgb);
        }
        all.extend(got.iter().map(|p| (p.0, id)));

        // The object's mesh: triangles indexing existing vertices, near the object's surfels.
        let mesh = read_ply(&dir.join(format!("out/object_{id}_mesh.ply")));
        let n = mesh.count("vertex");
        let faces = mesh.faces();
        assert!(!faces.is_empty(), "object {id}: empty mesh");
        assert!(faces.iter().flatten().all(|&v| v >= 0 && (v as usize) < n));
        let obj = summary["objects"]
            .as_array()
            .unwrap()
            .iter()
            .find(|o| o["id"] == id)
            .unwrap();
        assert_eq!(obj["points"], want.len());
        assert_eq!(
            (obj["mesh_vertices"].as_u64(), obj["mesh_faces"].as_u64()),
            (Some(n as u64), Some(faces.len() as u64))
        );
    }
    assert!(
        !dir.join("out/object_8.ply").exists() && summary["objects"].as_array().unwrap().len() == 2,
        "an object without surfels is not exported"
    );
    let scene = read_ply(&dir.join("out/scene_points.ply"));
    assert_eq!(scene.vertex_props().last().unwrap(), "object_id");
    let got: Vec<_> = scene.points().iter().map(|p| (p.0, p.3.unwrap())).collect();
    assert_eq!(got, all);
    let mesh = read_ply(&dir.join("out/mesh.ply"));
    let n = mesh.count("vertex");
    assert!(
        mesh.faces()
            .iter()
            .flatten()
            .all(|&v| v >= 0 && (v as usize) < n)
    );

    // Splats: every surfel, positions and rotations as stored, three scales.
    let splats = read_ply(&dir.join("out/splats.ply"));
    assert_eq!(splats.count("vertex"), s.len());
    assert_eq!(splats.vertex_props().len(), 62);
    let back = trand_io::read_surfels_ply(&dir.join("out/splats.ply")).unwrap();
    assert_eq!(back.means, s.means);
    assert_eq!(back.quats, s.quats);
    assert_eq!(back.opacity_logits, s.opacity_logits);
    assert_eq!(back.log_scales, s.log_scales);
}

#[test]
fn export_of_a_tiny_reconstruction_matches_its_summary() {
    let tmp = ScratchDir::new("cli-export-run").unwrap();
    let dir = tmp.path();
    tiny_run(dir, 30);
    ok(trand_in(dir, &["export", "--run", "run0", "--out", "out"]));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/export.json")).unwrap())
            .unwrap();
    assert_eq!(summary["state"], "t0");
    let objects = summary["objects"].as_array().unwrap();
    assert!(!objects.is_empty());
    let mut total = 0;
    for o in objects {
        let id = o["id"].as_u64().unwrap();
        let pts = read_ply(&dir.join(format!("out/object_{id}.ply")));
        assert_eq!(pts.count("vertex") as u64, o["points"].as_u64().unwrap());
        total += pts.count("vertex");
        let mesh = read_ply(&dir.join(format!("out/object_{id}_mesh.ply")));
        assert_eq!(mesh.count("face") as u64, o["mesh_faces"].as_u64().unwrap());
    }
    assert_eq!(
        read_ply(&dir.join("out/scene_points.ply")).count("vertex"),
        total
    );
    assert!(
        !dir.join("out/splats.ply").exists(),
        "splats only with --splats"
    );
}

#[test]
fn export_errors_name_the_file_and_leave_nothing_behind() {
    let tmp = ScratchDir::new("cli-export-errors").unwrap();
    let dir = tmp.path();
    hand_made_run(&dir.join("run"));
    std::fs::create_dir_all(dir.join("mine")).unwrap();
    std::fs::write(dir.join("mine/notes.txt"), "keep").unwrap();
    std::fs::create_dir_all(dir.join("no_surfels")).unwrap();
    for f in ["run.json", "config.toml"] {
        std::fs::copy(dir.join("run").join(f), dir.join("no_surfels").join(f)).unwrap();
    }
    for (what, args, named) in [
        (
            "missing run",
            vec!["--run", "nowhere", "--out", "o1"],
            "nowhere",
        ),
        ("no run.json", vec!["--run", "mine", "--out", "o2"], "mine"),
        (
            "no surfels",
            vec!["--run", "no_surfels", "--out", "o3"],
            "surfels.ply",
        ),
        (
            "existing out",
            vec!["--run", "run", "--out", "mine"],
            "mine",
        ),
        (
            "bad opacity",
            vec!["--run", "run", "--out", "o4", "--min-opacity", "1.5"],
            "--min-opacity",
        ),
    ] {
        let mut full = vec!["export"];
        full.extend(args.iter().copied());
        let out = trand_in(dir, &full);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{what}: accepted");
        assert!(err.contains(named), "{what}: {err}");
    }
    for o in ["o1", "o2", "o3", "o4"] {
        assert!(!dir.join(o).exists(), "{o} left behind");
    }
    let left: Vec<_> = std::fs::read_dir(dir.join("mine")).unwrap().collect();
    assert_eq!(left.len(), 1, "the existing folder was touched");
    assert!(
        std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .all(|e| !e.file_name().to_string_lossy().contains(".tmp-")),
        "temporary folder left behind"
    );
}
