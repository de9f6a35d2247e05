"""Shared by the peer drivers: a g2o reader/writer and the dwslam/GTSAM pose-graph cost in numpy.

Conventions (the same as dwslam's `data::g2o`, see crates/data/src/g2o.rs):
  * vertex poses are world_from_body; an edge measures Z = X_from^-1 * X_to;
  * residual d = Log(Z^-1 * X_from^-1 * X_to) with the full SE(2)/SE(3) logarithm, tangent
    order (v, omega) -- dwslam's order; the information matrix is the file's, symmetrised from
    its upper triangle, in file order (x y z qx qy qz) == (v, omega), NOT rescaled;
  * cost = 1/2 * sum d^T Lambda d (GTSAM's graph.error, Ceres's cost).
Only numpy is needed, so this module works in both the GTSAM venv (numpy 2) and the g2o venv
(numpy<2).
"""

import math

import numpy as np


class Graph:
    """A pose graph as read from a g2o file."""

    def __init__(self):
        self.dim = None          # 2 or 3
        self.vertices = {}       # id -> pose (2D: (x, y, theta); 3D: 4x4 matrix)
        self.order = []          # vertex ids in file order
        self.edges = []          # (from, to, measurement, information (dwslam order))
        self.fixed = []          # ids from FIX lines


def symmetric_from_upper(values, n):
    m = np.zeros((n, n))
    k = 0
    for i in range(n):
        for j in range(i, n):
            m[i, j] = m[j, i] = values[k]
            k += 1
    return m


def quat_to_matrix(qx, qy, qz, qw):
    q = np.array([qw, qx, qy, qz], dtype=float)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quat(r):
    """(qx, qy, qz, qw) of a rotation matrix (Shepperd's method)."""
    t = np.trace(r)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s
    return x, y, z, w


def se3(qx, qy, qz, qw, x, y, z):
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(qx, qy, qz, qw)
    t[:3, 3] = [x, y, z]
    return t


def read_g2o(path):
    """Reads VERTEX_SE2/EDGE_SE2/VERTEX_SE3:QUAT/EDGE_SE3:QUAT/FIX; other tags are an error here
    (the datasets have none; dwslam's reader reports them)."""
    g = Graph()
    with open(path) as f:
        for line_no, line in enumerate(f, 1):
            w = line.split()
            if not w or w[0].startswith("#"):
                continue
            tag = w[0]
            if tag == "VERTEX_SE2":
                g.dim = 2
                i = int(w[1])
                g.vertices[i] = tuple(float(v) for v in w[2:5])
                g.order.append(i)
            elif tag == "VERTEX_SE3:QUAT":
                g.dim = 3
                i = int(w[1])
                x, y, z, qx, qy, qz, qw = (float(v) for v in w[2:9])
                g.vertices[i] = se3(qx, qy, qz, qw, x, y, z)
                g.order.append(i)
            elif tag == "EDGE_SE2":
                g.dim = 2
                a, b = int(w[1]), int(w[2])
                z = tuple(float(v) for v in w[3:6])
                info = symmetric_from_upper([float(v) for v in w[6:12]], 3)
                g.edges.append((a, b, z, info))
            elif tag == "EDGE_SE3:QUAT":
                g.dim = 3
                a, b = int(w[1]), int(w[2])
                x, y, z, qx, qy, qz, qw = (float(v) for v in w[3:10])
                info = symmetric_from_upper([float(v) for v in w[10:31]], 6)
                g.edges.append((a, b, se3(qx, qy, qz, qw, x, y, z), info))
            elif tag == "FIX":
                g.fixed.extend(int(v) for v in w[1:])
            else:
                raise ValueError(f"{path}:{line_no}: unsupported tag {tag}")
    if not g.order:
        raise ValueError(f"{path}: no VERTEX lines; complete it first with "
                         "`cargo run -p data --example g2o_complete`")
    return g


def fmt(v):
    return repr(float(v))


def write_g2o(path, g, poses):
    """Writes `poses` (id -> pose in the same form as Graph.vertices) with g's edges."""
    with open(path, "w") as f:
        for i in g.order:
            p = poses[i]
            if g.dim == 2:
                f.write(f"VERTEX_SE2 {i} {fmt(p[0])} {fmt(p[1])} {fmt(p[2])}\n")
            else:
                qx, qy, qz, qw = matrix_to_quat(p[:3, :3])
                t = p[:3, 3]
                f.write("VERTEX_SE3:QUAT %d %s\n" % (i, " ".join(fmt(v) for v in (*t, qx, qy, qz, qw))))
        n = 3 if g.dim == 2 else 6
        for a, b, z, info in g.edges:
            upper = [info[r, c] for r in range(n) for c in range(r, n)]
            if g.dim == 2:
                meas = list(z)
                tag = "EDGE_SE2"
            else:
                qx, qy, qz, qw = matrix_to_quat(z[:3, :3])
                meas = [*z[:3, 3], qx, qy, qz, qw]
                tag = "EDGE_SE3:QUAT"
            f.write("%s %d %d %s\n" % (tag, a, b, " ".join(fmt(v) for v in meas + upper)))
        for i in g.fixed:
            f.write(f"FIX {i}\n")


# --- the cost, independent of GTSAM and g2o ------------------------------------------------

def skew(w):
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def so3_log(r):
    """Rotation vector with angle in [0, pi]."""
    c = max(-1.0, min(1.0, (np.trace(r) - 1) / 2))
    theta = math.acos(c)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if theta < 1e-8:
        return 0.5 * v
    if math.pi - theta < 1e-6:
        # near pi: from the symmetric part, axis = column of (R + I) with the largest norm
        b = (r + np.eye(3)) / 2
        k = int(np.argmax(np.diag(b)))
        axis = b[:, k] / math.sqrt(b[k, k])
        if np.dot(axis, v) < 0:
            axis = -axis
        return theta * axis
    return theta / (2 * math.sin(theta)) * v


def se3_log(t):
    """(v, omega) with t = V(omega) v."""
    w = so3_log(t[:3, :3])
    theta = np.linalg.norm(w)
    W = skew(w)
    if theta < 1e-8:
        v_inv = np.eye(3) - 0.5 * W + W @ W / 12
    else:
        half = theta / 2
        v_inv = np.eye(3) - 0.5 * W + (1 - half / math.tan(half)) / theta ** 2 * W @ W
    return np.concatenate([v_inv @ t[:3, 3], w])


def se2_matrix(p):
    c, s = math.cos(p[2]), math.sin(p[2])
    return np.array([[c, -s, p[0]], [s, c, p[1]], [0, 0, 1.0]])


def se2_log(m):
    theta = math.atan2(m[1, 0], m[0, 0])
    if abs(theta) < 1e-10:
        a, b = 1.0, 0.0
    else:
        a, b = math.sin(theta) / theta, (1 - math.cos(theta)) / theta
    v = np.array([[a, -b], [b, a]])
    return np.concatenate([np.linalg.solve(v, m[:2, 2]), [theta]])


def inv(m):
    r = np.eye(m.shape[0])
    n = m.shape[0] - 1
    r[:n, :n] = m[:n, :n].T
    r[:n, n] = -m[:n, :n].T @ m[:n, n]
    return r


def residual(dim, z, xa, xb):
    if dim == 2:
        e = inv(se2_matrix(z)) @ inv(se2_matrix(xa)) @ se2_matrix(xb)
        return se2_log(e)
    return se3_log(inv(z) @ inv(xa) @ xb)


def cost(g, poses):
    """1/2 sum d^T Lambda d over all edges (dwslam's and GTSAM's cost)."""
    total = 0.0
    for a, b, z, info in g.edges:
        d = residual(g.dim, z, poses[a], poses[b])
        total += 0.5 * d @ info @ d
    return total


def dwslam_to_gtsam_pose3_information(info):
    """dwslam's (v, omega) order -> GTSAM Pose3's (omega, v) order."""
    p = np.zeros((6, 6))
    p[0:3, 3:6] = np.eye(3)
    p[3:6, 0:3] = np.eye(3)
    return p @ info @ p.T
