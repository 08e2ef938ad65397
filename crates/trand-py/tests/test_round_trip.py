"""A tiny synthetic scene through reconstruct, render, update, save and load."""

import subprocess
import threading
import time

import numpy as np
import pytest

import trand
from conftest import ITERATIONS, SEED, cli_binary, depth_mae, new_view


def test_sequence_arrays_follow_the_cli_rig(seq, tiny):
    t0 = seq["train_0"]
    assert t0["frames"] == [1, 3, 5, 7, 9, 11]
    assert t0["images"][0].dtype == np.uint8 and t0["images"][0].shape == (120, 160, 3)
    assert t0["masks"][0].dtype == np.uint16 and t0["masks"][0].shape == (120, 160)
    assert t0["intrinsics"].shape == (6, 3, 3) and t0["world_to_camera"].shape == (6, 4, 4)
    assert seq["test_0"]["depth"][0].dtype == np.float32
    assert seq["removed"] == [1] and seq["object_ids"] == [1, 2, 3]
    assert len(trand.load_sequence(tiny, views=None)["train_0"]["frames"]) == 13


def test_reconstruction_depth_is_within_3_cm_at_the_test_cameras(scene0, seq):
    assert scene0.state == "t0" and scene0.object_ids == [1, 2, 3]
    assert depth_mae(scene0, seq["test_0"]) < 0.03


def test_update_removes_the_object_and_keeps_depth_within_8_cm(scene0, scene1, seq):
    before = scene0.points().copy()
    assert scene1.state == "t1" and scene1.removed == [1]
    assert scene1.object_ids == [2, 3]
    assert depth_mae(scene1, seq["test_1"]) < 0.08
    # The t = 0 scene is left as it was.
    assert np.array_equal(scene0.points(), before) and scene0.state == "t0"


def test_render_gives_every_map_with_its_shape_and_type(scene0, seq):
    t = seq["test_0"]
    h, w = t["masks"][0].shape
    m = scene0.render(t["intrinsics"][0], t["world_to_camera"][0], w, h)
    assert m["depth"].shape == (h, w) and m["depth"].dtype == np.float32
    assert m["objects"].shape == (h, w) and m["objects"].dtype == np.uint16
    assert m["alpha"].shape == (h, w) and m["alpha"].dtype == np.float32
    assert m["normal"].shape == (h, w, 3) and m["normal"].dtype == np.float32
    assert set(np.unique(m["objects"])) <= {0, 1, 2, 3}
    assert (m["alpha"] >= 0).all() and (m["alpha"] <= 1).all()
    on = m["alpha"] > 0.5
    assert np.allclose(np.linalg.norm(m["normal"][on], axis=-1), 1.0, atol=1e-4)
    # Object pixels mostly agree with the ground-truth mask.
    agree = (m["objects"] > 0) == (t["masks"][0] > 0)
    assert agree.mean() > 0.9
    assert np.array_equal(m["depth"], scene0.render_depth(t["intrinsics"][0], t["world_to_camera"][0], w, h))


def test_points_of_the_objects_are_theirs(scene0):
    pts = scene0.points()
    assert pts.shape == (len(scene0), 3) and pts.dtype == np.float32
    per = [scene0.points(i) for i in scene0.object_ids]
    assert all(len(p) > 0 for p in per)
    assert sum(len(p) for p in per) <= len(scene0)
    assert (pts[:, 2] > 0).all()


def test_saved_scenes_load_back_to_the_same_depth(scene0, scene1, seq, tmp_path):
    t = seq["test_1"]
    h, w = t["masks"][0].shape
    for name, s in (("t0", scene0), ("t1", scene1)):
        s.save(tmp_path / name)
        back = trand.load(tmp_path / name)
        assert back.state == s.state and back.object_ids == s.object_ids and len(back) == len(s)
        a = s.render_depth(t["intrinsics"][0], t["world_to_camera"][0], w, h)
        b = back.render_depth(t["intrinsics"][0], t["world_to_camera"][0], w, h)
        assert np.array_equal(a, b)
    # A loaded t = 0 scene updates to the same t = 1 scene.
    again = trand.load(tmp_path / "t0").update(*new_view(seq), progress=False)
    assert np.array_equal(again.points(), scene1.points())


def test_stacked_arrays_and_lists_give_the_same_scene(seq):
    t0 = seq["train_0"]
    args = dict(iterations=20, seed=3, progress=False)
    a = trand.reconstruct(t0["images"], t0["masks"], t0["intrinsics"], t0["world_to_camera"], **args)
    b = trand.reconstruct(
        np.stack(t0["images"]), np.stack(t0["masks"]).astype(np.int32),
        list(t0["intrinsics"]), list(t0["world_to_camera"]), **args,
    )
    assert np.array_equal(a.points(), b.points())


def test_same_seed_gives_the_cli_depth_bit_for_bit(scene0, scene1, tiny, tmp_path):
    cli = cli_binary()
    run0, run1 = tmp_path / "run0", tmp_path / "run1"
    subprocess.run(
        [cli, "reconstruct", "--data", str(tiny), "--out", str(run0),
         "--iterations", str(ITERATIONS), "--seed", str(SEED)],
        check=True, capture_output=True,
    )
    subprocess.run(
        [cli, "update", "--run", str(run0), "--data", str(tiny), "--out", str(run1)],
        check=True, capture_output=True,
    )
    seq = trand.load_sequence(tiny)
    for scene, run, split in ((scene0, run0, "test_0"), (scene1, run1, "test_1")):
        # The same surfels, bit for bit ...
        loaded = trand.load(run)
        assert np.array_equal(loaded.points(), scene.points())
        # ... so the same depth once clamped where the CLI clamps (at its test cameras' range).
        t = seq[split]
        for i, frame in enumerate(t["frames"]):
            h, w = t["masks"][i].shape
            k, m = t["intrinsics"][i], t["world_to_camera"][i]
            theirs = np.load(run / "depth" / f"{frame:06d}.npy")
            assert np.array_equal(scene.render_depth(k, m, w, h, far=loaded.far), theirs), f"{split} {frame}"
            assert np.array_equal(loaded.render_depth(k, m, w, h), theirs), f"{split} {frame}"


def test_the_cli_reads_a_saved_scene(scene0, tiny, tmp_path):
    cli = cli_binary()
    scene0.save(tmp_path / "py0")
    out = subprocess.run(
        [cli, "update", "--run", str(tmp_path / "py0"), "--data", str(tiny), "--out", str(tmp_path / "py1")],
        capture_output=True, text=True,
    )
    assert out.returncode == 0, out.stderr
    assert trand.load(tmp_path / "py1").removed == [1]


def test_the_gil_is_released_while_reconstructing(seq):
    t0 = seq["train_0"]
    ticks = 0
    done = threading.Event()

    def work():
        trand.reconstruct(t0["images"], t0["masks"], t0["intrinsics"], t0["world_to_camera"],
                          iterations=60, progress=False)
        done.set()

    th = threading.Thread(target=work)
    th.start()
    while not done.is_set():
        ticks += 1
        time.sleep(0.001)
    th.join()
    assert ticks > 100, f"the main thread ran only {ticks} times while the reconstruction ran"
