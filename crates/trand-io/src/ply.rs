//! Surfel PLY files: the 2DGS/3DGS `point_cloud.ply` layout plus TRAN-D's mask colour and object logits.
//!
//! Binary little-endian, one `vertex` element, all properties `float`, raw (pre-activation) values, in
//! the order of the authors' files (reference notes §3.1):
//!
//! ```text
//! x y z  nx ny nz  f_dc_0..2  f_rest_0..3R-1  f_seg_dc_0..2  f_seg_rest_0..3R-1  obj_index0..K-1
//! opacity  scale_0 scale_1  rot_0..3
//! ```
//! * `R = (d+1)² − 1` SH coefficients per channel beyond DC. `f_rest` is **channel-major** (all R
//!   coefficients of red, then green, then blue), the 3DGS convention, whereas [`Surfels::sh_rest`] is
//!   `[coefficient][channel]`: `f_rest_{c·R + k} = sh_rest[3k + c]`. The same holds for `f_seg_rest`.
//! * `nx ny nz` hold the surfel normal (third column of `R(q)`; 2DGS writes zeros). The reader ignores them.
//! * `rot_0..3` is the raw quaternion `(w, x, y, z)`; `scale_*` are log-scales; `opacity` a logit.
//! * A header comment `trand surfels sh_degree D num_objects K` records the degree and object count.
//!
//! The reader finds properties by name, so it also reads plain 2DGS files (no `f_seg_*`, no
//! `obj_index*`: those are zero, with K from the comment or [`DEFAULT_NUM_OBJECTS`]) and accepts any
//! scalar property type. Writing then reading gives back the exact bits. Counts from the header are
//! checked against the bytes present (with overflow-checked arithmetic) before anything is allocated,
//! and the object-channel count is bounded by [`MAX_NUM_OBJECTS`]. Values are returned as stored,
//! non-finite ones included; consumers check them with `Surfels::validate`.

use std::collections::HashMap;
use std::path::Path;

use trand_core::math::quat_to_rotmat;
use trand_core::sh::{MAX_SH_DEGREE, num_coeffs};
use trand_core::{DEFAULT_NUM_OBJECTS, MAX_NUM_OBJECTS, Surfels};

use crate::error::IoError;
use crate::write::write_atomic;

const COMMENT_TAG: &str = "trand surfels";

/// More vertex properties than any surfel layout has (degree 3 with 64 object channels has 170).
const MAX_PROPERTIES: usize = 4096;

/// The property names of a surfel PLY with `rest` coefficients per channel and `k` object channels.
pub fn surfel_property_names(rest: usize, k: usize) -> Vec<String> {
    let mut names: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    names.extend((0..3).map(|i| format!("f_dc_{i}")));
    names.extend((0..3 * rest).map(|i| format!("f_rest_{i}")));
    names.extend((0..3).map(|i| format!("f_seg_dc_{i}")));
    names.extend((0..3 * rest).map(|i| format!("f_seg_rest_{i}")));
    names.extend((0..k).map(|i| format!("obj_index{i}")));
    names.push("opacity".into());
    names.extend((0..2).map(|i| format!("scale_{i}")));
    names.extend((0..4).map(|i| format!("rot_{i}")));
    names
}

/// Serialises surfels to PLY bytes.
pub fn surfels_to_ply_bytes(s: &Surfels) -> Vec<u8> {
    let n = s.len();
    let rest = s.rest_coeffs();
    let k = s.num_objects;
    let names = surfel_property_names(rest, k);
    let mut out = Vec::with_capacity(512 + names.len() * 16 + n * names.len() * 4);
    out.extend_from_slice(b"ply\nformat binary_little_endian 1.0\n");
    out.extend_from_slice(
        format!(
            "comment {COMMENT_TAG} sh_degree {} num_objects {k}\n",
            s.sh_degree
        )
        .as_bytes(),
    );
    out.extend_from_slice(format!("element vertex {n}\n").as_bytes());
    for name in &names {
        out.extend_from_slice(format!("property float {name}\n").as_bytes());
    }
    out.extend_from_slice(b"end_header\n");
    let rs = 3 * rest;
    let mut push = |v: f32| out.extend_from_slice(&v.to_le_bytes());
    for i in 0..n {
        s.means[i].iter().for_each(|&v| push(v));
        let normal = quat_to_rotmat(s.quats[i])
            .map(|(m, _)| [m[0][2], m[1][2], m[2][2]])
            .unwrap_or([0.0; 3]);
        normal.iter().for_each(|&v| push(v));
        s.sh_dc[i].iter().for_each(|&v| push(v));
        for c in 0..3 {
            (0..rest).for_each(|j| push(s.sh_rest[i * rs + 3 * j + c]));
        }
        s.mask_dc[i].iter().for_each(|&v| push(v));
        for c in 0..3 {
            (0..rest).for_each(|j| push(s.mask_rest[i * rs + 3 * j + c]));
        }
        s.obj_logits[i * k..(i + 1) * k]
            .iter()
            .for_each(|&v| push(v));
        push(s.opacity_logits[i]);
        s.log_scales[i].iter().for_each(|&v| push(v));
        s.quats[i].iter().for_each(|&v| push(v));
    }
    out
}

/// Writes surfels as a binary PLY, atomically. The surfels must be consistent ([`Surfels::validate`]'s lengths).
pub fn write_surfels_ply(path: &Path, s: &Surfels) -> Result<(), IoError> {
    if let Err(e @ trand_core::SurfelsError::Length { .. }) = s.validate() {
        return Err(IoError::Ply {
            path: path.into(),
            reason: e.to_string(),
        });
    }
    write_atomic(path, &surfels_to_ply_bytes(s))
}

/// A scalar PLY property type.
#[derive(Clone, Copy, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(t: &str) -> Option<Self> {
        Some(match t {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Reads one value as `f32` (exact for `float` properties).
    fn read(self, b: &[u8]) -> f32 {
        match self {
            Self::I8 => b[0] as i8 as f32,
            Self::U8 => b[0] as f32,
            Self::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
            Self::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
            Self::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            Self::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            Self::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            Self::F64 => f64::from_le_bytes(b[..8].try_into().expect("8 bytes")) as f32,
        }
    }
}

struct Header {
    count: usize,
    /// (name, type, byte offset within a vertex record)
    props: Vec<(String, Scalar, usize)>,
    stride: usize,
    sh_degree: Option<u32>,
    num_objects: Option<usize>,
    body_offset: usize,
}

fn parse_header(bytes: &[u8], path: &Path) -> Result<Header, IoError> {
    let err = |reason: String| IoError::Ply {
        path: path.into(),
        reason,
    };
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| err("no `end_header` line".into()))?;
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| err("header is not UTF-8".into()))?;
    let mut lines = text.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(err("not a PLY file (first line is not `ply`)".into()));
    }
    let mut h = Header {
        count: 0,
        props: Vec::new(),
        stride: 0,
        sh_degree: None,
        num_objects: None,
        body_offset: end + 11,
    };
    let mut element: Option<String> = None;
    let mut seen_vertex = false;
    for line in lines {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", f, _] if *f != "binary_little_endian" => {
                return Err(err(format!(
                    "format `{f}` is not supported (binary_little_endian only)"
                )));
            }
            ["comment", rest @ ..] => {
                let words = rest.join(" ");
                if let Some(tail) = words.strip_prefix(COMMENT_TAG) {
                    let w: Vec<&str> = tail.split_whitespace().collect();
                    for pair in w.chunks(2) {
                        match pair {
                            ["sh_degree", v] => h.sh_degree = v.parse().ok(),
                            ["num_objects", v] => h.num_objects = v.parse().ok(),
                            _ => {}
                        }
                    }
                }
            }
            ["element", name, n] => {
                if seen_vertex {
                    element = Some(name.to_string());
                    continue; // elements after the vertices are ignored
                }
                if *name != "vertex" {
                    return Err(err(format!(
                        "element `{name}` before `vertex` is not supported"
                    )));
                }
                seen_vertex = true;
                h.count = n
                    .parse()
                    .map_err(|_| err(format!("bad vertex count `{n}`")))?;
                element = Some(name.to_string());
            }
            ["property", "list", ..] if element.as_deref() == Some("vertex") => {
                return Err(err("list properties in `vertex` are not supported".into()));
            }
            ["property", ty, name] if element.as_deref() == Some("vertex") => {
                let s = Scalar::parse(ty)
                    .ok_or_else(|| err(format!("property `{name}` has unknown type `{ty}`")))?;
                if h.props.len() >= MAX_PROPERTIES {
                    return Err(err(format!("more than {MAX_PROPERTIES} vertex properties")));
                }
                h.props.push((name.to_string(), s, h.stride));
                h.stride += s.size();
            }
            _ => {}
        }
    }
    if !seen_vertex {
        return Err(err("no `vertex` element".into()));
    }
    Ok(h)
}

/// Parses surfel PLY bytes; `path` only names the source in errors.
pub fn surfels_from_ply_bytes(bytes: &[u8], path: &Path) -> Result<Surfels, IoError> {
    let err = |reason: String| IoError::Ply {
        path: path.into(),
        reason,
    };
    let h = parse_header(bytes, path)?;
    let body = &bytes[h.body_offset..];
    // The count comes from the file: multiply with overflow checks, and compare with the bytes
    // present before anything is allocated from it.
    let needed = h.count.checked_mul(h.stride);
    if needed.is_none_or(|b| body.len() < b) {
        return Err(err(format!(
            "truncated: {} vertices of {} bytes need {} bytes, found {}",
            h.count,
            h.stride,
            needed.map_or_else(|| "more than 2^64".to_string(), |b| b.to_string()),
            body.len()
        )));
    }
    if h.count > 0 && h.stride == 0 {
        return Err(err(format!("{} vertices but no properties", h.count)));
    }
    let index: HashMap<&str, (Scalar, usize)> = h
        .props
        .iter()
        .map(|(n, s, o)| (n.as_str(), (*s, *o)))
        .collect();
    let count_prefix = |p: &str| {
        (0..)
            .take_while(|i| index.contains_key(format!("{p}{i}").as_str()))
            .count()
    };
    let n_rest = count_prefix("f_rest_");
    let n_seg_rest = count_prefix("f_seg_rest_");
    let k_file = count_prefix("obj_index");
    if n_rest % 3 != 0 {
        return Err(err(format!(
            "{n_rest} f_rest properties is not a multiple of 3"
        )));
    }
    let rest = n_rest / 3;
    let degree = match h.sh_degree {
        Some(d) => d,
        None => (0..=MAX_SH_DEGREE)
            .find(|&d| num_coeffs(d) - 1 == rest)
            .ok_or_else(|| err(format!("{n_rest} f_rest properties match no SH degree")))?,
    };
    if degree > MAX_SH_DEGREE || num_coeffs(degree) - 1 != rest {
        return Err(err(format!(
            "sh_degree {degree} does not match {n_rest} f_rest properties"
        )));
    }
    if n_seg_rest != 0 && n_seg_rest != n_rest {
        return Err(err(format!(
            "{n_seg_rest} f_seg_rest properties but {n_rest} f_rest"
        )));
    }
    let k = if k_file > 0 {
        k_file
    } else {
        h.num_objects.unwrap_or(DEFAULT_NUM_OBJECTS)
    };
    if k > MAX_NUM_OBJECTS {
        return Err(err(format!(
            "num_objects {k} is above the supported maximum {MAX_NUM_OBJECTS}"
        )));
    }
    if let Some(kc) = h.num_objects
        && k_file > 0
        && kc != k_file
    {
        return Err(err(format!(
            "comment says num_objects {kc} but the file has {k_file} obj_index properties"
        )));
    }
    let mut s = Surfels::new(degree, k).map_err(|e| err(e.to_string()))?;
    let req = |name: &str| {
        index
            .get(name)
            .copied()
            .ok_or_else(|| err(format!("missing property `{name}`")))
    };
    let opt = |name: &str| index.get(name).copied();
    let xyz = [req("x")?, req("y")?, req("z")?];
    let dc = [req("f_dc_0")?, req("f_dc_1")?, req("f_dc_2")?];
    let op = req("opacity")?;
    let sc = [req("scale_0")?, req("scale_1")?];
    let rot = [req("rot_0")?, req("rot_1")?, req("rot_2")?, req("rot_3")?];
    let fr: Vec<_> = (0..n_rest)
        .map(|i| index[format!("f_rest_{i}").as_str()])
        .collect();
    let seg_dc = [opt("f_seg_dc_0"), opt("f_seg_dc_1"), opt("f_seg_dc_2")];
    let seg_rest: Vec<_> = (0..n_seg_rest)
        .map(|i| index[format!("f_seg_rest_{i}").as_str()])
        .collect();
    let obj: Vec<_> = (0..k_file)
        .map(|i| index[format!("obj_index{i}").as_str()])
        .collect();
    let n = h.count;
    s.means.reserve(n);
    s.sh_rest = vec![0.0; n * 3 * rest];
    s.mask_rest = vec![0.0; n * 3 * rest];
    s.obj_logits = vec![0.0; n * k];
    for i in 0..n {
        let rec = &body[i * h.stride..(i + 1) * h.stride];
        let get = |(t, o): (Scalar, usize)| t.read(&rec[o..]);
        s.means.push(xyz.map(get));
        s.sh_dc.push(dc.map(get));
        s.opacity_logits.push(get(op));
        s.log_scales.push(sc.map(get));
        s.quats.push(rot.map(get));
        s.mask_dc.push(seg_dc.map(|p| p.map(get).unwrap_or(0.0)));
        for c in 0..3 {
            for j in 0..rest {
                s.sh_rest[i * 3 * rest + 3 * j + c] = get(fr[c * rest + j]);
                if n_seg_rest > 0 {
                    s.mask_rest[i * 3 * rest + 3 * j + c] = get(seg_rest[c * rest + j]);
                }
            }
        }
        for (c, &p) in obj.iter().enumerate() {
            s.obj_logits[i * k + c] = get(p);
        }
    }
    Ok(s)
}

/// Reads a surfel PLY file.
pub fn read_surfels_ply(path: &Path) -> Result<Surfels, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    surfels_from_ply_bytes(&bytes, path)
}
