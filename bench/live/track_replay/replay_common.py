"""What the track-replay scripts share: a KITTI odometry folder's camera and ground truth, a dump
of corner tracks, and a track's point triangulated from known poses."""
import collections
import numpy as np


def load_sequence(seq):
    """(f, cx, cy) of P0 in `seq`/calib.txt (with or without KITTI's labels) and the
    camera_from_world matrices of `seq`/poses.txt (KITTI: world_from_camera, 3×4 rows)."""
    p0 = [l.split() for l in open(seq + '/calib.txt') if l.strip()][0]
    p0 = [float(x) for x in (p0[1:] if p0[0].endswith(':') else p0)]
    poses = np.loadtxt(seq + '/poses.txt').reshape(-1, 3, 4)
    return (p0[0], p0[2], p0[6]), [np.linalg.inv(np.vstack([p, [0, 0, 0, 1]])) for p in poses]


def read_dump(path):
    """track id → [(frame, u, v), …] from "frame track u v" lines."""
    tracks = collections.defaultdict(list)
    for l in open(path):
        fr, t, u, v = l.split()
        tracks[int(t)].append((int(fr), float(u), float(v)))
    return tracks


def triangulate(obs, camera, Tcw, iterations):
    """The point seen at `obs` ((frame, u, v) rows) from the cameras `Tcw`: linear (DLT), then
    `iterations` Gauss-Newton steps on the pixel error. Returns (X, the residuals of the last
    linearisation), or None when the linear solution is at infinity or the point falls behind a
    camera."""
    f, cx, cy = camera
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
    A = []
    for fr, u, v in obs:
        Pm = K @ Tcw[int(fr)][:3]
        A.append(u * Pm[2] - Pm[0]); A.append(v * Pm[2] - Pm[1])
    _, _, Vt = np.linalg.svd(np.array(A))
    if abs(Vt[-1][3]) <= 1e-12:
        return None
    X = Vt[-1][:3] / Vt[-1][3]
    rs = []
    for _ in range(iterations):
        H = np.zeros((3, 3)); g = np.zeros(3); rs = []
        for fr, u, v in obs:
            R, t = Tcw[int(fr)][:3, :3], Tcw[int(fr)][:3, 3]; x = R @ X + t
            if x[2] <= 0:
                return None
            e = np.array([f * x[0] / x[2] + cx - u, f * x[1] / x[2] + cy - v])
            J = np.array([[f / x[2], 0, -f * x[0] / x[2] ** 2], [0, f / x[2], -f * x[1] / x[2] ** 2]]) @ R
            H += J.T @ J; g += J.T @ e; rs.append(e)
        X = X - np.linalg.solve(H + 1e-9 * np.eye(3), g)
    return X, np.array(rs)
