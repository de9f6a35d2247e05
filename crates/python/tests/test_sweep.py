"""`python -m dwslam.sweep` on a local Ray cluster of two worker processes: 3 sequences × 3
settings and a job with a bad path give one table; the bad job is a failed row with its
error while the others finish; the same deterministic sweep gives the same table twice (but
for its timing columns)."""

import csv
import json
import subprocess
import sys

import pytest

from conftest import require

pytest.importorskip("ray")

SETTINGS = {
    "default": {},
    "no-loops": {"loops": {"enabled": False}},
    "small-window": {"optimiser": {"inner": 10, "outer": 40}},
}


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    sequences = [
        {"name": "kitchen", "path": str(require("seven_scenes_redkitchen_1000")),
         "max_frames": 300},
        {"name": "euroc", "path": str(require("euroc_v1_01_easy_micro")), "sensor": "stereo"},
        {"name": "tum-xyz", "path": str(require("tum_rgbd_fr1_xyz_fragment"))},
        {"name": "missing", "path": "no/such/sequence"},
    ]
    job_list = [{"sequence": s["name"], "setting": c} for s in sequences[:3] for c in SETTINGS]
    job_list.append({"sequence": "missing", "setting": "default"})
    path = tmp_path_factory.mktemp("sweep") / "jobs.json"
    path.write_text(json.dumps({"sequences": sequences, "settings": SETTINGS,
                                "jobs": job_list, "deterministic": True}))
    return path


def sweep(jobs, out):
    done = subprocess.run(
        [sys.executable, "-m", "dwslam.sweep", str(jobs), "--out", str(out), "--cpus", "2",
         "--timeout", "600"],
        capture_output=True, text=True,
    )
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    return done, rows


def test_a_sweep_on_a_local_ray_cluster_gives_one_table_twice(jobs, tmp_path):
    first, rows = sweep(jobs, tmp_path / "first")
    # One job failed: the sweep says so by its exit code, after every other job finished.
    assert first.returncode == 1, first.stdout + first.stderr
    assert len(rows) == 10
    failed = [r for r in rows if r["status"] != "ok"]
    assert [(r["sequence"], r["setting"]) for r in failed] == [("missing", "default")]
    assert "no/such/sequence" in failed[0]["error"]
    ok = [r for r in rows if r["status"] == "ok"]
    for r in ok:
        assert float(r["tracked_percent"]) > 90, r
        assert 0 < float(r["ate_live_m"]) < 0.1 and 0 < float(r["ate_final_m"]) < 0.1, r
        assert float(r["ms_per_frame"]) > 0
        assert (tmp_path / "first" / "runs" / r["sequence"] / r["setting"]
                / "summary.json").is_file()
    assert {r["sequence"] for r in ok} == {"kitchen", "euroc", "tum-xyz"}
    assert {r["setting"] for r in ok} == set(SETTINGS)
    # The settings reach the runs.
    by = {(r["sequence"], r["setting"]): r for r in ok}
    assert all(by[(s, "no-loops")]["loops"] == "0" for s in ("kitchen", "euroc", "tum-xyz"))
    assert int(by[("kitchen", "default")]["loops"]) >= 1
    markdown = (tmp_path / "first" / "results.md").read_text()
    assert "| kitchen | no-loops | rgbd |" in markdown and "**failed**" in markdown
    assert "10 jobs, 9 ok, 1 failed." in markdown

    second, again = sweep(jobs, tmp_path / "second")
    assert second.returncode == 1
    timing = ("ms_per_frame", "seconds")
    strip = lambda table: [{k: v for k, v in r.items() if k not in timing} for r in table]  # noqa: E731
    assert strip(again) == strip(rows)


def test_a_bad_jobs_file_is_one_line_of_error(tmp_path):
    bad = tmp_path / "jobs.json"
    bad.write_text('{"sequences": [{"name": "a"}]}')
    done = subprocess.run([sys.executable, "-m", "dwslam.sweep", str(bad), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.startswith("error: ") and "sequences[0]" in done.stderr
    assert "Traceback" not in done.stderr
