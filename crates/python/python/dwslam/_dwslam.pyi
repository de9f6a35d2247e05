"""Type stubs of dwslam's native module (crates/python/src/lib.rs)."""

from typing import Any, Dict, Iterator, Optional, Tuple

import numpy as np

__version__: str

class DwslamError(RuntimeError): ...

def run(
    path: str,
    *,
    sensor: Optional[str] = ...,
    config: Any = ...,
    out: Optional[str] = ...,
    deterministic: bool = ...,
    max_frames: Optional[int] = ...,
    start_frame: int = ...,
    depth_frames_only: bool = ...,
    camera: Optional[str] = ...,
    format: Optional[str] = ...,
    skip_bad_frames: bool = ...,
    save_map: Optional[str] = ...,
    load_map: Optional[str] = ...,
    localise: bool = ...,
    quiet: bool = ...,
) -> Dict[str, Any]: ...
def read_trajectory(path: str) -> Tuple[np.ndarray, np.ndarray]: ...
def eval_arrays(
    gt_timestamps: np.ndarray,
    gt_poses: np.ndarray,
    est_timestamps: np.ndarray,
    est_poses: np.ndarray,
    *,
    align: str = ...,
    max_time_difference: float = ...,
    rpe_delta: int = ...,
) -> Dict[str, Any]: ...

class System:
    def __init__(
        self,
        camera: Dict[str, Any],
        *,
        sensor: Optional[str] = ...,
        config: Any = ...,
        deterministic: bool = ...,
        load_map: Optional[str] = ...,
        localise: bool = ...,
        save_map: Optional[str] = ...,
        name: str = ...,
    ) -> None: ...
    def track(
        self,
        image: np.ndarray,
        timestamp: float,
        right: Optional[np.ndarray] = ...,
        depth: Optional[np.ndarray] = ...,
        index: Optional[int] = ...,
    ) -> Dict[str, Any]: ...
    def progress(self) -> Dict[str, int]: ...
    def finish(self) -> Dict[str, Any]: ...
    @property
    def camera(self) -> Dict[str, Any]: ...
    @property
    def free_scale(self) -> bool: ...

class Sequence:
    """A recorded sequence's frames as numpy arrays: each a dict of ``index``, ``timestamp``,
    ``image`` ((H, W, 3) RGB where the sequence has colour, else (H, W) grey, uint8),
    ``right`` (stereo), ``depth`` (raw uint16, RGB-D), ``world_from_camera`` (4×4 ground
    truth or None)."""

    def __init__(
        self,
        path: str,
        *,
        sensor: Optional[str] = ...,
        max_frames: Optional[int] = ...,
        start_frame: int = ...,
        depth_frames_only: bool = ...,
        camera: Optional[str] = ...,
        format: Optional[str] = ...,
    ) -> None: ...
    @property
    def camera(self) -> Dict[str, Any]: ...
    @property
    def ground_truth(self) -> Optional[Tuple[np.ndarray, np.ndarray]]: ...
    def __len__(self) -> int: ...
    def __iter__(self) -> Iterator[Dict[str, Any]]: ...
    def __next__(self) -> Dict[str, Any]: ...
