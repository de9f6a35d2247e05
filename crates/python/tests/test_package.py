"""The Python package against the binary: the README's example gives the trajectory of
`dwslam run --deterministic` (to 1e-9), streaming the same frames through `System.track`
gives the same poses, `dwslam.eval` gives `dwslam eval`'s numbers; bad input is an exception
naming what is wrong; the interpreter is released while frames are processed; Ctrl-C stops a
run with its outputs written."""

import json
import os
import pathlib
import re
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

import dwslam
from conftest import REPO, data_root

FRAMES = 300


def readme_example() -> str:
    """The Python example of the README (the block after its `tested by` marker)."""
    text = (REPO / "README.md").read_text()
    marker = "<!-- tested by crates/python/tests/test_package.py -->"
    assert marker in text, "the README's Python example lost its marker"
    block = re.search(r"```python\n(.*?)```", text[text.index(marker) :], re.S)
    assert block, "no ```python block after the marker"
    return block.group(1)


@pytest.fixture(scope="module")
def binary_run(kitchen, dwslam_bin, tmp_path_factory):
    out = tmp_path_factory.mktemp("binary")
    subprocess.run(
        [dwslam_bin, "run", kitchen, "--deterministic", "--max-frames", str(FRAMES),
         "--quiet", "--out", out],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return out


@pytest.fixture(scope="module")
def example(kitchen):
    """The README's example, run on this machine's data."""
    code = readme_example().replace('"../shared/data/', f'"{data_root()}/')
    namespace = {}
    exec(compile(code, "README.md", "exec"), namespace)
    return namespace


def assert_same_poses(a: np.ndarray, b: np.ndarray, what: str):
    assert a.shape == b.shape, f"{what}: {a.shape} vs {b.shape}"
    both = ~np.isnan(a[:, 0, 0])
    assert np.array_equal(both, ~np.isnan(b[:, 0, 0])), f"{what}: frames with a pose differ"
    worst = np.abs(a[both] - b[both]).max()
    assert worst <= 1e-9, f"{what}: poses differ by {worst}"


def test_the_readme_example_gives_the_binarys_trajectory(example, binary_run):
    result = example["result"]
    assert isinstance(result, dwslam.Result)
    assert len(result.timestamps) == FRAMES
    assert result.summary["frames"] == FRAMES and result.summary["sensor"] == "rgbd"
    assert result.summary["run"]["mode"] == "deterministic"
    for name, stamps, poses in [
        ("trajectory.tum", result.timestamps[result.tracked], result.poses[result.tracked]),
        ("trajectory_final.tum", result.final_timestamps, result.final_poses),
    ]:
        t, p = dwslam._dwslam.read_trajectory(str(binary_run / name))
        assert np.array_equal(t, stamps), name
        assert_same_poses(poses, p, name)
    # The map the binary wrote holds the points the package returns.
    summary = json.loads((binary_run / "summary.json").read_text())
    assert summary["points"] == len(result.points) and summary["keyframes"] == len(
        result.keyframe_ids
    )
    assert result.points.shape[1] == 3 and result.colours.dtype == np.uint8
    assert result.keyframe_poses.shape == (len(result.keyframe_ids), 4, 4)


def test_streaming_frame_by_frame_gives_the_same_poses(example):
    result, streamed, tracked = example["result"], example["streamed"], example["tracked"]
    assert isinstance(tracked, dwslam.Tracked)
    assert_same_poses(streamed.poses, result.poses, "live poses")
    assert_same_poses(streamed.final_poses, result.final_poses, "final poses")
    assert np.array_equal(streamed.states, result.states)


def test_eval_gives_the_binarys_errors(example, binary_run, dwslam_bin, tmp_path):
    errors = example["errors"]
    stats = tmp_path / "eval.json"
    subprocess.run(
        [dwslam_bin, "eval", binary_run / "ground_truth.tum", binary_run / "trajectory.tum",
         "--max-time-difference", "0.02", "--json", stats],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    theirs = json.loads(stats.read_text())
    ours = errors["ate"]["rmse"]
    assert errors["poses"] == FRAMES
    assert abs(ours - theirs["ate"]["rmse"]) <= 1e-9, (ours, theirs["ate"])
    # And the run's own evaluation (summary.json) says the same.
    live = example["result"].summary["evaluation"]["live"]["ate_rmse_m"]
    assert abs(ours - live) <= 1e-9
    assert 0.0 < ours < 0.05, f"ATE {ours} m on 300 frames of the kitchen"


def test_the_interpreter_runs_other_threads_while_frames_are_processed(kitchen):
    counts = []
    done = threading.Event()

    def count():
        n = 0
        while not done.is_set():
            n += 1
        counts.append(n)

    worker = threading.Thread(target=count)
    worker.start()
    started = time.perf_counter()
    dwslam.run(kitchen, max_frames=150, deterministic=True)
    seconds = time.perf_counter() - started
    done.set()
    worker.join()
    # A Python thread counts a few million a second; with the interpreter held by the run it
    # would only count between the run's calls.
    assert counts[0] > 1e5 * seconds, (counts[0], seconds)


def test_ctrl_c_stops_a_run_with_its_outputs_written(kitchen, tmp_path):
    timer = threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        dwslam.run(kitchen, out=tmp_path, deterministic=True)
    timer.cancel()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert 0 < summary["frames"] < 1000
    lines = (tmp_path / "trajectory.tum").read_text().splitlines()
    assert len(lines) >= summary["frames_with_pose"]


def test_stereo_and_monocular_runs(euroc, kitchen):
    stereo = dwslam.run(euroc, deterministic=True)
    assert stereo.summary["sensor"] == "stereo"
    assert stereo.tracked.mean() > 0.9
    gt = dwslam.Sequence(euroc).ground_truth
    assert dwslam.eval(gt, stereo, max_time_difference=0.02)["ate"]["rmse"] < 0.05
    mono = dwslam.run(kitchen, sensor="mono", max_frames=200, deterministic=True)
    assert mono.summary["sensor"] == "mono"
    assert mono.tracked.sum() > 100
    # A monocular map has its own scale: compared after a similarity.
    e = dwslam.eval(dwslam.Sequence(kitchen).ground_truth, mono, align="sim3",
                    max_time_difference=0.02)
    assert e["scale"] > 0 and e["ate"]["rmse"] < 0.1


def test_a_map_saved_by_a_streamed_run_is_localised_in(kitchen, tmp_path):
    path = tmp_path / "kitchen.map"
    sequence = dwslam.Sequence(kitchen, max_frames=200)
    system = dwslam.System(sequence.camera, deterministic=True, save_map=path)
    for frame in sequence:
        system.track(frame["image"], frame["timestamp"], depth=frame["depth"])
    mapped = system.finish()
    assert path.is_file() and mapped.summary["saved_map"]["holds"]["keyframes"] > 0
    again = dwslam.run(kitchen, start_frame=200, max_frames=100, load_map=path,
                       localise=True, deterministic=True)
    assert again.summary["keyframes_made"] == 0
    assert again.tracked.mean() > 0.9


def test_bad_input_is_an_exception_that_says_what_is_wrong(kitchen, tmp_path):
    with pytest.raises(dwslam.DwslamError, match="no-such-sequence"):
        dwslam.run(tmp_path / "no-such-sequence")
    with pytest.raises(ValueError, match="sensor='stereo'.*RGB-D"):
        dwslam.run(kitchen, sensor="stereo")
    with pytest.raises(ValueError, match="lidar"):
        dwslam.run(kitchen, sensor="lidar")
    with pytest.raises(ValueError, match="start_frame=5000"):
        dwslam.run(kitchen, start_frame=5000)
    with pytest.raises(ValueError, match="load_map"):
        dwslam.run(kitchen, localise=True)
    with pytest.raises(ValueError, match="config.*nonsense"):
        dwslam.run(kitchen, config={"keyframes": {"nonsense": 1}})
    with pytest.raises(dwslam.DwslamError, match="not a dwslam map"):
        bad = tmp_path / "bad.map"
        bad.write_bytes(b"hello")
        dwslam.run(kitchen, load_map=bad)
    with pytest.raises(ValueError, match="fx"):
        dwslam.System({"sensor": "mono", "fy": 500, "cx": 320, "cy": 240})
    sequence = dwslam.Sequence(kitchen, max_frames=2)
    system = dwslam.System(sequence.camera, config={"loops": {"enabled": False}})
    frame = next(iter(sequence))
    with pytest.raises(ValueError, match="image"):
        system.track(np.zeros((480, 640, 4), np.uint8), 0.0)
    with pytest.raises(ValueError, match="uint16"):
        system.track(frame["image"], 0.0, depth=frame["depth"].astype(np.float32))
    stereo = dwslam.System({"sensor": "stereo", "fx": 500, "fy": 500, "cx": 320, "cy": 240,
                            "baseline": 0.1}, config={"loops": {"enabled": False}})
    with pytest.raises(ValueError, match="right"):
        stereo.track(frame["image"], 0.0)
    system.track(frame["image"], frame["timestamp"], depth=frame["depth"])
    system.finish()
    with pytest.raises(dwslam.DwslamError, match="finished"):
        system.track(frame["image"], 1.0)
    with pytest.raises(TypeError, match="trajectory"):
        dwslam.eval(42, 43)
