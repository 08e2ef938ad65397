#!/usr/bin/env python3
"""What a run would score had the table's height moved its frame by another share.

    python3 bench/table_share.py RUN:SEQ... [--shares 0,0.5,1] [--trand target/release/trand]

RUN is a finished `trand reconstruct` of SEQ (a sequence with exact test views: a public one, a
`trand synth` scene or a `trand perturb` copy's exact original). The move onto the table comes after
training (`run.json`: `table_height`), so a run moved by share `a` of the measured height `h` instead
of the `shifted_m` it applied is the same model `a·h − shifted_m` lower; rendered at SEQ's t=0 test
cameras shifted by that amount (`trand render`, as `bench/shared_shift.py` does), it is scored with
`trand eval`'s metric: the share of object pixels within 2.5 cm. At the run's own share this
reproduces `trand eval`. BENCHMARKS.md §8, "Faint peaks".
"""
import argparse
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from shared_shift import within  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", metavar="RUN:SEQ")
    ap.add_argument("--shares", default="0,0.5,1", help="comma-separated shares of the height")
    ap.add_argument("--trand", default="target/release/trand")
    a = ap.parse_args()
    shares = [float(s) for s in a.shares.split(",")]
    for pair in a.runs:
        run, sep, seq = pair.partition(":")
        if not sep:
            ap.error(f"{pair!r}: give RUN:SEQ")
        table = json.load(open(f"{run}/run.json"))["table_height"]
        fit = table.get("fit") or {}
        h, moved = fit.get("height_m") or 0.0, table.get("shifted_m") or 0.0
        with tempfile.TemporaryDirectory() as tmp:
            scores = [within(run, seq, np.array([0.0, 0.0, s * h - moved]), a.trand, tmp, f"s{k}")
                      for k, s in enumerate(shares)]
        cells = "  ".join(f"{s:g}: {v:.2f}" for s, v in zip(shares, scores))
        print(f"{run}  reading {table.get('reading')}  contrast {fit.get('contrast', 0):.3f}  "
              f"height {1e3 * h:+.1f} mm  moved {1e3 * moved:+.1f} mm  {cells}", flush=True)


if __name__ == "__main__":
    main()
