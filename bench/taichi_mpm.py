#!/usr/bin/env python3
"""Peer benchmark for trand-physics' MPM: the same MLS-MPM in Taichi on its CPU backend.

Same particles (the fixture `particles_in.npy`), same parameters as TRAN-D's scene update
(dx = 1/48 m, E = 5e4 Pa, nu = 0.4, density 30000, particle volume dx^3, gravity (0, 0, -4.9),
sticky ground at z = 0, 100 frames x 10 substeps x 4e-4 s), the same substep as
`crates/trand-physics/src/mpm.rs`: P2G (APIC, quadratic B-spline, fixed-corotated stress via
Taichi's f32 `ti.svd`, as in taichi_elements) with atomic adds, grid update, G2P.

Grids (`--grid`):
  dense  : a dense 64^3 grid with index offset -8 (covers [-0.17, 1.17] m per axis), cleared each substep;
  sparse : the authors' unbounded layout, pointer(32^3) -> pointer(32^3) -> dense(4^3) with offset
           -2048 (4096 nodes per axis), deactivated each substep, grid update as a struct-for over
           active nodes.
Timing: one warm-up frame (JIT compile) on the same particles, then the particles are reset and 100
frames are timed between ti.sync() calls. Prints wall seconds, process CPU seconds (all threads;
the steadier number on a shared machine) and the per-body mean displacement (to
check it is the same simulation as the fixture's reference output).

Usage: python bench/taichi_mpm.py [--grid dense|sparse] [--frames 100] [--threads N]
"""
import argparse
import os
import time

import numpy as np
import taichi as ti

HERE = os.path.dirname(os.path.abspath(__file__))
FIXTURE = os.path.join(HERE, "..", "crates", "trand-physics", "tests", "data", "mpm-reference")

ap = argparse.ArgumentParser()
ap.add_argument("--grid", choices=["dense", "sparse"], default="dense")
ap.add_argument("--frames", type=int, default=100)
ap.add_argument("--threads", type=int, default=0, help="CPU threads (0: Taichi's default, all cores)")
args = ap.parse_args()

init_kw = dict(arch=ti.cpu, default_fp=ti.f32, random_seed=0)
if args.threads > 0:
    init_kw["cpu_max_num_threads"] = args.threads
ti.init(**init_kw)

x_in = np.load(os.path.join(FIXTURE, "particles_in.npy")).astype(np.float32)
n = x_in.shape[0]

dx = 1.0 / 48.0
inv_dx = 48.0
E, nu, rho = 5e4, 0.4, 30000.0
mu0, la0 = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
p_vol = dx ** 3
p_mass = rho * p_vol
frame_dt, substeps = 4e-3, 10
dt = frame_dt / substeps
gravity = ti.Vector([0.0, 0.0, -4.9])

x = ti.Vector.field(3, ti.f32, n)
v = ti.Vector.field(3, ti.f32, n)
C = ti.Matrix.field(3, 3, ti.f32, n)
F = ti.Matrix.field(3, 3, ti.f32, n)
grid_v = ti.Vector.field(3, ti.f32)
grid_m = ti.field(ti.f32)

if args.grid == "dense":
    OFF = -8
    ti.root.dense(ti.ijk, 64).place(grid_v, grid_m, offset=(OFF, OFF, OFF))
else:
    OFF = -2048
    ti.root.pointer(ti.ijk, 32).pointer(ti.ijk, 32).dense(ti.ijk, 4).place(grid_v, grid_m, offset=(OFF, OFF, OFF))


@ti.kernel
def reset(xs: ti.types.ndarray(dtype=ti.math.vec3, ndim=1)):
    for p in x:
        x[p] = xs[p]
        v[p] = ti.Vector.zero(ti.f32, 3)
        C[p] = ti.Matrix.zero(ti.f32, 3, 3)
        F[p] = ti.Matrix.identity(ti.f32, 3)


@ti.kernel
def clear_dense():
    for I in ti.grouped(grid_m):
        grid_v[I] = ti.Vector.zero(ti.f32, 3)
        grid_m[I] = 0.0


@ti.kernel
def p2g():
    for p in x:
        base = ti.floor(x[p] * inv_dx - 0.5).cast(int)
        fx = x[p] * inv_dx - base.cast(float)
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
        F[p] = (ti.Matrix.identity(ti.f32, 3) + dt * C[p]) @ F[p]
        U, sig, V = ti.svd(F[p])
        J = sig[0, 0] * sig[1, 1] * sig[2, 2]
        stress = 2 * mu0 * (F[p] - U @ V.transpose()) @ F[p].transpose() + ti.Matrix.identity(ti.f32, 3) * la0 * J * (J - 1)
        stress = (-dt * p_vol * 4 * inv_dx * inv_dx) * stress
        affine = stress + p_mass * C[p]
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            offset = ti.Vector([i, j, k])
            dpos = (offset.cast(float) - fx) * dx
            weight = w[i][0] * w[j][1] * w[k][2]
            grid_v[base + offset] += weight * (p_mass * v[p] + affine @ dpos)
            grid_m[base + offset] += weight * p_mass


@ti.kernel
def grid_op():
    for I in ti.grouped(grid_m):
        if grid_m[I] > 0:
            gv = grid_v[I] / grid_m[I] + dt * gravity
            if I[2] < 0:  # sticky ground z = 0: node z = I[2]*dx < 0
                gv = ti.Vector.zero(ti.f32, 3)
            grid_v[I] = gv


@ti.kernel
def g2p():
    for p in x:
        base = ti.floor(x[p] * inv_dx - 0.5).cast(int)
        fx = x[p] * inv_dx - base.cast(float)
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
        new_v = ti.Vector.zero(ti.f32, 3)
        new_C = ti.Matrix.zero(ti.f32, 3, 3)
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            offset = ti.Vector([i, j, k])
            dpos = offset.cast(float) - fx
            g_v = grid_v[base + offset]
            weight = w[i][0] * w[j][1] * w[k][2]
            new_v += weight * g_v
            new_C += 4 * inv_dx * weight * g_v.outer_product(dpos)
        v[p] = new_v
        C[p] = new_C
        x[p] += dt * new_v


def substep():
    if args.grid == "dense":
        clear_dense()
    else:
        ti.deactivate_all_snodes()  # the authors' engine: grid.deactivate_all() per substep
    p2g()
    grid_op()
    g2p()


def frames(k):
    for _ in range(k):
        for _ in range(substeps):
            substep()
    ti.sync()


reset(x_in)
frames(1)  # warm-up: JIT-compiles every kernel
reset(x_in)
ti.sync()
t0, c0 = time.perf_counter(), time.process_time()
frames(args.frames)
secs, cpu = time.perf_counter() - t0, time.process_time() - c0

out = x.to_numpy()
da = (out[:20000] - x_in[:20000]).mean(0)
db = (out[20000:] - x_in[20000:]).mean(0)
print(f"body A mean displacement {da}, z range [{out[:20000, 2].min():.4f}, {out[:20000, 2].max():.4f}]")
print(f"body B mean displacement {db}, z range [{out[20000:, 2].min():.4f}, {out[20000:, 2].max():.4f}]")
print(f"taichi {ti.__version__} cpu, grid {args.grid}: {n} particles, {args.frames} frames x {substeps} substeps: {secs:.3f} s")
print(f"  process CPU time (all threads): {cpu:.3f} s")
