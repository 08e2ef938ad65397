"""Bad arguments raise ValueError / TypeError naming the argument; Ctrl-C raises KeyboardInterrupt."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import trand


@pytest.fixture
def views(seq):
    t0 = seq["train_0"]
    return [list(t0["images"]), list(t0["masks"]), list(t0["intrinsics"]), list(t0["world_to_camera"])]


def reconstruct(images, masks, intrinsics, w2c, **kw):
    return trand.reconstruct(images, masks, intrinsics, w2c, iterations=1, progress=False, **kw)


def test_wrong_image_shape_names_the_view(views):
    images, masks, ks, ws = views
    bad = images.copy()
    bad[2] = bad[2][..., :2]
    with pytest.raises(ValueError, match=r"images\[2\]: expected an HxWx3 image"):
        reconstruct(bad, masks, ks, ws)


def test_wrong_dtypes_are_type_errors(views):
    images, masks, ks, ws = views
    with pytest.raises(TypeError, match=r"images\[0\]: expected dtype uint8"):
        reconstruct([i.astype(np.float32) for i in images], masks, ks, ws)
    with pytest.raises(TypeError, match=r"masks\[1\]: expected integer instance ids"):
        reconstruct(images, [m.astype(np.float64) if i == 1 else m for i, m in enumerate(masks)], ks, ws)
    with pytest.raises(TypeError, match="images: expected a list"):
        reconstruct(42, masks, ks, ws)


def test_a_mask_of_another_size_is_refused(views):
    images, masks, ks, ws = views
    bad = masks.copy()
    bad[4] = bad[4][:-1]
    with pytest.raises(ValueError, match=r"masks\[4\]: shape \(119, 160\) differs"):
        reconstruct(images, bad, ks, ws)


def test_nan_pose_names_the_entry(views):
    images, masks, ks, ws = views
    bad = [w.copy() for w in ws]
    bad[3][1, 2] = np.nan
    with pytest.raises(ValueError, match=r"world_to_camera\[3\]\[1\]\[2\]: is nan"):
        reconstruct(images, masks, ks, bad)


def test_a_non_rotation_and_a_skewed_k_are_refused(views):
    images, masks, ks, ws = views
    bad = [w.copy() for w in ws]
    bad[0][:3, :3] *= 2
    with pytest.raises(ValueError, match=r"world_to_camera\[0\].*orthonormal"):
        reconstruct(images, masks, ks, bad)
    badk = [k.copy() for k in ks]
    badk[5][0, 1] = 0.5
    with pytest.raises(ValueError, match=r"intrinsics\[5\]\[0\]\[1\]: skew"):
        reconstruct(images, masks, badk, ws)
    with pytest.raises(ValueError, match=r"intrinsics\[0\]: expected shape \(3, 3\)"):
        reconstruct(images, masks, [k[:2] for k in ks], ws)


def test_mismatched_lengths_are_named(views):
    images, masks, ks, ws = views
    with pytest.raises(ValueError, match=r"masks: 5 given for 6 images"):
        reconstruct(images, masks[:5], ks, ws)
    with pytest.raises(ValueError, match=r"world_to_camera: 4 given for 6 images"):
        reconstruct(images, masks, ks, ws[:4])
    with pytest.raises(ValueError, match="images: no views given"):
        reconstruct([], [], [], [])


def test_bad_options_are_named(views):
    images, masks, ks, ws = views
    with pytest.raises(ValueError, match="identity: 'sam' is not one of"):
        reconstruct(images, masks, ks, ws, identity="sam")
    with pytest.raises(ValueError, match="method: "):
        reconstruct(images, masks, ks, ws, method="nerf")
    with pytest.raises(ValueError, match="downsample: 0 is not in 1..64"):
        reconstruct(images, masks, ks, ws, downsample=0)
    with pytest.raises(TypeError, match="seed: expected an integer"):
        reconstruct(images, masks, ks, ws, seed=1.5)
    with pytest.raises(ValueError, match=r"masks\[0\]: object id 40 does not fit"):
        reconstruct(images, [np.where(m > 0, 40, 0) for m in masks], ks, ws)
    with pytest.raises(ValueError, match="masks: no object pixels"):
        reconstruct(images, [np.zeros_like(m) for m in masks], ks, ws)


def test_scene_methods_check_their_arguments(scene0, scene1, seq, tmp_path):
    t = seq["test_0"]
    k, w = t["intrinsics"][0], t["world_to_camera"][0]
    with pytest.raises(ValueError, match="width: 0 is not in"):
        scene0.render_depth(k, w, 0, 120)
    bad = w.copy()
    bad[3] = [0, 0, 1, 1]
    with pytest.raises(ValueError, match=r"world_to_camera\[3\]: the bottom row"):
        scene0.render_depth(k, bad, 160, 120)
    with pytest.raises(ValueError, match="object_id: no object 9"):
        scene0.points(9)
    with pytest.raises(ValueError, match="mask: the new image's mask is empty"):
        scene0.update(t["images"][0], np.zeros((120, 160), np.uint16), k, w, progress=False)
    with pytest.raises(ValueError, match="removed: no object 7 at t=0"):
        scene0.update(t["images"][0], t["masks"][0], k, w, removed=[7], progress=False)
    with pytest.raises(ValueError, match="needs a t=0 scene"):
        scene1.update(t["images"][0], t["masks"][0], k, w, progress=False)
    scene0.save(tmp_path / "s")
    with pytest.raises(FileExistsError):
        scene0.save(tmp_path / "s")
    with pytest.raises(FileNotFoundError):
        trand.load(tmp_path / "absent")
    with pytest.raises(ValueError, match="not a run folder"):
        trand.load(tmp_path)
    with pytest.raises(FileNotFoundError):
        trand.load_sequence(tmp_path / "absent")


def test_ctrl_c_interrupts_a_reconstruction(tiny):
    # A process started in the background by a non-interactive shell inherits SIGINT ignored, and
    # Python then keeps it ignored: restore the handler an interactive Python has.
    script = textwrap.dedent(f"""
        import signal, sys, time, trand
        signal.signal(signal.SIGINT, signal.default_int_handler)
        seq = trand.load_sequence({str(tiny)!r})
        t0 = seq["train_0"]
        print("ready", flush=True)
        start = time.time()
        try:
            trand.reconstruct(t0["images"], t0["masks"], t0["intrinsics"], t0["world_to_camera"],
                              iterations=100000, progress=False)
        except KeyboardInterrupt:
            print("interrupted after", time.time() - start, flush=True)
            sys.exit(3)
        sys.exit(0)
    """)
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(3.0)
    sent = time.time()
    p.send_signal(signal.SIGINT)
    try:
        code = p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert code == 3, p.stdout.read()
    assert time.time() - sent < 10
