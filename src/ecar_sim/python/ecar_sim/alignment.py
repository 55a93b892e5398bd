"""Point-set alignment for the Python tools: one Umeyama fit, quaternions, similarities.

Used by `run_session` (the map -> world fit of the VO and plane metrics), `vo_metrics`
and `ground_truth_aligner` (world -> map for rviz). The C++ side has its own in
`ecar_core/trajectory_eval.h` (`ecar_eval_traj`).

    s, r, t = umeyama(p_map, p_world)                   # p_world ~ s R p_map + t
    _, r, t = umeyama(p_world, p_map, with_scale=False)  # SE(3): s == 1
    T_world_map = Similarity(s, r, t)
    p_w = T_world_map.apply(p_m)

Quaternions are (x, y, z, w), as in geometry_msgs and TUM files.
"""

import math

import numpy as np


def quat_to_rot(q):
    """Rotation matrix of a quaternion (x, y, z, w); it need not be normalised."""
    x, y, z, w = q
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rot_to_quat(r):
    """(x, y, z, w) of a rotation matrix, w >= 0."""
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0
    y = math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0
    z = math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0
    x = math.copysign(x, r[2, 1] - r[1, 2])
    y = math.copysign(y, r[0, 2] - r[2, 0])
    z = math.copysign(z, r[1, 0] - r[0, 1])
    return x, y, z, w


def umeyama(src, dst, with_scale=True):
    """(s, R, t) minimising sum |dst_i - (s R src_i + t)|^2 over corresponding rows
    (Umeyama 1991). With with_scale=False the fit is rigid (SE(3)) and s is 1.0.

    Raises ValueError with fewer than 3 pairs, rows of different counts, or (with scale)
    source points that all coincide."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape:
        raise ValueError("umeyama: %d source but %d destination positions" % (len(src), len(dst)))
    if len(src) < 3:
        raise ValueError("a similarity needs at least 3 corresponding positions, got %d" % len(src))
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    u, d, vt = np.linalg.svd(b.T @ a / len(src))
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    r = u @ sign @ vt
    s = 1.0
    if with_scale:
        var = (a * a).sum() / len(src)
        if var <= 0:
            raise ValueError("the source positions do not spread (all equal)")
        s = float(np.trace(np.diag(d) @ sign) / var)
    return s, r, mu_d - s * r @ mu_s


class Similarity:
    """x_dst = s R x_src + t (e.g. T_world_map: map coordinates into the world)."""

    def __init__(self, s=1.0, r=None, t=None):
        self.s = s
        self.r = np.eye(3) if r is None else r
        self.t = np.zeros(3) if t is None else t

    def apply(self, p):
        """The point p (3-vector) mapped; rows of an Nx3 array are mapped one by one."""
        p = np.asarray(p, dtype=float)
        if p.ndim == 1:
            return self.s * self.r @ p + self.t
        return self.s * p @ self.r.T + self.t

    def residuals(self, src, dst):
        """|dst_i - apply(src_i)| per row."""
        return np.linalg.norm(np.asarray(dst, float) - self.apply(src), axis=1)


def robust_similarity(src, dst, floor=0.1, factor=3.0):
    """A similarity fit that drops outliers by a second fit: rows whose residual after the
    first fit exceeds max(floor, factor * median residual) are left out.

    Returns (Similarity, keep: bool array over the rows, residuals of the kept rows after
    the second fit). Raises ValueError as umeyama does."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    first = Similarity(*umeyama(src, dst))
    residual = first.residuals(src, dst)
    keep = residual <= max(floor, factor * float(np.median(residual)))
    sim = Similarity(*umeyama(src[keep], dst[keep]))
    return sim, keep, sim.residuals(src[keep], dst[keep])
