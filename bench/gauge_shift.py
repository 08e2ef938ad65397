#!/usr/bin/env python3
"""Where each pose gauge would put the scene if training found the views' relative errors exactly.

    python3 bench/gauge_shift.py COPY SEQ [--frames 1,3,5,7,9,11] [--deg 0.5 --mm 3]

COPY is a `trand perturb --pose` copy of the exact sequence SEQ. The images fix the training
views' pose corrections only up to one common world motion (the gauge, `trand_train::pose`).
This script takes each view's exact correction (the world motion from its given camera to its exact
one), adds the common motion each gauge would choose, and prints the shift the corrected cameras
then share at the objects (the least-squares meeting point of their rays, as `shared_shift.py`
measures it on a finished run), in millimetres, x y z:
- `given`: the cameras as given (no correction);
- `mean`: the mean correction held at zero;
- `prior`: the common motion that makes the implied per-view errors likeliest under independent
  errors of `--deg` degrees of each camera's orientation and `--mm` millimetres of its centre (only
  their ratio matters): minimise sum rho^2 |w_i + g_w|^2 + |d_i + g_d + (w_i + g_w) x C_i|^2,
  rho = mm / deg (metres), C_i the given centres (a gauge tried and rejected, BENCHMARKS.md §10).
No training runs: this is the part of the cost that the gauge alone leaves, the lower bound of what a
run reaches with that gauge (trand holds the mean).
"""
import argparse

import numpy as np

from shared_shift import cameras, log_rotation, meeting_shift, object_centres


def cross_matrix(c):
    return np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])


def prior_gauge(xi, centres, rho):
    """The common motion g minimising the prior energy (module docs); about the centres' mean the
    rotation and translation blocks decouple."""
    c0 = centres.mean(axis=0)
    P = len(xi) * rho * rho * np.eye(3)
    b_w, b_d = np.zeros(3), np.zeros(3)
    for x, c in zip(xi, centres):
        w, d = x[:3], x[3:] + np.cross(x[:3], c0)
        c = c - c0
        r = d + np.cross(w, c)
        cx = cross_matrix(c)
        P -= cx @ cx
        b_w -= rho * rho * w + np.cross(c, r)
        b_d -= r
    g_w = np.linalg.solve(P, b_w)
    return np.concatenate([g_w, b_d / len(xi) - np.cross(g_w, c0)])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("copy")
    ap.add_argument("seq")
    ap.add_argument("--frames", default="1,3,5,7,9,11", help="the training frames (default: the paper's six)")
    ap.add_argument("--deg", type=float, default=0.5)
    ap.add_argument("--mm", type=float, default=3.0)
    a = ap.parse_args()
    given = cameras(f"{a.copy}/train_0/scene_camera.json")
    exact = cameras(f"{a.seq}/train_0/scene_camera.json")
    frames = [int(f) for f in a.frames.split(",") if int(f) in given]
    xi, centres = [], []
    for f in frames:
        (Rg, tg, _), (Re, te, _) = given[f], exact[f]
        xi.append(np.concatenate([log_rotation(Rg.T @ Re), Rg.T @ (te - tg)]))
        centres.append(-Rg.T @ tg)
    xi, centres = np.array(xi), np.array(centres)
    points = object_centres(a.seq)
    rho = a.mm / 1000.0 / np.radians(a.deg)
    for name, g in [("given", None), ("mean", -xi.mean(axis=0)), ("prior", prior_gauge(xi, centres, rho))]:
        xs = np.zeros_like(xi) if g is None else xi + g
        s = meeting_shift({f: (x[:3], x[3:]) for f, x in zip(frames, xs)}, given, exact, points)
        print(f"{name:6s} {1000 * np.linalg.norm(s):5.2f} mm  [{', '.join(f'{1000 * v:5.2f}' for v in s)}]")


if __name__ == "__main__":
    main()
