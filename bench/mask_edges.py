#!/usr/bin/env python3
"""How far the training masks' edges were off before and after a run grew them to the photograph's edge.

    python3 bench/mask_edges.py RUN [COPY]

RUN is a finished `trand reconstruct`; its `run.json` lists every (view, object) mask grown and by how
many pixels (`mask_edges`). COPY, a `trand perturb --boundary B` copy (the run's data), says in its
`perturbation.json` by how much each mask was eroded (negative) or dilated; without it the masks are
taken as exact. Over the run's training views it prints the masks counted, how many were grown, and
the sum over masks of the pixels still eroded and dilated, as given and as grown (a mask eroded by 3 px
and grown by 2 counts 1 px eroded; its blobs are not counted).
"""
import json
import os
import sys


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    run = sys.argv[1]
    r = json.load(open(os.path.join(run, "run.json")))
    grown = {(g["view"], g["object_id"]): g["px"] for g in r["mask_edges"]["grown_to_image_edges"]}
    views = r["train_views"]
    given = {}
    if len(sys.argv) == 3:
        p = json.load(open(os.path.join(sys.argv[2], "perturbation.json")))
        for v in p["views"]:
            for oid, radius in v["boundary"]:
                given[(v["view"], oid)] = radius
    else:
        for v in views:
            for oid in r["object_channels"]:
                given[(v, oid[0])] = 0
    rows = [(k, rad, grown.get(k, 0)) for k, rad in given.items() if k[0] in views]
    ero = lambda x: sum(max(0, -v) for v in x)
    dil = lambda x: sum(max(0, v) for v in x)
    before = [rad for _, rad, _ in rows]
    after = [rad + g for _, rad, g in rows]
    print(f"{run}: {len(rows)} masks, {sum(1 for *_, g in rows if g)} grown; "
          f"eroded/dilated px as given {ero(before)}/{dil(before)}, as grown {ero(after)}/{dil(after)}")


if __name__ == "__main__":
    main()
