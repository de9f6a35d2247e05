"""dwslam from Python: double window optimisation visual SLAM (Strasdat 2012).

The same system as the ``dwslam`` binary, through its Rust library (PyO3): ``run`` is
``dwslam run``'s loop, ``System`` the live system driven frame by frame, ``Sequence`` the
readers of TUM RGB-D / 7-Scenes, EuRoC, KITTI and image folders, ``eval`` the trajectory
errors of ``dwslam eval`` (as evo computes them). Arrays are numpy arrays; poses are
``world_from_camera`` 4×4 matrices; errors are ``DwslamError`` (or ``ValueError`` for a bad
argument) with the message the binary prints.

>>> import dwslam
>>> result = dwslam.run("seven_scenes_redkitchen_1000", max_frames=300, deterministic=True)
>>> result.poses.shape, result.summary["keyframes"]
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from collections.abc import Sequence as Seq
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

import numpy as np

from . import _dwslam
from ._dwslam import DwslamError, Sequence

__version__ = _dwslam.__version__

__all__ = [
    "DwslamError",
    "Result",
    "Sequence",
    "System",
    "Tracked",
    "eval",
    "run",
    "__version__",
]

PathLike = Union[str, "os.PathLike[str]"]
Config = Union[None, PathLike, Mapping[str, Any]]


@dataclass
class Result:
    """What a run produced (``dwslam.run`` or ``System.finish``).

    Every frame's pose as tracked live (``poses``, NaN where a frame has none, with its
    ``states`` and ``reasons``), the trajectory after the run's final optimisation
    (``final_timestamps``, ``final_poses``), the keyframes, the map points with their colours,
    and ``summary``: the run's ``summary.json`` as a dict.
    """

    frame_index: np.ndarray
    timestamps: np.ndarray
    poses: np.ndarray
    states: np.ndarray
    reasons: List[Optional[str]]
    final_timestamps: np.ndarray
    final_poses: np.ndarray
    keyframe_ids: np.ndarray
    keyframe_frames: np.ndarray
    keyframe_timestamps: np.ndarray
    keyframe_poses: np.ndarray
    points: np.ndarray
    colours: np.ndarray
    summary: Dict[str, Any] = field(repr=False)

    @classmethod
    def _from_native(cls, d: Dict[str, Any]) -> "Result":
        d = dict(d)
        summary = json.loads(d.pop("summary_json"))
        d["states"] = np.asarray(d["states"], dtype=str)
        return cls(summary=summary, **d)

    @property
    def tracked(self) -> np.ndarray:
        """A mask of the frames with a pose."""
        return ~np.isnan(self.poses[:, 0, 0])

    def __repr__(self) -> str:
        s = self.summary
        loops = len(s.get("loops", []))
        return (
            f"dwslam.Result({len(self.timestamps)} frames, {s.get('keyframes')} keyframes, "
            f"{s.get('points')} points, {loops} loop{'' if loops == 1 else 's'})"
        )


def run(
    path: PathLike,
    *,
    sensor: Optional[str] = None,
    config: Config = None,
    out: Optional[PathLike] = None,
    deterministic: bool = False,
    max_frames: Optional[int] = None,
    start_frame: int = 0,
    depth_frames_only: bool = False,
    camera: Optional[PathLike] = None,
    format: Optional[str] = None,
    skip_bad_frames: bool = False,
    save_map: Optional[PathLike] = None,
    load_map: Optional[PathLike] = None,
    localise: bool = False,
    quiet: bool = True,
) -> Result:
    """Runs the live system on a recorded sequence, as ``dwslam run PATH`` does.

    ``sensor``: ``"mono"``, ``"stereo"`` or ``"rgbd"`` (default: the sequence's own).
    ``config``: a YAML file's path or a dict of overrides (the same keys). ``out``: write the
    run folder there (trajectories, ``map.ply``, ``summary.json``, …); by default nothing is
    kept. ``deterministic``: run the back-end at fixed points of the frame stream (identical
    results run to run, the same as ``dwslam run --deterministic``). The interpreter is
    released while the run goes on; Ctrl-C stops it after the frame in hand (the outputs are
    written) and raises ``KeyboardInterrupt``.
    """
    native = _dwslam.run(
        os.fspath(path),
        sensor=sensor,
        config=_config(config),
        out=None if out is None else os.fspath(out),
        deterministic=deterministic,
        max_frames=max_frames,
        start_frame=start_frame,
        depth_frames_only=depth_frames_only,
        camera=None if camera is None else os.fspath(camera),
        format=format,
        skip_bad_frames=skip_bad_frames,
        save_map=None if save_map is None else os.fspath(save_map),
        load_map=None if load_map is None else os.fspath(load_map),
        localise=localise,
        quiet=quiet,
    )
    return Result._from_native(native)


@dataclass(frozen=True)
class Tracked:
    """One frame as tracked: its pose (``world_from_camera``, 4×4, or ``None`` before the map
    starts), its state (``"good"``, ``"weak"`` or ``"lost"``) with the reason, and the
    keyframe id it became, if it did."""

    index: int
    pose: Optional[np.ndarray]
    state: str
    reason: Optional[str]
    keyframe: Optional[int]


class System:
    """The live system, driven frame by frame.

    ``camera``: a dict as ``Sequence.camera`` gives it — ``sensor`` (``"mono"``, ``"stereo"``,
    ``"rgbd"``), ``fx``, ``fy``, ``cx``, ``cy`` (pixels, of undistorted / rectified images),
    ``baseline`` (stereo, metres), ``depth_metres_per_unit`` and ``depth_max_valid_raw``
    (RGB-D; millimetres and 65535 by default). ``sensor`` runs a stereo or RGB-D camera
    monocular. ``load_map`` goes on in a saved map (``localise=True``: only localise in it);
    ``save_map`` is written by ``finish``.

    >>> seq = dwslam.Sequence("seven_scenes_redkitchen_1000", max_frames=100)
    >>> system = dwslam.System(seq.camera)
    >>> for f in seq:
    ...     tracked = system.track(f["image"], f["timestamp"], depth=f["depth"])
    >>> result = system.finish()
    """

    def __init__(
        self,
        camera: Mapping[str, Any],
        *,
        sensor: Optional[str] = None,
        config: Config = None,
        deterministic: bool = False,
        load_map: Optional[PathLike] = None,
        localise: bool = False,
        save_map: Optional[PathLike] = None,
        name: str = "python",
    ) -> None:
        self._native = _dwslam.System(
            dict(camera),
            sensor=sensor,
            config=_config(config),
            deterministic=deterministic,
            load_map=None if load_map is None else os.fspath(load_map),
            localise=localise,
            save_map=None if save_map is None else os.fspath(save_map),
            name=name,
        )

    def track(
        self,
        image: np.ndarray,
        timestamp: float,
        right: Optional[np.ndarray] = None,
        depth: Optional[np.ndarray] = None,
        index: Optional[int] = None,
    ) -> Tracked:
        """Tracks one frame: ``image`` is ``(H, W)`` grey or ``(H, W, 3)`` RGB ``uint8`` (the
        left image of a stereo pair, whose ``right`` is needed); ``depth`` is the raw
        ``uint16`` depth image of an RGB-D camera. The interpreter is released meanwhile."""
        d = self._native.track(
            np.ascontiguousarray(image, dtype=np.uint8),
            float(timestamp),
            right=None if right is None else np.ascontiguousarray(right, dtype=np.uint8),
            depth=None if depth is None else _depth(depth),
            index=index,
        )
        return Tracked(**d)

    def finish(self) -> Result:
        """Ends the run: the final optimisation, the map saved (``save_map``); the result."""
        return Result._from_native(self._native.finish())

    @property
    def progress(self) -> Dict[str, int]:
        """Keyframes, points and loops so far."""
        return self._native.progress()

    @property
    def camera(self) -> Dict[str, Any]:
        return self._native.camera

    @property
    def free_scale(self) -> bool:
        """A monocular map's scale is its own: compare after a similarity (``align="sim3"``)."""
        return self._native.free_scale


Trajectory = Union[PathLike, Result, Tuple[np.ndarray, np.ndarray]]


def eval(
    ground_truth: Trajectory,
    estimate: Trajectory,
    *,
    align: str = "se3",
    max_time_difference: float = 0.01,
    rpe_delta: int = 1,
    final: bool = False,
) -> Dict[str, Any]:
    """ATE and RPE of ``estimate`` against ``ground_truth``, as ``dwslam eval`` (and evo)
    compute them, after associating timestamps within ``max_time_difference`` seconds.

    Each trajectory is a file (TUM, KITTI or EuRoC CSV), a ``Result`` (its live poses, or
    with ``final=True`` the poses after the run), or ``(timestamps, poses)`` with poses as
    ``(N, 4, 4)`` matrices or ``(N, 7)`` TUM rows. ``align``: ``"se3"``, ``"sim3"``
    (monocular) or ``"none"``. Returns ``ate`` and ``rpe_translation`` (metres) and
    ``rpe_rotation_deg`` statistics (``rmse``, ``mean``, ``median``, ``std``, ``min``,
    ``max``, ``sse``), the per-pose ``ate_errors``, the alignment's ``scale`` and the number of
    ``poses`` compared.
    """
    gt_t, gt_p = _trajectory(ground_truth, final)
    est_t, est_p = _trajectory(estimate, final)
    return _dwslam.eval_arrays(
        gt_t,
        gt_p,
        est_t,
        est_p,
        align=align,
        max_time_difference=float(max_time_difference),
        rpe_delta=int(rpe_delta),
    )


def _trajectory(t: Trajectory, final: bool) -> Tuple[np.ndarray, np.ndarray]:
    if isinstance(t, Result):
        if final:
            return t.final_timestamps, t.final_poses
        keep = t.tracked
        return t.timestamps[keep], t.poses[keep]
    if isinstance(t, (str, os.PathLike)):
        return _dwslam.read_trajectory(os.fspath(t))
    if isinstance(t, Seq) and len(t) == 2:
        stamps, poses = t
        return (
            np.ascontiguousarray(stamps, dtype=np.float64),
            np.ascontiguousarray(poses, dtype=np.float64),
        )
    raise TypeError(
        "a trajectory is a file path, a dwslam.Result or (timestamps, poses); got "
        f"{type(t).__name__}"
    )


def _config(config: Config) -> Any:
    if config is None or isinstance(config, Mapping):
        return None if config is None else dict(config)
    return os.fspath(config)


def _depth(depth: np.ndarray) -> np.ndarray:
    depth = np.asarray(depth)
    if depth.dtype != np.uint16:
        raise ValueError(
            f"depth: expected the raw uint16 depth image, got {depth.dtype} "
            "(scale metres by the camera's depth_metres_per_unit first)"
        )
    return np.ascontiguousarray(depth)
