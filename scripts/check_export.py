"""Reads back every PLY of a `trand export` folder with plyfile (the reader MeshLab-style tools share
the format with) and checks what Open3D and MeshLab rely on: binary little-endian, the expected
properties, face indices inside the vertex list, finite values; prints counts and the mean distance of
each object's mesh vertices to the nearest of its exported points.

    python scripts/check_export.py OUT_DIR   (needs: pip install plyfile numpy)
"""
import json
import sys
from pathlib import Path

import numpy as np
from plyfile import PlyData


def read(path):
    ply = PlyData.read(str(path))
    assert ply.text is False and ply.byte_order == "<", f"{path}: not binary little-endian"
    return ply


def check_points(path, with_ids):
    v = read(path)["vertex"].data
    names = set(v.dtype.names)
    need = {"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"} | ({"object_id"} if with_ids else set())
    assert need <= names, f"{path}: missing {need - names}"
    xyz = np.stack([v["x"], v["y"], v["z"]], 1)
    n = np.stack([v["nx"], v["ny"], v["nz"]], 1)
    assert np.isfinite(xyz).all() and np.isfinite(n).all(), path
    assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-4), f"{path}: normals not unit"
    return xyz, (v["object_id"] if with_ids else None)


def check_mesh(path):
    ply = read(path)
    v = ply["vertex"].data
    f = ply["face"].data["vertex_indices"]
    xyz = np.stack([v["x"], v["y"], v["z"]], 1)
    faces = np.stack(f) if len(f) else np.zeros((0, 3), int)
    assert faces.shape[1] == 3, path
    assert len(faces) == 0 or (faces.min() >= 0 and faces.max() < len(xyz)), f"{path}: bad face index"
    return xyz, faces


def nearest_mean(a, b, chunk=2048):
    """Mean over a of the distance to the nearest point of b (brute force, chunked)."""
    out = []
    for i in range(0, len(a), chunk):
        d = ((a[i:i + chunk, None, :] - b[None, :, :]) ** 2).sum(-1)
        out.append(np.sqrt(d.min(1)))
    return float(np.concatenate(out).mean()) if out else float("nan")


def main(out):
    out = Path(out)
    summary = json.loads((out / "export.json").read_text())
    pts, ids = check_points(out / "scene_points.ply", True)
    assert len(pts) == summary["scene_points"]
    mv, mf = check_mesh(out / "mesh.ply")
    assert (len(mv), len(mf)) == (summary["mesh_vertices"], summary["mesh_faces"])
    print(f"scene: {len(pts)} points, mesh {len(mv)} vertices / {len(mf)} faces")
    for o in summary["objects"]:
        p, _ = check_points(out / f"object_{o['id']}.ply", False)
        assert len(p) == o["points"] == int((ids == o["id"]).sum())
        v, f = check_mesh(out / f"object_{o['id']}_mesh.ply")
        assert (len(v), len(f)) == (o["mesh_vertices"], o["mesh_faces"])
        d = nearest_mean(v, p) if len(v) and len(p) else float("nan")
        print(f"object {o['id']}: {len(p)} points, mesh {len(v)} vertices / {len(f)} faces, "
              f"mean vertex-to-point distance {1000 * d:.2f} mm")
    splats = out / "splats.ply"
    if splats.exists():
        v = read(splats)["vertex"].data
        need = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + \
            [f"f_rest_{i}" for i in range(45)] + ["opacity", "scale_0", "scale_1", "scale_2"] + \
            [f"rot_{i}" for i in range(4)]
        assert list(v.dtype.names) == need, f"{splats}: properties {v.dtype.names}"
        assert len(v) == summary["splats"]
        thin = v["scale_2"] - 0.5 * (v["scale_0"] + v["scale_1"])
        print(f"splats: {len(v)}, third scale / geometric mean = {np.exp(thin).mean():.4g}")
    print("ok")


if __name__ == "__main__":
    main(sys.argv[1])
