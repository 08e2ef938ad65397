//! A list of named cameras to render a finished run at (`trand render --cameras FILE`).
//!
//! ```text
//! [ { "name": "wrist",                      file-name-safe: letters, digits, `_`, `-`, `.`; unique
//!     "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],          3x3 row-major (or 9 numbers)
//!     "world_to_camera": [[r, r, r, tx], ..., [0, 0, 0, 1]], 4x4 row-major (or 16 numbers)
//!     "width": 1280, "height": 720 }, ... ]
//! ```
//! OpenCV conventions, as everywhere in trand (`trand_core::camera`): x right, y down, z forward,
//! metres, and **integer pixel centres**, which is what OpenCV's calibration gives, so a calibrated
//! `K` is used as it is. The rasterizer has no skew, so `K[0][1]` must be 0.
//!
//! Every value is checked before anything is rendered, and an error names the file and the field
//! (`[2].K[0][0]`). `NaN` and `Infinity` are not JSON, but Python's `json.dump` writes them; they are
//! read as such, so that the message says which field holds one instead of where the parser choked.

use std::collections::HashSet;
use std::path::Path;

use serde_json::Value;
use trand_core::Camera;

use crate::arrays::camera_from_matrices;
use crate::error::IoError;
use crate::json::Obj;

/// The largest image side accepted (a guard against a typo allocating gigabytes).
pub const MAX_SIDE: u32 = 16_384;

/// One camera of the list.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedCamera {
    pub name: String,
    pub camera: Camera,
}

/// Marker the non-JSON number words are rewritten to before parsing (as parsed, and as written in
/// the JSON text).
const NON_FINITE: &str = "\u{0}non-finite:";
const NON_FINITE_JSON: &str = "\\u0000non-finite:";

/// Rewrites bare `NaN`, `Infinity` and `-Infinity` (outside strings) into marked strings.
fn quote_non_finite(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut in_string = false;
    let mut escaped = false;
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            out.push(c);
            match (escaped, c) {
                (true, _) => escaped = false,
                (false, '\\') => escaped = true,
                (false, '"') => in_string = false,
                _ => {}
            }
            rest = &rest[c.len_utf8()..];
            continue;
        }
        if let Some(word) = ["-Infinity", "Infinity", "NaN"]
            .into_iter()
            .find(|w| rest.starts_with(w))
        {
            out.push('"');
            out.push_str(NON_FINITE_JSON);
            out.push_str(word);
            out.push('"');
            rest = &rest[word.len()..];
            continue;
        }
        if c == '"' {
            in_string = true;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

/// A matrix of `rows × cols` numbers, given as rows or as one flat row-major list.
fn matrix(o: &Obj, key: &str, rows: usize, cols: usize) -> Result<Vec<Vec<f64>>, IoError> {
    let shape = format!("a {rows}x{cols} array (rows) or {} numbers", rows * cols);
    let a = o
        .req(key)?
        .as_array()
        .ok_or_else(|| o.err(key, format!("expected {shape}")))?;
    let flat: Vec<(String, &Value)> = if a.len() == rows * cols && !a[0].is_array() {
        a.iter()
            .enumerate()
            .map(|(i, v)| (format!("{key}[{i}]"), v))
            .collect()
    } else if a.len() == rows {
        let mut f = Vec::new();
        for (r, row) in a.iter().enumerate() {
            let row = row
                .as_array()
                .filter(|row| row.len() == cols)
                .ok_or_else(|| o.err(&format!("{key}[{r}]"), format!("expected {cols} numbers")))?;
            f.extend(
                row.iter()
                    .enumerate()
                    .map(|(c, v)| (format!("{key}[{r}][{c}]"), v)),
            );
        }
        f
    } else {
        return Err(o.err(key, format!("expected {shape}, found {} entries", a.len())));
    };
    let mut m = vec![vec![0.0; cols]; rows];
    for (i, (field, v)) in flat.into_iter().enumerate() {
        m[i / cols][i % cols] = number(o, &field, v)?;
    }
    Ok(m)
}

fn number(o: &Obj, field: &str, v: &Value) -> Result<f64, IoError> {
    if let Some(word) = v.as_str().and_then(|s| s.strip_prefix(NON_FINITE)) {
        return Err(o.err(field, format!("is {word}; every value must be finite")));
    }
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| o.err(field, format!("expected a number, found {v}")))
}

fn side(o: &Obj, key: &str) -> Result<u32, IoError> {
    let v = o.req(key)?;
    if let Some(word) = v.as_str().and_then(|s| s.strip_prefix(NON_FINITE)) {
        return Err(o.err(key, format!("is {word}; expected a positive integer")));
    }
    let n = v
        .as_u64()
        .ok_or_else(|| o.err(key, format!("expected a positive integer, found {v}")))?;
    if n == 0 || n > MAX_SIDE as u64 {
        return Err(o.err(key, format!("{n} is not in 1..={MAX_SIDE} pixels")));
    }
    Ok(n as u32)
}

fn name(o: &Obj, seen: &mut HashSet<String>) -> Result<String, IoError> {
    let n = o.str("name")?;
    let safe = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.');
    if n.is_empty() || n.starts_with('.') || !n.chars().all(safe) {
        return Err(o.err(
            "name",
            format!("`{n}` must be a file name of letters, digits, `_`, `-` or `.`"),
        ));
    }
    if !seen.insert(n.to_string()) {
        return Err(o.err("name", format!("`{n}` is used twice")));
    }
    Ok(n.to_string())
}

/// The camera of one entry: `K`, `world_to_camera`, `width` and `height`, checked by
/// [`camera_from_matrices`] (the error names the entry's field).
fn camera(o: &Obj) -> Result<Camera, IoError> {
    let k = matrix(o, "K", 3, 3)?;
    let m = matrix(o, "world_to_camera", 4, 4)?;
    let (width, height) = (side(o, "width")?, side(o, "height")?);
    let k: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| k[i][j]));
    let m: [[f64; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| m[i][j]));
    camera_from_matrices(&k, &m, width, height).map_err(|e| o.err(&e.field, e.reason))
}

/// Reads and checks a camera list.
pub fn read_cameras_json(path: &Path) -> Result<Vec<NamedCamera>, IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    let value: Value =
        serde_json::from_str(&quote_non_finite(&text)).map_err(|source| IoError::Json {
            path: path.into(),
            source,
        })?;
    let list = value
        .as_array()
        .ok_or_else(|| IoError::field(path, "(top level)", "expected an array of cameras"))?;
    if list.is_empty() {
        return Err(IoError::field(
            path,
            "(top level)",
            "the camera list is empty",
        ));
    }
    let mut seen = HashSet::new();
    list.iter()
        .enumerate()
        .map(|(i, v)| {
            let o = Obj::element(path, format!("[{i}]"), v)?;
            let name = name(&o, &mut seen)?;
            let camera = camera(&o)?;
            Ok(NamedCamera { name, camera })
        })
        .collect()
}

/// The JSON text of a camera list that [`read_cameras_json`] reads back to the same bits.
pub fn cameras_to_json(cams: &[NamedCamera]) -> String {
    let list: Vec<Value> = cams
        .iter()
        .map(|c| {
            let k = &c.camera.intrinsics;
            let r = &c.camera.r_w2c;
            let t = &c.camera.t_w2c;
            serde_json::json!({
                "name": c.name,
                "K": [[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]],
                "world_to_camera": [
                    [r[0][0], r[0][1], r[0][2], t[0]],
                    [r[1][0], r[1][1], r[1][2], t[1]],
                    [r[2][0], r[2][1], r[2][2], t[2]],
                    [0.0, 0.0, 0.0, 1.0],
                ],
                "width": k.width,
                "height": k.height,
            })
        })
        .collect();
    serde_json::to_string_pretty(&list).expect("JSON values serialise")
}

#[cfg(test)]
mod tests {
    use super::*;
    use trand_core::Intrinsics;

    fn write(text: &str) -> (crate::ScratchDir, std::path::PathBuf) {
        let dir = crate::ScratchDir::new("cameras").unwrap();
        let p = dir.path().join("cams.json");
        std::fs::write(&p, text).unwrap();
        (dir, p)
    }

    const GOOD: &str = r#"[{"name": "a", "K": [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]],
        "world_to_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1]],
        "width": 640, "height": 480}]"#;

    fn error_of(text: &str) -> String {
        let (_d, p) = write(text);
        read_cameras_json(&p).unwrap_err().to_string()
    }

    #[test]
    fn a_camera_list_round_trips_bit_for_bit() {
        let (_d, p) = write(GOOD);
        let cams = read_cameras_json(&p).unwrap();
        assert_eq!(cams[0].camera.intrinsics.cx, 319.5);
        assert_eq!(cams[0].camera.t_w2c, [0.0, 0.0, 0.5]);
        let mut odd = cams[0].clone();
        odd.camera = Camera::look_at(
            Intrinsics::centered(612.345_678_9, 33, 17),
            glam::DVec3::new(0.3, -0.71, 0.456),
            glam::DVec3::new(0.01, 0.02, 0.03),
            glam::DVec3::Z,
        );
        let (_d2, p2) = write(&cameras_to_json(std::slice::from_ref(&odd)));
        assert_eq!(read_cameras_json(&p2).unwrap(), vec![odd]);
    }

    #[test]
    fn flat_row_major_lists_read_as_rows() {
        let flat = GOOD.replace(
            "[[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]]",
            "[500, 0, 319.5, 0, 500, 239.5, 0, 0, 1]",
        );
        let (_d, p) = write(&flat);
        assert_eq!(
            read_cameras_json(&p).unwrap()[0].camera.intrinsics.fx,
            500.0
        );
    }

    #[test]
    fn bad_values_are_named_by_file_and_field() {
        let e = error_of(&GOOD.replace("[0, 0, 1, 0.5]", "[0, 0, 1, NaN]"));
        assert!(
            e.contains("cams.json") && e.contains("[0].world_to_camera[2][3]") && e.contains("NaN"),
            "{e}"
        );
        let e = error_of(&GOOD.replace("\"width\": 640", "\"width\": 0"));
        assert!(e.contains("[0].width") && e.contains("not in 1..="), "{e}");
        let e = error_of(&GOOD.replace("[0, 1, 0, 0]", "[0, 2, 0, 0]"));
        assert!(
            e.contains("[0].world_to_camera") && e.contains("orthonormal"),
            "{e}"
        );
        let e = error_of(&GOOD.replace("[0, 0, 1, 0.5]", "[0, 0, -1, 0.5]"));
        assert!(e.contains("reflection"), "{e}");
        let e = error_of(&GOOD.replace("[0, 0, 0, 1]]", "[0, 0, 1, 1]]"));
        assert!(e.contains("world_to_camera[3]"), "{e}");
        let e = error_of(&GOOD.replace("[0, 500, 239.5]", "[0, 500]"));
        assert!(e.contains("[0].K[1]"), "{e}");
        let e = error_of(&GOOD.replace("\"a\"", "\"../x\""));
        assert!(e.contains("[0].name"), "{e}");
        let e = error_of(&GOOD.replace("-Infinity", "").replace("319.5", "-Infinity"));
        assert!(e.contains("[0].K[0][2]") && e.contains("-Infinity"), "{e}");
        let e = error_of(&format!("[{0}, {0}]", &GOOD[1..GOOD.len() - 1]));
        assert!(e.contains("[1].name") && e.contains("twice"), "{e}");
        assert!(error_of("[]").contains("empty"));
        assert!(error_of("{}").contains("expected an array"));
    }

    #[test]
    fn non_finite_words_inside_strings_are_left_alone() {
        assert_eq!(
            quote_non_finite(r#"{"NaN": "x\"NaN"}"#),
            r#"{"NaN": "x\"NaN"}"#
        );
        assert!(quote_non_finite("[NaN]").contains(NON_FINITE_JSON));
    }
}
