"""SE(2) helpers on plain numpy arrays.

A pose is a length-3 array ``(x, y, yaw)``: metres, metres, radians,
yaw counter-clockwise from +x and wrapped to (-pi, pi]. ``mTv`` is the pose
of frame v expressed in frame m; ``vP`` is a point (or an (N, 2) array of
points) in frame v. Composition follows the usual rule ``mTw = mTv * vTw``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(angle: ArrayLike) -> FloatArray | float:
    """Wrap angles (radians) to (-pi, pi]; scalars stay scalars."""
    # an angle an ulp above pi rounds the modulo up to 2 pi, hence the check for -pi
    if isinstance(angle, float):  # the filter's hot path: the same arithmetic, no array
        wrapped = math.pi - (math.pi - float(angle)) % (2.0 * math.pi)
        return wrapped if wrapped > -math.pi else math.pi
    a = np.asarray(angle, dtype=float)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    wrapped = np.where(wrapped > -np.pi, wrapped, np.pi)
    if wrapped.ndim == 0:
        return float(wrapped)
    return wrapped


def pose(x: float, y: float, yaw: float) -> FloatArray:
    """A pose array ``(x, y, yaw)`` with yaw wrapped."""
    return np.array([x, y, wrap_angle(yaw)], dtype=float)


def rotation(yaw: float) -> FloatArray:
    """2x2 rotation matrix for ``yaw`` radians."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def rotate_pose_covariance(covariance: ArrayLike, yaw: float) -> FloatArray:
    """A (3, 3) pose covariance ``(x, y, yaw)`` with its position axes turned by ``yaw``:
    ``J C J^T``, ``J = blockdiag(R(yaw), 1)``.

    ``yaw`` = a pose's own yaw turns a covariance given along that pose's axes (gtsam's and
    g2o's tangent space of a ``Pose2``) into its parent's; ``-yaw`` the other way. A relative
    pose ``aTb`` measured with covariance ``C`` in a's axes is what gtsam's ``BetweenFactor``
    and g2o's ``EDGE_SE2`` compare in b's axes: their noise is ``rotate_pose_covariance(C,
    -aTb.yaw)``.
    """
    J = np.eye(3)
    J[:2, :2] = rotation(yaw)
    C = J @ np.asarray(covariance, dtype=float) @ J.T
    return 0.5 * (C + C.T)


def compose(aTb: ArrayLike, bTc: ArrayLike) -> FloatArray:
    """``aTc = aTb * bTc`` for poses ``(x, y, yaw)``."""
    ax, ay, ayaw = np.asarray(aTb, dtype=float)
    bx, by, byaw = np.asarray(bTc, dtype=float)
    c, s = math.cos(ayaw), math.sin(ayaw)
    return np.array([ax + c * bx - s * by, ay + s * bx + c * by, wrap_angle(ayaw + byaw)])


def inverse(aTb: ArrayLike) -> FloatArray:
    """``bTa`` from ``aTb``."""
    x, y, yaw = np.asarray(aTb, dtype=float)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([-c * x - s * y, s * x - c * y, wrap_angle(-yaw)])


def between(aTb: ArrayLike, aTc: ArrayLike) -> FloatArray:
    """``bTc = inverse(aTb) * aTc``: the relative pose of c seen from b."""
    return compose(inverse(aTb), aTc)


def transform_points(aTb: ArrayLike, bP: ArrayLike) -> FloatArray:
    """Points from frame b to frame a: ``aP = aTb * bP``; ``bP`` is (2,) or (N, 2)."""
    x, y, yaw = np.asarray(aTb, dtype=float)
    pts = np.asarray(bP, dtype=float)
    return pts @ rotation(yaw).T + np.array([x, y])


def inverse_transform_points(aTb: ArrayLike, aP: ArrayLike) -> FloatArray:
    """Points from frame a to frame b: ``bP = inverse(aTb) * aP``; (2,) or (N, 2)."""
    x, y, yaw = np.asarray(aTb, dtype=float)
    pts = np.asarray(aP, dtype=float)
    return (pts - np.array([x, y])) @ rotation(yaw)


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(qx, qy, qz, qw)`` of a rotation by ``yaw`` about +z."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def quaternion_to_yaw(qx: float, qy: float, qz: float, qw: float) -> float:
    """Yaw (rotation about +z, radians) of a quaternion of any length; roll and pitch are
    ignored."""
    cos_part = qw * qw + qx * qx - qy * qy - qz * qz  # 1 - 2 (y^2 + z^2) for a unit quaternion
    return float(wrap_angle(math.atan2(2.0 * (qw * qz + qx * qy), cos_part)))


def clip_segment(a: ArrayLike, b: ArrayLike, lo: float, hi: float):
    """Liang-Barsky clip of the segment a-b (2,) to the square [lo, hi]^2.

    Returns the clipped end points ``(a', b')`` or None when the segment misses it.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    d = b - a
    t0, t1 = 0.0, 1.0
    for k in range(2):
        for p, q in ((-d[k], a[k] - lo), (d[k], hi - a[k])):
            if abs(p) < 1e-12:
                if q < 0:
                    return None
                continue
            t = q / p
            if p < 0:
                t0 = max(t0, t)
            else:
                t1 = min(t1, t)
            if t0 > t1:
                return None
    return a + d * t0, a + d * t1


def clip_segments(
    a: FloatArray, b: FloatArray, lo: float, hi: float
) -> tuple[FloatArray, np.ndarray]:
    """:func:`clip_segment` of many segments at once: the clipped end
    points (K, 2, 2) and which segments meet the square [lo, hi]^2 (K,)."""
    d = b - a
    t0, t1 = np.zeros(len(a)), np.ones(len(a))
    keep = np.ones(len(a), dtype=bool)
    for k in range(2):
        for p, q in ((-d[:, k], a[:, k] - lo), (d[:, k], hi - a[:, k])):
            flat = np.abs(p) < 1e-12
            keep &= ~(flat & (q < 0))
            t = q / np.where(flat, 1.0, p)
            t0 = np.where(~flat & (p < 0), np.maximum(t0, t), t0)
            t1 = np.where(~flat & (p > 0), np.minimum(t1, t), t1)
    keep &= t0 <= t1
    return np.stack([a + d * t0[:, None], a + d * t1[:, None]], axis=1), keep


def segment_pieces(
    a: FloatArray, ab: FloatArray, piece: float
) -> tuple[FloatArray, NDArray[np.intp]]:
    """The middles (M, 2) of segments ``a[k]``, ``a[k] + ab[k]`` (K, 2 each) cut into equal
    pieces at most ``piece`` long (one piece for a point), and the segment of each (M,). A
    KD-tree over the middles finds every segment that comes within ``r`` of a point among
    the pieces whose middle lies within ``r + piece / 2`` of it."""
    count = np.maximum(1, np.ceil(np.hypot(ab[:, 0], ab[:, 1]) / piece)).astype(np.intp)
    owner = np.repeat(np.arange(len(a)), count)
    first = np.cumsum(count) - count
    share = (np.arange(len(owner)) - first[owner] + 0.5) / count[owner]
    return a[owner] + share[:, None] * ab[owner], owner


def rotation_variance(points: ArrayLike, covariance: ArrayLike) -> float:
    """Variance (rad^2) of the rotation of a rigid set of 2D ``points`` (N, 2) about their
    centroid, fitted by least squares to the points, from the points' joint covariance
    ``covariance`` (2N, 2N; or (N, 2, 2) per point, taken as independent), m^2.

    A small rotation ``d`` moves point ``i`` by ``d * (-a_iy, a_ix)`` (``a = p - centroid``),
    so the least-squares rotation of displacements ``e`` is ``g . e`` with
    ``g_i = (-a_iy, a_ix) / sum |a|^2``, and its variance is ``g^T C g``."""
    P = np.asarray(points, dtype=float).reshape(-1, 2)
    C = np.asarray(covariance, dtype=float)
    if C.ndim == 3:
        blocks, C = C, np.zeros((2 * len(P), 2 * len(P)))
        for i, block in enumerate(blocks):
            C[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = block
    a = P - P.mean(axis=0)
    spread = float(np.sum(a**2))
    if spread <= 0 or C.shape != (2 * len(P), 2 * len(P)):
        raise ValueError(f"rotation_variance: {len(P)} distinct points with a "
                         f"{2 * len(P)} x {2 * len(P)} covariance needed, got {C.shape}")
    g = np.column_stack([-a[:, 1], a[:, 0]]).ravel() / spread
    return float(g @ C @ g)
