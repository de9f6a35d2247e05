"""Many runs as Ray tasks: ``python -m dwslam.sweep JOBS --out OUT [--address ADDR]``.

A sweep is a list of jobs — a sequence (path, sensor, frames) with a setting (a named
configuration override) — each run by ``dwslam.run`` as one Ray task (one CPU) on whatever
cluster ``ray.init(address=…)`` reaches (a local one of ``--cpus`` workers when none is
given), each writing its own run folder ``OUT/runs/<sequence>/<setting>/``. The results come
back into one table, ``OUT/results.csv`` and ``OUT/results.md``: per sequence and setting the
state of the job, ATE live and after the run, the share of frames tracked, keyframes, loops
and milliseconds per frame. A job that fails (a bad path, a run that stops, a worker that dies)
is a row with its error; a task is retried at most ``--max-retries`` times if its worker dies,
never for an error of its own, and one that outlives ``--timeout`` seconds is cancelled.

The jobs file (JSON, or YAML where PyYAML is installed — Ray brings it):

.. code-block:: json

    {"sequences": [{"name": "kitchen", "path": "…/seven_scenes_redkitchen_1000",
                    "max_frames": 300},
                   {"name": "euroc", "path": "…/euroc_v1_01_easy_micro", "sensor": "stereo"}],
     "settings": {"default": {}, "no-loops": {"loops": {"enabled": false}}},
     "deterministic": true}

makes every sequence × setting job; ``"jobs": [{"sequence": "kitchen", "setting":
"no-loops"}, …]`` picks some instead. A relative ``path`` is relative to the jobs file. On a
cluster of several machines, every node needs the package (``pip install`` it there, or
``--runtime-env`` with a ``pip`` entry) and the sequences at the same paths.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import sys
import time
import traceback
from typing import Any, Dict, List, Optional

#: The table's columns, in order; ``ms_per_frame`` and ``seconds`` are the only ones that
#: vary between two deterministic sweeps of the same jobs.
COLUMNS = [
    "sequence",
    "setting",
    "sensor",
    "status",
    "frames",
    "tracked_percent",
    "ate_live_m",
    "ate_final_m",
    "alignment",
    "keyframes",
    "loops",
    "ms_per_frame",
    "seconds",
    "error",
]

TIMING_COLUMNS = ("ms_per_frame", "seconds")


class SweepError(Exception):
    """A jobs file that cannot be swept (the message says what and where)."""


def load_jobs(path: pathlib.Path) -> Dict[str, Any]:
    """The jobs file: its sequences, settings and the jobs they make."""
    try:
        text = path.read_text()
    except OSError as e:
        raise SweepError(f"{path}: {e.strerror or e}") from None
    if path.suffix in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise SweepError(f"{path}: YAML needs PyYAML (pip install pyyaml), or write JSON")
        try:
            spec = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise SweepError(f"{path}: {e}") from None
    else:
        try:
            spec = json.loads(text)
        except json.JSONDecodeError as e:
            raise SweepError(f"{path}:{e.lineno}:{e.colno}: {e.msg}") from None
    if not isinstance(spec, dict) or not isinstance(spec.get("sequences"), list):
        raise SweepError(f"{path}: expected an object with a list of \"sequences\"")
    sequences: Dict[str, Dict[str, Any]] = {}
    for i, s in enumerate(spec["sequences"]):
        if not isinstance(s, dict) or "path" not in s:
            raise SweepError(f"{path}: sequences[{i}]: expected an object with a \"path\"")
        unknown = set(s) - {"name", "path", "sensor", "max_frames", "start_frame",
                            "depth_frames_only"}
        if unknown:
            raise SweepError(f"{path}: sequences[{i}]: unknown keys {sorted(unknown)}")
        name = str(s.get("name") or pathlib.Path(s["path"]).name)
        if name in sequences:
            raise SweepError(f"{path}: two sequences named {name!r} (give each a \"name\")")
        full = pathlib.Path(s["path"])
        if not full.is_absolute():
            full = (path.parent / full).resolve()
        sequences[name] = {**s, "name": name, "path": str(full)}
    settings = spec.get("settings", {"default": {}})
    if not isinstance(settings, dict) or not all(isinstance(v, dict) for v in settings.values()):
        raise SweepError(f"{path}: \"settings\": expected an object of named config overrides")
    if "jobs" in spec:
        jobs = []
        for i, j in enumerate(spec["jobs"]):
            if j.get("sequence") not in sequences or j.get("setting") not in settings:
                raise SweepError(
                    f"{path}: jobs[{i}]: {j!r} names no sequence or setting of the file"
                )
            jobs.append((j["sequence"], j["setting"]))
    else:
        jobs = [(s, c) for s in sequences for c in settings]
    return {
        "sequences": sequences,
        "settings": settings,
        "jobs": jobs,
        "deterministic": bool(spec.get("deterministic", False)),
    }


def run_job(sequence: Dict[str, Any], setting: str, config: Dict[str, Any],
            deterministic: bool, out: str) -> Dict[str, Any]:
    """One job (in a Ray worker): the run, and its row of the table. An error of the run is
    the row's, not the task's: it is reported, never retried."""
    import dwslam

    row: Dict[str, Any] = {c: "" for c in COLUMNS}
    row.update(sequence=sequence["name"], setting=setting, sensor=sequence.get("sensor", ""))
    started = time.perf_counter()
    try:
        os.makedirs(out, exist_ok=True)
        result = dwslam.run(
            sequence["path"],
            sensor=sequence.get("sensor"),
            config=config,
            out=out,
            deterministic=deterministic,
            max_frames=sequence.get("max_frames"),
            start_frame=sequence.get("start_frame", 0),
            depth_frames_only=sequence.get("depth_frames_only", False),
            quiet=True,
        )
    except Exception as e:  # noqa: BLE001 — every failure is the job's row
        row.update(status="failed", error=f"{type(e).__name__}: {e}".replace("\n", " "),
                   seconds=round(time.perf_counter() - started, 3))
        with open(os.path.join(out, "error.txt"), "w") as f:
            f.write(traceback.format_exc())
        return row
    s = result.summary
    frames = s["frames"]
    evaluation = s.get("evaluation", {})
    run = s.get("run", {})
    row.update(
        status="ok",
        sensor=s["sensor"],
        frames=frames,
        tracked_percent=round(
            100.0 * (s["tracking"]["good"] + s["tracking"]["weak"]) / max(frames, 1), 2),
        ate_live_m=evaluation.get("live", {}).get("ate_rmse_m", ""),
        ate_final_m=evaluation.get("final", {}).get("ate_rmse_m", ""),
        alignment=evaluation.get("live", {}).get("alignment", ""),
        keyframes=s["keyframes"],
        loops=len(s.get("loops", [])),
        ms_per_frame=round(1e3 * run.get("seconds", 0.0) / max(frames, 1), 3),
        seconds=round(time.perf_counter() - started, 3),
    )
    return row


def sweep(spec: Dict[str, Any], out: pathlib.Path, address: Optional[str], cpus: int,
          max_retries: int, timeout: Optional[float],
          runtime_env: Optional[Dict[str, Any]] = None) -> List[Dict[str, Any]]:
    """Runs the jobs of ``spec`` as Ray tasks; returns the table's rows (in the jobs' order)."""
    import ray

    options: Dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
    if runtime_env:
        options["runtime_env"] = runtime_env
    if address:
        ray.init(address=address, **options)
    else:
        ray.init(num_cpus=cpus, **options)
    try:
        task = ray.remote(num_cpus=1, max_retries=max_retries, retry_exceptions=False)(run_job)
        pending = {}
        for sequence, setting in spec["jobs"]:
            folder = out / "runs" / _safe(sequence) / _safe(setting)
            ref = task.remote(spec["sequences"][sequence], setting, spec["settings"][setting],
                              spec["deterministic"], str(folder))
            pending[ref] = (sequence, setting)
        total = len(pending)
        rows: Dict[Any, Dict[str, Any]] = {}
        started = time.monotonic()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            for ref in ready:
                sequence, setting = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except Exception as e:  # noqa: BLE001 — a worker that died, a cancelled task
                    row = _failed(spec, sequence, setting, f"{type(e).__name__}: {e}")
                rows[(sequence, setting)] = row
                print(f"[{len(rows)}/{total}] {sequence} / {setting}: {row['status']}"
                      + (f" ({row['error']})" if row["error"] else ""), flush=True)
            if timeout is not None and time.monotonic() - started > timeout and pending:
                for ref, (sequence, setting) in pending.items():
                    ray.cancel(ref, force=True)
                    rows[(sequence, setting)] = _failed(
                        spec, sequence, setting, f"cancelled after the sweep's {timeout:g} s")
                pending.clear()
        return [rows[job] for job in spec["jobs"]]
    finally:
        ray.shutdown()


def _failed(spec: Dict[str, Any], sequence: str, setting: str, error: str) -> Dict[str, Any]:
    row = {c: "" for c in COLUMNS}
    row.update(sequence=sequence, setting=setting,
               sensor=spec["sequences"][sequence].get("sensor", ""), status="failed",
               error=error.replace("\n", " "))
    return row


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def write_table(rows: List[Dict[str, Any]], out: pathlib.Path) -> None:
    """``results.csv`` and ``results.md`` in ``out``."""
    with open(out / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    cm = lambda v: "—" if v == "" else f"{100 * float(v):.2f}"  # noqa: E731
    lines = [
        "| sequence | setting | sensor | ATE live (cm) | ATE after (cm) | tracked % | "
        "keyframes | loops | ms / frame | state |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        state = "ok" if r["status"] == "ok" else f"**failed**: {r['error']}"
        lines.append(
            f"| {r['sequence']} | {r['setting']} | {r['sensor']} | {cm(r['ate_live_m'])} | "
            f"{cm(r['ate_final_m'])} | {r['tracked_percent']} | {r['keyframes']} | "
            f"{r['loops']} | {r['ms_per_frame']} | {state} |"
        )
    failed = sum(r["status"] != "ok" for r in rows)
    lines += ["", f"{len(rows)} jobs, {len(rows) - failed} ok, {failed} failed."]
    (out / "results.md").write_text("\n".join(lines) + "\n")


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dwslam.sweep",
        description="Run a sweep of dwslam jobs (sequence × setting) as Ray tasks; one table "
                    "of results (results.csv, results.md) in OUT.")
    parser.add_argument("jobs", type=pathlib.Path, help="the jobs file (JSON or YAML)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="output folder")
    parser.add_argument("--address", help="the Ray cluster (ray.init's address; 'auto' for "
                        "the one started on this machine); default: a local cluster")
    parser.add_argument("--cpus", type=int, default=os.cpu_count() or 1,
                        help="the local cluster's CPUs, one job each (default: all)")
    parser.add_argument("--max-retries", type=int, default=1,
                        help="re-runs of a task whose worker died (never for a job's own "
                             "error; default 1)")
    parser.add_argument("--timeout", type=float, help="cancel the jobs still running after "
                        "this many seconds (they are reported failed)")
    parser.add_argument("--deterministic", action="store_true",
                        help="every run deterministic (as the jobs file's \"deterministic\")")
    parser.add_argument("--runtime-env", type=json.loads,
                        help="Ray's runtime_env as JSON, e.g. '{\"pip\": [\"dwslam\"]}'")
    args = parser.parse_args(argv)
    try:
        spec = load_jobs(args.jobs)
    except SweepError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.deterministic:
        spec["deterministic"] = True
    if args.cpus < 1:
        print("error: --cpus must be at least 1", file=sys.stderr)
        return 2
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(f"error: --out {args.out}: {e.strerror or e}", file=sys.stderr)
        return 2
    print(f"sweep: {len(spec['jobs'])} jobs ({len(spec['sequences'])} sequences × "
          f"{len(spec['settings'])} settings) on "
          f"{args.address or f'a local Ray cluster of {args.cpus} CPUs'}", flush=True)
    rows = sweep(spec, args.out, args.address, args.cpus, args.max_retries, args.timeout,
                 args.runtime_env)
    write_table(rows, args.out)
    print((args.out / "results.md").read_text())
    print(f"wrote {args.out / 'results.csv'} and {args.out / 'results.md'}")
    return 0 if all(r["status"] == "ok" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
