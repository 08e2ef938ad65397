#!/usr/bin/env bash
# Reproduces the figures of BENCHMARKS.md. Prints the machine, the commit and the date first.
#
#   bench/run_all.sh PART [OUT]     PART: blender | containers | default | time | raster | mpm | speed | all
#
# blender     every public Blender sequence (../shared/data/blender/seq_*), the defaults (native
#             resolution): t=0 and t=1, pooled, per sequence, per object and per kind
# containers  ten `trand synth --preset containers` scenes (seeds 0-9), --downsample 2
# default     ten `trand synth` scenes (seeds 1000-1009), --downsample 2
# time        wall, CPU and peak memory of t=0 and of the update on the four public sequences (run it on an
#             otherwise idle machine)
# raster      the rasterizer's divan benchmarks
# mpm         trand's MLS-MPM on the authors' fixture, then the Taichi script beside it when a Python
#             with taichi is given in TAICHI_PYTHON (process CPU time of both)
# speed       every speed figure: time, raster and mpm, one after the other
#
# The data folder is ../shared/data unless TRAND_DATA says otherwise. Results go to OUT
# (default bench-out/); the accuracy parts are resumable (`trand bench` skips finished runs).
set -euo pipefail
cd "$(dirname "$0")/.."
PART=${1:?usage: bench/run_all.sh blender|containers|default|time|raster|mpm|all [OUT]}
OUT=${2:-bench-out}
DATA=${TRAND_DATA:-../shared/data}
mkdir -p "$OUT"

echo "machine: $(nproc) cores,$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2), $(free -g | awk '/Mem/{print $2}') GiB"
echo "commit:  $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- crates || echo ' (with local changes)')"
echo "date:    $(date -u '+%F %H:%M UTC')"
echo "rustc:   $(rustc --version)"

cargo build --release -p trand-cli
T=target/release/trand

blender() {
    [ -d "$DATA/blender" ] || { echo "no $DATA/blender (set TRAND_DATA)"; exit 1; }
    $T bench --data "$DATA"/blender/seq_* --methods trand --out "$OUT/blender"
}

containers() {
    mkdir -p "$OUT/containers-data"
    for s in 0 1 2 3 4 5 6 7 8 9; do
        [ -d "$OUT/containers-data/c$s" ] ||
            $T synth --preset containers --seed "$s" --out "$OUT/containers-data/c$s" --quiet
    done
    $T bench --data "$OUT"/containers-data/c? --methods trand --downsample 2 --out "$OUT/containers"
}

default() {
    $T bench --synth 10 --methods trand --downsample 2 --out "$OUT/default"
}

timed() {
    # the run's own summary line, then wall, CPU (user + system) and peak memory from GNU time
    /usr/bin/time -o "$OUT/time/last" -f "  wall %e s, CPU %U+%S s, peak %M KiB" "$@" 2>"$OUT/time/stderr" |
        grep -E "reconstructed|updated" || { cat "$OUT/time/stderr"; exit 1; }
    cat "$OUT/time/last"
}

time_runs() {
    for s in seq_101 seq_105 seq_108 seq_109; do
        rm -rf "$OUT/time/$s"
        mkdir -p "$OUT/time/$s"
        echo "$s t=0 (defaults):"
        timed $T reconstruct --data "$DATA/blender/$s" --out "$OUT/time/$s/t0"
        echo "$s update (defaults):"
        timed $T update --run "$OUT/time/$s/t0" --data "$DATA/blender/$s" --out "$OUT/time/$s/t1"
    done
}

raster() { cargo bench -p trand-render --bench raster; }

mpm() {
    cargo bench -p trand-physics --bench mpm
    if [ -n "${TAICHI_PYTHON:-}" ]; then
        "$TAICHI_PYTHON" bench/taichi_mpm.py --grid sparse
    else
        echo "TAICHI_PYTHON not set: the Taichi side is skipped (python3 -m venv V && V/bin/pip install taichi numpy)"
    fi
}

case "$PART" in
    blender) blender ;;
    containers) containers ;;
    default) default ;;
    time) time_runs ;;
    raster) raster ;;
    mpm) mpm ;;
    speed) time_runs; raster; mpm ;;
    all) blender; containers; default; time_runs; raster; mpm ;;
    *) echo "unknown part $PART"; exit 2 ;;
esac
