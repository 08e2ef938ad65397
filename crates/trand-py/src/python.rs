//! The native module `trand._trand`: thin wrappers of [`crate::scene`] taking and giving flat buffers.
//!
//! The Python layer (`python/trand/__init__.py`) checks shapes and dtypes, names the argument at fault,
//! and turns numpy arrays into the little-endian bytes these functions take (and the bytes they give
//! back into arrays), so nothing here depends on numpy's C API. Every computation runs through
//! [`crate::interrupt::run`]: without the GIL, and stopped by Ctrl-C.

use std::io::Write;
use std::path::PathBuf;

use pyo3::exceptions::{
    PyFileExistsError, PyFileNotFoundError, PyKeyboardInterrupt, PyOSError, PyValueError,
};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};
use trand_core::Camera;
use trand_io::{IoError, View};
use trand_pipeline::associate::Identity;
use trand_pipeline::{Method, PipelineError, ReconstructOptions};

use crate::interrupt;
use crate::scene::{Scene, SceneError};

fn py_err(e: SceneError) -> PyErr {
    match e {
        SceneError::Pipeline(PipelineError::Interrupted(_)) => {
            PyKeyboardInterrupt::new_err("interrupted")
        }
        SceneError::Argument { .. } => PyValueError::new_err(e.to_string()),
        SceneError::Io(IoError::Missing { .. })
        | SceneError::Pipeline(PipelineError::Io(IoError::Missing { .. })) => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        SceneError::Io(IoError::Output { .. })
        | SceneError::Pipeline(PipelineError::Io(IoError::Output { .. })) => {
            PyFileExistsError::new_err(e.to_string())
        }
        SceneError::Io(IoError::Io { .. })
        | SceneError::Pipeline(PipelineError::Io(IoError::Io { .. })) => {
            PyOSError::new_err(e.to_string())
        }
        _ => PyValueError::new_err(e.to_string()),
    }
}

fn arg_err(arg: &str, e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("{arg}: {e}"))
}

/// A camera from the flat row-major `K` (9 numbers) and `world_to_camera` (16 numbers); errors
/// name `{arg}` and the entry.
fn camera(k: [f64; 9], w2c: [f64; 16], width: u32, height: u32, at: &str) -> PyResult<Camera> {
    let k = [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]];
    let w = [0, 1, 2, 3].map(|r| [w2c[4 * r], w2c[4 * r + 1], w2c[4 * r + 2], w2c[4 * r + 3]]);
    trand_io::camera_from_matrices(&k, &w, width, height).map_err(|e| {
        let arg = if e.field.starts_with('K') {
            format!("intrinsics{at}{}", &e.field[1..])
        } else if let Some(rest) = e.field.strip_prefix("world_to_camera") {
            format!("world_to_camera{at}{rest}")
        } else {
            format!("{}{at}", e.field)
        };
        arg_err(&arg, e.reason)
    })
}

/// One view as the Python layer passes it: RGB bytes (H·W·3), mask bytes (H·W little-endian u16),
/// width, height, flat K, flat world-to-camera.
type ViewArgs<'py> = (
    Bound<'py, PyBytes>,
    Bound<'py, PyBytes>,
    u32,
    u32,
    [f64; 9],
    [f64; 16],
);

fn view(v: &ViewArgs<'_>, index: Option<usize>) -> PyResult<View> {
    let at = index.map_or(String::new(), |i| format!("[{i}]"));
    let (rgb, mask, w, h, k, w2c) = v;
    let cam = camera(*k, *w2c, *w, *h, &at)?;
    let ids: Vec<u16> = mask
        .as_bytes()
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    let name = format!("view{at}");
    trand_io::view_from_arrays(
        name,
        index.unwrap_or(0) as u32,
        cam,
        rgb.as_bytes().to_vec(),
        ids,
    )
    .map_err(|e| {
        let arg = if e.field == "image" {
            "images"
        } else {
            "masks"
        };
        arg_err(&format!("{arg}{at}"), e.reason)
    })
}

fn parse_identity(s: &str) -> PyResult<Identity> {
    match s {
        "auto" => Ok(Identity::Auto),
        "ids" => Ok(Identity::ObjectIds),
        "overlap" => Ok(Identity::Overlap),
        _ => Err(arg_err(
            "identity",
            format!("`{s}`: expected \"auto\", \"ids\" or \"overlap\""),
        )),
    }
}

fn parse_method(s: &str) -> PyResult<Method> {
    match s {
        "trand" => Ok(Method::Trand),
        "no-object-loss" => Ok(Method::NoObjectLoss),
        "plain-2dgs" => Ok(Method::Plain2dgs),
        _ => Err(arg_err(
            "method",
            format!("`{s}`: expected \"trand\", \"no-object-loss\" or \"plain-2dgs\""),
        )),
    }
}

/// A progress line on stderr, rewritten in place.
fn report_progress(line: &str) {
    let mut err = std::io::stderr().lock();
    let _ = write!(err, "\r{line:<70}");
    let _ = err.flush();
}

fn end_progress() {
    eprintln!();
}

/// Little-endian bytes of `values`.
fn le_bytes<'py, T: Copy, const N: usize>(
    py: Python<'py>,
    values: &[T],
    to: fn(T) -> [u8; N],
) -> Bound<'py, PyBytes> {
    let bytes: Vec<u8> = values.iter().flat_map(|&v| to(v)).collect();
    PyBytes::new(py, &bytes)
}

/// A reconstructed scene (wrapped by `trand.Scene`).
#[pyclass(name = "NativeScene", module = "trand._trand", frozen)]
pub struct PyScene {
    inner: Scene,
}

#[pymethods]
impl PyScene {
    /// Depth, object ids, alpha and normals at one camera, as little-endian bytes.
    #[pyo3(signature = (k, w2c, width, height, far=None))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        k: [f64; 9],
        w2c: [f64; 16],
        width: u32,
        height: u32,
        far: Option<f32>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let cam = camera(k, w2c, width, height, "")?;
        if far.is_some_and(|f| f.is_nan() || f <= 0.0) {
            return Err(arg_err("far", "must be a positive number of metres"));
        }
        let maps = interrupt::run(py, |_| self.inner.render(&cam, far))?.map_err(py_err)?;
        let d = PyDict::new(py);
        d.set_item("depth", le_bytes(py, &maps.depth.data, f32::to_le_bytes))?;
        d.set_item("objects", le_bytes(py, &maps.ids.data, u16::to_le_bytes))?;
        d.set_item("alpha", le_bytes(py, &maps.alpha.data, f32::to_le_bytes))?;
        d.set_item("normal", le_bytes(py, &maps.normal.data, f32::to_le_bytes))?;
        Ok(d)
    }

    /// The t = 1 update from one view; a new scene.
    #[pyo3(signature = (view, removed, identity, progress))]
    fn update(
        &self,
        py: Python<'_>,
        view: ViewArgs<'_>,
        removed: Option<Vec<u16>>,
        identity: &str,
        progress: bool,
    ) -> PyResult<PyScene> {
        let identity = parse_identity(identity)?;
        let v = self::view(&view, None)?;
        let out = interrupt::run(py, |cancel| {
            let mut show = |stage: &str, i: u32, n: u32| {
                if progress {
                    report_progress(&format!("trand update: {stage} {i}/{n}"));
                }
            };
            let r = self.inner.update(&v, removed, identity, &mut show, cancel);
            if progress {
                end_progress();
            }
            r
        })?;
        Ok(PyScene {
            inner: out.map_err(py_err)?,
        })
    }

    /// Writes a run folder.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        interrupt::run(py, |_| self.inner.save(&path))?.map_err(py_err)
    }

    /// The object ids present.
    #[getter]
    fn object_ids(&self) -> Vec<u16> {
        self.inner.object_ids()
    }

    /// `"t0"` or `"t1"`.
    #[getter]
    fn state(&self) -> &'static str {
        self.inner.state.as_str()
    }

    /// Objects taken away by the update.
    #[getter]
    fn removed(&self) -> Vec<u16> {
        self.inner.removed.clone()
    }

    /// The far clamp of rendered depth in metres (infinity: none).
    #[getter]
    fn far(&self) -> f32 {
        self.inner.clamp
    }

    /// The run report (`run.json`) as JSON text.
    #[getter]
    fn report(&self) -> String {
        self.inner.report.to_string()
    }

    fn __len__(&self) -> usize {
        self.inner.surfels.len()
    }

    /// Surfel centres (N·3 little-endian f32), all or of one object.
    #[pyo3(signature = (object_id=None))]
    fn points<'py>(
        &self,
        py: Python<'py>,
        object_id: Option<u16>,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let p = self.inner.points(object_id).map_err(py_err)?;
        let flat: Vec<f32> = p.into_iter().flatten().collect();
        Ok(le_bytes(py, &flat, f32::to_le_bytes))
    }
}

/// The t = 0 reconstruction from views given as
/// `(rgb bytes, mask bytes, width, height, K[9], world_to_camera[16])`.
#[pyfunction]
#[pyo3(signature = (views, iterations, downsample, seed, method, identity, progress))]
#[allow(clippy::too_many_arguments)]
fn reconstruct(
    py: Python<'_>,
    views: Vec<ViewArgs<'_>>,
    iterations: Option<u32>,
    downsample: u32,
    seed: u64,
    method: &str,
    identity: &str,
    progress: bool,
) -> PyResult<PyScene> {
    let mut opts = ReconstructOptions {
        method: parse_method(method)?,
        identity: parse_identity(identity)?,
        downsample,
        ..Default::default()
    };
    if let Some(n) = iterations {
        opts.train.iterations = n;
    }
    let iterations = opts.train.iterations;
    opts.train.seed = seed;
    opts.init.seed = seed;
    if iterations == 0 {
        return Err(arg_err("iterations", "must be at least 1"));
    }
    if downsample == 0 || downsample > trand_pipeline::reconstruct::MAX_DOWNSAMPLE {
        return Err(arg_err(
            "downsample",
            format!(
                "{downsample}: must be 1 to {}",
                trand_pipeline::reconstruct::MAX_DOWNSAMPLE
            ),
        ));
    }
    let views = views
        .iter()
        .enumerate()
        .map(|(i, v)| view(v, Some(i)))
        .collect::<PyResult<Vec<_>>>()?;
    let out = interrupt::run(py, |cancel| {
        let mut on_step = |r: &trand_pipeline::StepReport| {
            if progress && (r.iteration.is_multiple_of(10) || r.iteration == iterations) {
                report_progress(&format!(
                    "trand: iteration {}/{iterations}  loss {:.4}  surfels {}",
                    r.iteration, r.loss, r.num_surfels
                ));
            }
        };
        let r = Scene::reconstruct(views, &opts, &mut on_step, cancel);
        if progress {
            end_progress();
        }
        r
    })?;
    Ok(PyScene {
        inner: out.map_err(py_err)?,
    })
}

/// Reads a run folder.
#[pyfunction]
fn load(py: Python<'_>, path: PathBuf) -> PyResult<PyScene> {
    let s = interrupt::run(py, |_| Scene::load(&path))?.map_err(py_err)?;
    Ok(PyScene { inner: s })
}

fn view_dict<'py>(py: Python<'py>, v: &View) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let k = &v.camera.intrinsics;
    let (r, t) = (&v.camera.r_w2c, &v.camera.t_w2c);
    d.set_item("name", &v.name)?;
    d.set_item("frame", v.frame)?;
    d.set_item("width", k.width)?;
    d.set_item("height", k.height)?;
    d.set_item("K", [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0])?;
    let w2c = [
        r[0][0], r[0][1], r[0][2], t[0], r[1][0], r[1][1], r[1][2], t[1], r[2][0], r[2][1],
        r[2][2], t[2], 0.0, 0.0, 0.0, 1.0,
    ];
    d.set_item("world_to_camera", w2c)?;
    d.set_item("rgb", v.rgb.as_ref().map(|i| PyBytes::new(py, &i.data)))?;
    d.set_item(
        "mask",
        v.instance
            .as_ref()
            .map(|i| le_bytes(py, &i.data, u16::to_le_bytes)),
    )?;
    d.set_item(
        "depth",
        v.depth
            .as_ref()
            .map(|i| le_bytes(py, &i.data, f32::to_le_bytes)),
    )?;
    Ok(d)
}

/// Every view of a sequence folder (BOP, authors' transforms, nerfstudio or KeyPose), by split, and
/// the frames `trand reconstruct --views N` trains on.
#[pyfunction]
#[pyo3(signature = (path, views))]
fn load_sequence<'py>(
    py: Python<'py>,
    path: PathBuf,
    views: Option<u32>,
) -> PyResult<Bound<'py, PyDict>> {
    let count = match views {
        None => None,
        Some(n) => Some(
            trand_io::ViewCount::from_count(n as usize)
                .ok_or_else(|| arg_err("views", format!("{n}: must be 3, 6, 12 or None")))?,
        ),
    };
    let seq = interrupt::run(py, |_| trand_io::read_sequence(&path))?
        .map_err(|e| py_err(SceneError::Io(e)))?;
    let d = PyDict::new(py);
    for (key, state) in [("0", trand_io::State::T0), ("1", trand_io::State::T1)] {
        for split in [trand_io::Split::Train, trand_io::Split::Test] {
            let list = PyList::empty(py);
            for v in seq.views(split, state) {
                list.append(view_dict(py, v)?)?;
            }
            let name = match split {
                trand_io::Split::Train => format!("train_{key}"),
                trand_io::Split::Test => format!("test_{key}"),
            };
            d.set_item(name, list)?;
        }
    }
    let training: Vec<u32> = match (seq.train_selection, count) {
        (trand_io::TrainSelection::Ring, Some(n)) => trand_io::select_train_views(&seq.train_t0, n)
            .iter()
            .map(|v| v.frame)
            .collect(),
        _ => seq.train_t0.iter().map(|v| v.frame).collect(),
    };
    d.set_item("training_frames", training)?;
    d.set_item("object_ids", seq.object_ids.clone())?;
    d.set_item("removed", seq.removed_ids.clone())?;
    Ok(d)
}

/// Generates a synthetic sequence (BOP layout) with exact ground truth, as `trand synth` does.
#[pyfunction]
#[pyo3(signature = (out, preset, seed))]
fn synth(py: Python<'_>, out: PathBuf, preset: &str, seed: u64) -> PyResult<()> {
    use trand_synth::Preset;
    let p = match preset {
        "default" => Preset::Default,
        "tiny" => Preset::Tiny,
        "containers" => Preset::Containers,
        "containers-tiny" => Preset::ContainersTiny,
        _ => {
            return Err(arg_err(
                "preset",
                format!("`{preset}`: expected default, tiny, containers or containers-tiny"),
            ));
        }
    };
    let mut c = trand_synth::SynthConfig::new(p, seed, out);
    c.progress = trand_synth::Progress::Hidden;
    interrupt::run(py, |_| trand_synth::generate(&c))?
        .map(|_| ())
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

#[pymodule]
#[pyo3(name = "_trand")]
fn native_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyScene>()?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(load, m)?)?;
    m.add_function(wrap_pyfunction!(load_sequence, m)?)?;
    m.add_function(wrap_pyfunction!(synth, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
