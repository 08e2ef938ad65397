"""trand: metric depth of transparent objects from a few posed views (TRAN-D), from numpy.

Conventions, as everywhere in trand: metres; OpenCV camera axes (x right, y down, z forward);
``world_to_camera`` maps world points into the camera frame; ``intrinsics`` is the 3x3 ``K`` with
integer pixel centres (what OpenCV's calibration gives); the world is z up with the table at z = 0.

>>> seq = trand.load_sequence("seq")                      # or your own arrays
>>> t0 = seq["train_0"]
>>> scene = trand.reconstruct(t0["images"], t0["masks"], t0["intrinsics"], t0["world_to_camera"])
>>> depth = scene.render_depth(K, world_to_camera, 640, 480)   # HxW float32 metres, 0 = nothing
>>> t1 = scene.update(image, mask, K, world_to_camera)         # after an object was taken away

Every computation runs without the GIL, and Ctrl-C stops it (``KeyboardInterrupt``). Bad arguments
raise ``ValueError`` or ``TypeError`` naming the argument.
"""

from __future__ import annotations

import os
from typing import Any, Dict, List, Optional, Sequence, Union

import numpy as np

from . import _trand

__all__ = ["Scene", "reconstruct", "load", "load_sequence", "synth", "__version__"]
__version__: str = _trand.__version__

PathLike = Union[str, "os.PathLike[str]"]
ArrayList = Union[np.ndarray, Sequence[np.ndarray]]

_IDENTITIES = ("auto", "ids", "overlap")
_METHODS = ("trand", "no-object-loss", "plain-2dgs")


def _as_list(name: str, value: Any, ndim: int) -> List[np.ndarray]:
    """Per-view arrays from a list of arrays or one stacked array (one more dimension)."""
    if isinstance(value, np.ndarray):
        if value.ndim == ndim + 1:
            return list(value)
        raise ValueError(
            f"{name}: expected a list of arrays or one array of {ndim + 1} dimensions, "
            f"got shape {value.shape}"
        )
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"{name}: expected a list of numpy arrays, got {type(value).__name__}")
    return [np.asarray(v) for v in value]


def _image(name: str, a: Any) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{name}: expected an HxWx3 image, got shape {a.shape}")
    if a.dtype != np.uint8:
        raise TypeError(f"{name}: expected dtype uint8, got {a.dtype}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{name}: the image is empty ({a.shape[1]}x{a.shape[0]})")
    return np.ascontiguousarray(a)


def _mask(name: str, a: Any, shape: tuple) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2:
        raise ValueError(f"{name}: expected an HxW mask of instance ids, got shape {a.shape}")
    if a.shape != shape:
        raise ValueError(
            f"{name}: shape {a.shape} differs from its image's {shape} (H, W)"
        )
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer):
        raise TypeError(
            f"{name}: expected integer instance ids (0 = background), got dtype {a.dtype}"
        )
    if a.size and (int(a.min()) < 0 or int(a.max()) > 65535):
        raise ValueError(
            f"{name}: instance ids must lie in 0..65535, found {int(a.min())}..{int(a.max())}"
        )
    return np.ascontiguousarray(a, dtype="<u2")


def _matrix(name: str, a: Any, n: int) -> List[float]:
    try:
        m = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name}: expected a {n}x{n} array of numbers ({e})") from None
    if m.shape != (n, n):
        raise ValueError(f"{name}: expected shape ({n}, {n}), got {m.shape}")
    bad = np.argwhere(~np.isfinite(m))
    if len(bad):
        i, j = bad[0]
        raise ValueError(f"{name}[{i}][{j}]: is {m[i, j]}; every value must be finite")
    return [float(x) for x in m.ravel()]


def _view(index: Optional[int], image: Any, mask: Any, intrinsics: Any, w2c: Any) -> tuple:
    at = "" if index is None else f"[{index}]"
    img = _image(f"image{'s' if index is not None else ''}{at}", image)
    msk = _mask(f"mask{'s' if index is not None else ''}{at}", mask, img.shape[:2])
    k = _matrix(f"intrinsics{at}", intrinsics, 3)
    w = _matrix(f"world_to_camera{at}", w2c, 4)
    h, wd = img.shape[:2]
    return (img.tobytes(), msk.tobytes(), int(wd), int(h), k, w)


def _choice(name: str, value: Any, choices: tuple) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{name}: expected a string, one of {choices}, got {type(value).__name__}")
    if value not in choices:
        raise ValueError(f"{name}: {value!r} is not one of {choices}")
    return value


def _int(name: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name}: {value} is not in {lo}..{hi}")
    return int(value)


def _size(name: str, value: Any) -> int:
    return _int(name, value, 1, 8192)


class Scene:
    """A reconstructed scene: object-aware 2D Gaussian surfels with their object ids.

    Made by :func:`reconstruct` (t = 0), :meth:`update` (t = 1) or :func:`load` (a run folder).
    A scene is never changed in place.
    """

    __slots__ = ("_native",)

    def __init__(self, native: "_trand.NativeScene") -> None:
        if not isinstance(native, _trand.NativeScene):
            raise TypeError("Scene objects come from trand.reconstruct, trand.load or Scene.update")
        self._native = native

    def __repr__(self) -> str:
        return f"<trand.Scene {self.state}: {len(self)} surfels, objects {self.object_ids}>"

    def __len__(self) -> int:
        """Number of surfels."""
        return len(self._native)

    @property
    def object_ids(self) -> List[int]:
        """Ids of the objects in the scene (the t = 0 objects less those removed)."""
        return list(self._native.object_ids)

    @property
    def state(self) -> str:
        """``"t0"`` (reconstructed) or ``"t1"`` (updated after a removal)."""
        return self._native.state

    @property
    def removed(self) -> List[int]:
        """Object ids the update found removed (or was told were)."""
        return list(self._native.removed)

    @property
    def report(self) -> Dict[str, Any]:
        """The run report (what ``run.json`` holds): timings, loss curve, identity, matching, ..."""
        import json

        return json.loads(self._native.report)

    def points(self, object_id: Optional[int] = None) -> np.ndarray:
        """Surfel centres as an Nx3 float32 array (metres, world frame): all of them, or those of
        ``object_id`` (surfels whose probability of that object is above one half)."""
        if object_id is not None:
            object_id = _int("object_id", object_id, 0, 65535)
        b = self._native.points(object_id)
        return np.frombuffer(b, dtype="<f4").reshape(-1, 3).copy()

    @property
    def far(self) -> float:
        """Depth beyond this many metres is clamped to it (``inf``: no clamp). A scene from
        :func:`reconstruct` clamps at twice the distance from the nearest training camera to the
        point the cameras look at; a loaded run at the clamp it recorded (``trand reconstruct``
        applies that rule to its test cameras)."""
        return float(self._native.far)

    def render(
        self,
        intrinsics: Any,
        world_to_camera: Any,
        width: int,
        height: int,
        *,
        far: Optional[float] = None,
    ) -> Dict[str, np.ndarray]:
        """Renders the scene at one camera.

        Returns a dict: ``depth`` (HxW float32, metres along the camera z axis, 0 where nothing),
        ``objects`` (HxW uint16 object id, 0 = background), ``alpha`` (HxW float32 accumulated
        opacity) and ``normal`` (HxWx3 float32 unit normals in the camera frame, 0 where nothing).
        ``far`` overrides :attr:`far`. With the run's ``far``, the depth is the one
        ``trand reconstruct`` / ``trand update`` write: a test camera gives the same bits.
        """
        w = _size("width", width)
        h = _size("height", height)
        k = _matrix("intrinsics", intrinsics, 3)
        m = _matrix("world_to_camera", world_to_camera, 4)
        if far is not None:
            if isinstance(far, bool) or not isinstance(far, (int, float, np.floating, np.integer)):
                raise TypeError(f"far: expected a number of metres, got {type(far).__name__}")
            if not far > 0:
                raise ValueError(f"far: {far} must be a positive number of metres")
            far = float(far)
        d = self._native.render(k, m, w, h, far)
        return {
            "depth": np.frombuffer(d["depth"], dtype="<f4").reshape(h, w).copy(),
            "objects": np.frombuffer(d["objects"], dtype="<u2").reshape(h, w).copy(),
            "alpha": np.frombuffer(d["alpha"], dtype="<f4").reshape(h, w).copy(),
            "normal": np.frombuffer(d["normal"], dtype="<f4").reshape(h, w, 3).copy(),
        }

    def render_depth(
        self,
        intrinsics: Any,
        world_to_camera: Any,
        width: int,
        height: int,
        *,
        far: Optional[float] = None,
    ) -> np.ndarray:
        """Depth at one camera: HxW float32, metres, 0 where nothing is rendered (see :meth:`render`)."""
        return self.render(intrinsics, world_to_camera, width, height, far=far)["depth"]

    def update(
        self,
        image: Any,
        mask: Any,
        intrinsics: Any,
        world_to_camera: Any,
        *,
        removed: Optional[Sequence[int]] = None,
        identity: str = "auto",
        progress: bool = True,
    ) -> "Scene":
        """The t = 1 update after objects were taken away, from one new image.

        Finds the removed objects (t = 0 objects missing from ``mask``; ``removed`` overrides),
        deletes them, simulates the rest with MLS-MPM, relocalises moved objects and refines on the
        new image, as ``trand update`` does. ``identity``: ``"auto"`` (the mask's ids are t = 0
        object ids when they agree with the rendered scene), ``"ids"`` (they are) or ``"overlap"``
        (per-image ids, matched by overlap). Returns a new scene; this one is left unchanged.
        """
        v = _view(None, image, mask, intrinsics, world_to_camera)
        ident = _choice("identity", identity, _IDENTITIES)
        rem = None
        if removed is not None:
            if isinstance(removed, (str, bytes)) or not isinstance(removed, (Sequence, np.ndarray)):
                raise TypeError(f"removed: expected a list of object ids, got {type(removed).__name__}")
            rem = [_int(f"removed[{i}]", r, 1, 65535) for i, r in enumerate(removed)]
        return Scene(self._native.update(v, rem, ident, bool(progress)))

    def save(self, path: PathLike) -> None:
        """Writes a run folder at ``path`` (which must not exist): ``surfels.ply`` (readable by
        splat viewers), ``config.toml`` and ``run.json``. ``trand render --run PATH`` and, for a
        t = 0 scene, ``trand update --run PATH`` read it; :func:`load` reads it back."""
        self._native.save(os.fspath(path))


def reconstruct(
    images: ArrayList,
    masks: ArrayList,
    intrinsics: ArrayList,
    world_to_camera: ArrayList,
    *,
    iterations: Optional[int] = None,
    downsample: int = 1,
    seed: int = 0,
    method: str = "trand",
    identity: str = "auto",
    progress: bool = True,
) -> Scene:
    """The t = 0 reconstruction from a few posed views of the objects.

    ``images``: HxWx3 uint8; ``masks``: HxW integer instance ids (0 = background); ``intrinsics``:
    3x3; ``world_to_camera``: 4x4 (metres, OpenCV axes). Each a list with one entry per view, or
    one stacked array. Trains on every view given, in order (``trand reconstruct`` on the paper's
    rig picks 6 ring views: :func:`load_sequence` returns those). ``identity``: ``"auto"``,
    ``"ids"`` (the masks' ids name the same object in every view) or ``"overlap"`` (per-image ids,
    associated across views). ``method``: ``"trand"``, ``"no-object-loss"`` or ``"plain-2dgs"``.
    ``iterations``: ``None`` takes ``trand reconstruct``'s default.
    The same seed gives the same scene, bit for bit, as ``trand reconstruct --seed``.
    """
    ims = _as_list("images", images, 3)
    mks = _as_list("masks", masks, 2)
    ks = _as_list("intrinsics", intrinsics, 2)
    ws = _as_list("world_to_camera", world_to_camera, 2)
    n = len(ims)
    if n == 0:
        raise ValueError("images: no views given")
    for name, lst in (("masks", mks), ("intrinsics", ks), ("world_to_camera", ws)):
        if len(lst) != n:
            raise ValueError(f"{name}: {len(lst)} given for {n} images; one per view is needed")
    views = [_view(i, ims[i], mks[i], ks[i], ws[i]) for i in range(n)]
    native = _trand.reconstruct(
        views,
        None if iterations is None else _int("iterations", iterations, 1, 1_000_000),
        _int("downsample", downsample, 1, 64),
        _int("seed", seed, 0, 2**64 - 1),
        _choice("method", method, _METHODS),
        _choice("identity", identity, _IDENTITIES),
        bool(progress),
    )
    return Scene(native)


def load(path: PathLike) -> Scene:
    """Reads a run folder written by ``trand reconstruct``, ``trand update`` or :meth:`Scene.save`."""
    return Scene(_trand.load(os.fspath(path)))


def _split(views: List[Dict[str, Any]]) -> Dict[str, Any]:
    def arr(v: Dict[str, Any], key: str, dtype: str, channels: int) -> Optional[np.ndarray]:
        b = v[key]
        if b is None:
            return None
        shape = (v["height"], v["width"]) + ((channels,) if channels > 1 else ())
        return np.frombuffer(b, dtype=dtype).reshape(shape).copy()

    return {
        "images": [arr(v, "rgb", "u1", 3) for v in views],
        "masks": [arr(v, "mask", "<u2", 1) for v in views],
        "depth": [arr(v, "depth", "<f4", 1) for v in views],
        "intrinsics": np.array([v["K"] for v in views], dtype=np.float64).reshape(-1, 3, 3),
        "world_to_camera": np.array([v["world_to_camera"] for v in views], dtype=np.float64).reshape(-1, 4, 4),
        "frames": [v["frame"] for v in views],
        "names": [v["name"] for v in views],
    }


def load_sequence(path: PathLike, views: Optional[int] = 6) -> Dict[str, Any]:
    """The arrays of a sequence in any layout trand reads (BOP, the authors' transforms files,
    nerfstudio ``transforms.json``, a KeyPose capture), in trand's conventions.

    Returns a dict with ``train_0``, ``train_1``, ``test_0`` and ``test_1``, each a dict of
    ``images`` (HxWx3 uint8), ``masks`` (HxW uint16), ``depth`` (HxW float32 metres; ``None`` where
    the layout has none), ``intrinsics`` (Nx3x3), ``world_to_camera`` (Nx4x4), ``frames`` and
    ``names``; plus ``object_ids`` and ``removed`` (the ids removed at t = 1, if the layout says).
    ``train_0`` holds the views ``trand reconstruct --views N`` trains on (``views`` = 3, 6 or 12
    ring views on the paper's rig; ``None``: every ``train_0`` view); the t = 1 image of the update
    is ``train_1`` frame 0.
    """
    if views is not None:
        views = _int("views", views, 3, 12)
    d = _trand.load_sequence(os.fspath(path), views)
    keep = set(d["training_frames"])
    out: Dict[str, Any] = {}
    for key in ("train_0", "train_1", "test_0", "test_1"):
        vs = d[key]
        if key == "train_0":
            order = {f: i for i, f in enumerate(d["training_frames"])}
            vs = sorted((v for v in vs if v["frame"] in keep), key=lambda v: order[v["frame"]])
        out[key] = _split(vs)
    out["object_ids"] = list(d["object_ids"])
    out["removed"] = None if d["removed"] is None else list(d["removed"])
    return out


def synth(out: PathLike, *, preset: str = "tiny", seed: int = 0) -> None:
    """Generates a synthetic sequence with exact ground truth at ``out`` (BOP layout), as
    ``trand synth --preset PRESET --seed SEED`` does: ``"tiny"`` (160x120, for tests), ``"default"``,
    ``"containers"`` or ``"containers-tiny"``."""
    _trand.synth(
        os.fspath(out),
        _choice("preset", preset, ("default", "tiny", "containers", "containers-tiny")),
        _int("seed", seed, 0, 2**64 - 1),
    )
