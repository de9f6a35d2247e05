"""Shared fixtures of the Python package's tests: the real datasets (as the Rust tests find
them: $DWSLAM_DATA or ../shared/data; a skip when absent, a failure when
DWSLAM_REQUIRE_DATA=1) and the `dwslam` binary the package is compared with."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]


def data_root() -> pathlib.Path:
    root = os.environ.get("DWSLAM_DATA") or str(REPO / ".." / "shared" / "data")
    return pathlib.Path(root).resolve()


def require(relative: str) -> pathlib.Path:
    path = data_root() / relative
    if path.exists():
        return path
    if os.environ.get("DWSLAM_REQUIRE_DATA", "").strip() == "1":
        pytest.fail(f"{path} not found (DWSLAM_REQUIRE_DATA=1)")
    pytest.skip(f"{path} not found")


@pytest.fixture(scope="session")
def kitchen() -> pathlib.Path:
    return require("seven_scenes_redkitchen_1000")


@pytest.fixture(scope="session")
def euroc() -> pathlib.Path:
    return require("euroc_v1_01_easy_micro")


@pytest.fixture(scope="session")
def dwslam_bin() -> pathlib.Path:
    """The release binary of this checkout (`$DWSLAM_BIN`, else built here)."""
    given = os.environ.get("DWSLAM_BIN")
    if given:
        return pathlib.Path(given)
    subprocess.run(
        ["cargo", "build", "--release", "--quiet", "--bin", "dwslam"], cwd=REPO, check=True
    )
    return REPO / "target" / "release" / "dwslam"
