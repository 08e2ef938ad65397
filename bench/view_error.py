#!/usr/bin/env python3
"""How far each training camera of a run is from the exact one, in pixels at the objects.

    python3 bench/view_error.py RUN COPY SEQ

RUN is a finished `trand reconstruct` of COPY, a `trand perturb` copy of the exact sequence SEQ.
For every training view it prints the mean distance, in pixels, between where the exact camera
and the run's camera (the given one, corrected by the table alignment where it was kept and by the
pose refinement) project each object's centre; the given cameras' distances for comparison.
"""
import argparse

import numpy as np

from shared_shift import cameras, corrections_of, object_centres, rotation


def projection(R, t, K, X):
    x = K @ (R @ X + t)
    return x[:2] / x[2]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("copy")
    ap.add_argument("seq")
    a = ap.parse_args()
    given = cameras(f"{a.copy}/train_0/scene_camera.json")
    exact = cameras(f"{a.seq}/train_0/scene_camera.json")
    centres = object_centres(a.seq)
    rows = {"given": [], "run": []}
    for f, (w, d) in sorted(corrections_of(a.run).items()):
        Rg, tg, c = given[f]
        Re, te, _ = exact[f]
        K = np.array(c["cam_K"], float).reshape(3, 3)
        Rc, tc = Rg @ rotation(np.array(w)), Rg @ np.array(d) + tg
        for name, (R, t) in (("given", (Rg, tg)), ("run", (Rc, tc))):
            off = [np.linalg.norm(projection(R, t, K, X) - projection(Re, te, K, X)) for X in centres]
            rows[name].append(np.mean(off))
    for name, px in rows.items():
        print(f"{name:5s} px {np.round(px, 1).tolist()}  mean {np.mean(px):.2f}")


if __name__ == "__main__":
    main()
