#!/usr/bin/env python3
"""How much of a perturbed copy's t=0 cost is the shift no training image shows.

    python3 bench/shared_shift.py RUN COPY SEQ [--axes xyz] [--given] [--trand target/release/trand]

RUN is a finished `trand reconstruct` of COPY, a `trand perturb` copy of the exact sequence SEQ.
Independent pose errors of the training views leave the corrected cameras a common offset: the
least-squares meeting point of their rays through each object's centre lies off the exact cameras'
by a shift s (BENCHMARKS.md §8). The model is built where the corrected cameras put it, so it sits
at truth + s. This script measures s from `run.json`'s pose corrections (which hold the table-height move),
renders the run with `trand render` at SEQ's t=0 test cameras moved by s, and prints the share of
object pixels within 2.5 cm as run and with s removed (the metric of `trand eval`: uncovered pixels
count with an error of their GT depth). `--axes z` removes only the shift's vertical part.
"""
import argparse
import glob
import json
import os
import subprocess
import tempfile

import numpy as np
from PIL import Image


def rotation(w):
    """exp([w]x), Rodrigues."""
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = np.asarray(w) / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def log_rotation(R):
    """The rotation vector of R (inverse Rodrigues)."""
    th = np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    if th < 1e-12:
        return np.zeros(3)
    return th / (2.0 * np.sin(th)) * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])


def cameras(path):
    out = {}
    for k, c in json.load(open(path)).items():
        out[int(k)] = (np.array(c["cam_R_w2c"], float).reshape(3, 3), np.array(c["cam_t_w2c"], float) / 1000.0, c)
    return out


def object_centres(seq):
    gt = json.load(open(f"{seq}/test_0/scene_gt.json"))
    cams = cameras(f"{seq}/test_0/scene_camera.json")
    k = min(int(f) for f in gt)
    R, t, _ = cams[k]
    return [R.T @ (np.array(o["cam_t_m2c"], float) / 1000.0 - t) for o in gt[str(k)]]


def meeting_shift(corrections, given, exact, points):
    """The least-squares shift s with which cameras see the points: `corrections` maps each frame to
    its (omega, delta) (world frame, radians and metres) applied to its `given` camera; `exact` holds
    the true ones."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for f, (w, d) in corrections.items():
        Rg, tg, _ = given[f]
        Re, te, _ = exact[f]
        # Corrected camera: x_c = R_g (exp([w]x) x + d) + t_g (d includes the table-height move).
        Rc = Rg @ rotation(np.array(w))
        tc = Rg @ np.array(d) + tg
        centre = -Re.T @ te
        for X in points:
            # The point the corrected camera sees where the exact one sees X, across the ray.
            e = Re.T @ (Rc @ X + tc - (Re @ X + te))
            u = X - centre
            u /= np.linalg.norm(u)
            P = np.eye(3) - np.outer(u, u)
            A += P
            b += P @ e
    return -np.linalg.solve(A, b)


def corrections_of(run, given_only=False):
    """Each training frame's correction (omega, delta) of its given camera in `run`: the table
    alignment, where it was kept, composed with the refinement (zero with `given_only`)."""
    r = json.load(open(f"{run}/run.json"))
    found = (r.get("details", r).get("table_alignment") or {}).get("found") or {}
    aligned = found.get("corrections") if found.get("kept") else None
    corrections = {}
    for i, v in enumerate(r["pose_refinement"]["views"]):
        f = int(v["view"].split("/")[-1])
        if given_only:
            corrections[f] = (np.zeros(3), np.zeros(3))
        elif aligned is None:
            corrections[f] = (v["omega_rad"], v["delta_m"])
        else:
            # Training refined the cameras aligned on the table: compose the two corrections,
            # exp([W]x) = exp([a_w]x) exp([w]x), D = exp([a_w]x) d + a_d.
            a_w, a_d = np.array(aligned[i][:3]), np.array(aligned[i][3:])
            turn = rotation(a_w) @ rotation(np.array(v["omega_rad"]))
            corrections[f] = (log_rotation(turn), rotation(a_w) @ np.array(v["delta_m"]) + a_d)
    return corrections


def shared_shift(run, copy, seq, given_only=False):
    """The least-squares shift s with which the corrected training cameras see every object centre
    (the given ones, uncorrected, with `given_only`)."""
    given = cameras(f"{copy}/train_0/scene_camera.json")
    exact = cameras(f"{seq}/train_0/scene_camera.json")
    return meeting_shift(corrections_of(run, given_only), given, exact, object_centres(seq))


def within(run, seq, shift, trand, tmp, tag):
    cams = cameras(f"{seq}/test_0/scene_camera.json")
    listed = []
    for k in sorted(cams):
        R, t, c = cams[k]
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, t - R @ shift
        listed.append({"name": f"{k:06d}", "K": c["cam_K"], "world_to_camera": M.flatten().tolist(),
                       "width": c["width"], "height": c["height"]})
    spec, out = os.path.join(tmp, f"{tag}.json"), os.path.join(tmp, tag)
    json.dump(listed, open(spec, "w"))
    subprocess.run([trand, "render", "--run", run, "--cameras", spec, "--out", out], check=True,
                   stdout=subprocess.DEVNULL)
    n = ok = 0
    for k in sorted(cams):
        scale = cams[k][2].get("depth_scale", 1.0)
        gt = np.array(Image.open(f"{seq}/test_0/depth/{k:06d}.png"), float) * scale / 1000.0
        mask = np.zeros(gt.shape, bool)
        for p in glob.glob(f"{seq}/test_0/mask_visib/{k:06d}_*.png"):
            mask |= np.array(Image.open(p)) > 0
        mask &= gt > 0
        pred = np.load(f"{out}/{k:06d}_depth.npy").astype(float)
        pred = np.where(np.isfinite(pred), pred, 0.0)
        n += mask.sum()
        ok += (np.abs(gt - pred)[mask] < 0.025).sum()
    return 100.0 * ok / n


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("copy")
    ap.add_argument("seq")
    ap.add_argument("--axes", default="xyz", help="the shift's components to remove (default xyz)")
    ap.add_argument("--given", action="store_true", help="also print the given cameras' shift")
    ap.add_argument("--trand", default="target/release/trand")
    a = ap.parse_args()
    if not a.axes or set(a.axes) - set("xyz"):
        ap.error(f"--axes {a.axes!r}: give some of x, y, z")
    if a.given:
        g = shared_shift(a.run, a.copy, a.seq, given_only=True)
        print(f"given cameras' shift (mm) {np.round(1000 * g, 2).tolist()}")
    s = shared_shift(a.run, a.copy, a.seq) * np.array([float(c in a.axes) for c in "xyz"])
    with tempfile.TemporaryDirectory() as tmp:
        as_run = within(a.run, a.seq, np.zeros(3), a.trand, tmp, "as_run")
        removed = within(a.run, a.seq, s, a.trand, tmp, "removed")
    print(f"shift (mm) {np.round(1000 * s, 2).tolist()}  within 2.5 cm: as run {as_run:.2f} %, shift removed {removed:.2f} %")


if __name__ == "__main__":
    main()
