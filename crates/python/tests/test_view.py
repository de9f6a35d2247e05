"""`dwslam run --view-save FILE.rrd` (a binary built with `--features view`) read back by the
Rerun Python SDK of the same version: the entities of the live view, one image and one
camera pose per frame, the tracked points, the map, the edges and the time series — on
7-Scenes (RGB-D) and a monocular KITTI drive."""

import collections
import os
import subprocess

import pytest

from conftest import require

rr = pytest.importorskip("rerun", reason="the Rerun SDK (pip install rerun-sdk==0.36.3)")
from rerun.experimental import RrdReader  # noqa: E402

VIEW_ENTITIES = {
    "/world/camera",
    "/world/camera/image",
    "/world/camera/image/tracked",
    "/world/trajectory",
    "/world/trajectory_final",
    "/world/ground_truth",
    "/world/keyframes",
    "/world/points",
    "/world/covisibility",
    "/world/pose_constraints",
    "/world/loops",
    "/tracking/state",
    "/tracking/points",
    "/tracking/log",
    "/timing/ms",
}


@pytest.fixture(scope="module")
def view_bin(dwslam_bin):
    """The binary, if it has the live view (CI builds it so: DWSLAM_REQUIRE_VIEW=1)."""
    help_text = subprocess.run([dwslam_bin, "run", "--help"], capture_output=True,
                               text=True).stdout
    assert "--view-save" in help_text
    probe = subprocess.run([dwslam_bin, "run", "/nonexistent", "--view-save", "/tmp/x.rrd"],
                           capture_output=True, text=True)
    if "--features view" in probe.stderr:
        if os.environ.get("DWSLAM_REQUIRE_VIEW", "").strip() == "1":
            pytest.fail("the binary has no live view (DWSLAM_REQUIRE_VIEW=1)")
        pytest.skip("the binary was built without --features view")
    return dwslam_bin


def read_view(path):
    """Per entity: the frames (the `frame` timeline) its rows were logged at, and the
    columns they carry; and the static entities."""
    frames = collections.defaultdict(list)
    columns = collections.defaultdict(set)
    static = set()
    for chunk in RrdReader(path).stream():
        entity = chunk.entity_path
        batch = chunk.to_record_batch()
        if chunk.is_static:
            static.add(entity)
            columns[entity].update(batch.schema.names)
            continue
        columns[entity].update(batch.schema.names)
        if "frame" in batch.schema.names:
            frames[entity].extend(batch.column("frame").to_pylist())
    return frames, columns, static


def run_view(dwslam_bin, tmp_path, args):
    rrd = tmp_path / "view.rrd"
    out = tmp_path / "out"
    subprocess.run([dwslam_bin, "run", *map(str, args), "--deterministic", "--quiet",
                    "--view-save", rrd, "--out", out], check=True, stdout=subprocess.DEVNULL)
    posed = sum(1 for line in (out / "trajectory.tum").read_text().splitlines()
                if line and not line.startswith("#"))
    return read_view(rrd), posed


def check_view(view, frames_run, posed, mono):
    frames, columns, static = view
    present = set(frames) | static
    missing = VIEW_ENTITIES - present - ({"/world/pose_constraints"} if mono else set())
    assert not missing, f"entities missing from the view: {sorted(missing)}"
    # One image per frame, one camera pose per frame with a pose.
    images = frames["/world/camera/image"]
    assert sorted(images) == list(range(frames_run)), "not one image per frame"
    assert any("Image:buffer" in c for c in columns["/world/camera/image"])
    poses = frames["/world/camera"]
    assert len(poses) == len(set(poses)) == posed, (len(poses), posed)
    assert any("Transform3D" in c for c in columns["/world/camera"])
    # The frustum (the camera's pinhole) is logged once, statically.
    assert "/world/camera/image" in static
    assert any("Pinhole" in c for c in columns["/world/camera/image"])
    # Tracked points on every frame; a state and a time per frame.
    assert len(frames["/world/camera/image/tracked"]) == frames_run
    assert len(frames["/tracking/state"]) == frames_run
    assert len(frames["/timing/ms"]) == frames_run
    assert any("Points3D:colors" in c for c in columns["/world/points"])


def test_the_view_of_an_rgbd_run(kitchen, view_bin, tmp_path):
    view, posed = run_view(view_bin, tmp_path, [kitchen, "--max-frames", 300])
    check_view(view, 300, posed, mono=False)


def test_the_view_of_a_monocular_kitti_drive(view_bin, tmp_path):
    kitti = require("kitti_odometry_snippets/KITTI_04_0_270")
    view, posed = run_view(view_bin, tmp_path, [kitti, "--sensor", "mono", "--max-frames",
                                                120])
    check_view(view, 120, posed, mono=True)
