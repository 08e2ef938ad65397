"""The package's acceptance round trip on a generated scene, printing what it measures.

    python examples/round_trip.py [SEQUENCE]     # default: generates `trand synth --preset tiny --seed 7`

t = 0 from the six ring views (300 iterations), depth at the t = 0 test cameras; the update with
train_1 frame 0, depth at the t = 1 test cameras. The error is the mean absolute depth error over the
ground-truth object pixels (metres).
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import trand


def depth_mae(scene, split):
    errors = []
    for i, mask in enumerate(split["masks"]):
        h, w = mask.shape
        d = scene.render_depth(split["intrinsics"][i], split["world_to_camera"][i], w, h)
        on = (mask > 0) & (split["depth"][i] > 0)
        errors.append(np.abs(d[on] - split["depth"][i][on]))
    return float(np.concatenate(errors).mean())


def main():
    if len(sys.argv) > 1:
        path = Path(sys.argv[1])
    else:
        path = Path(tempfile.mkdtemp()) / "tiny"
        trand.synth(path, preset="tiny", seed=7)
    seq = trand.load_sequence(path)
    t0 = seq["train_0"]
    start = time.perf_counter()
    scene = trand.reconstruct(
        t0["images"], t0["masks"], t0["intrinsics"], t0["world_to_camera"], iterations=300
    )
    print(f"t=0: {len(scene)} surfels in {time.perf_counter() - start:.1f} s, "
          f"depth MAE {depth_mae(scene, seq['test_0']):.4f} m")
    t1 = seq["train_1"]
    i = t1["frames"].index(0)
    start = time.perf_counter()
    after = scene.update(t1["images"][i], t1["masks"][i], t1["intrinsics"][i], t1["world_to_camera"][i])
    print(f"t=1: removed {after.removed}, {len(after)} surfels in {time.perf_counter() - start:.1f} s, "
          f"depth MAE {depth_mae(after, seq['test_1']):.4f} m")


if __name__ == "__main__":
    main()
