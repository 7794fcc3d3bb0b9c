"""How uncertain a map line is across itself, at each point along it.

A mapped line's error is a shift and a turn: its offset across itself at the point a share
``lam`` of the way from end ``a`` to end ``b`` is ``e(lam) = (1 - lam) e_a + lam e_b``, with
``e_a``, ``e_b`` the offsets at its ends. The (2, 2) covariance of ``(e_a, e_b)`` (m^2; a
map's ``Marking.across_covariance``) therefore gives the variance anywhere on it:
``(1 - lam)^2 C_aa + 2 lam (1 - lam) C_ab + lam^2 C_bb``. A 250 m aisle line whose map is
sure of it at one end and drifts at the other is sure where it is sure, not on average.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from semslam.geometry import FloatArray
from semslam.types import Marking


def end_covariances(markings: Sequence[Marking]) -> FloatArray:
    """(M, 2, 2) covariances of the offsets at each line's ends, m^2: its
    ``across_covariance``; else ``sigma`` squared at both ends, fully correlated (the same
    everywhere along it); else zeros (nothing known)."""
    out = np.zeros((len(markings), 2, 2))
    for i, m in enumerate(markings):
        if m.across_covariance is not None:
            out[i] = m.across_covariance
        elif m.sigma is not None and np.isfinite(m.sigma):
            out[i] = m.sigma**2
    return out


def across_variance(end_cov: FloatArray, lam: FloatArray) -> FloatArray:
    """Variance across the line (m^2) at shares ``lam`` of the way from ``a`` to ``b``
    (clipped to the segment), given each line's ``end_cov`` (..., 2, 2) broadcast against
    ``lam`` (...)."""
    t = np.clip(np.asarray(lam, dtype=float), 0.0, 1.0)
    c = np.asarray(end_cov, dtype=float)
    u = 1.0 - t
    return np.maximum(u * u * c[..., 0, 0] + 2.0 * t * u * c[..., 0, 1] + t * t * c[..., 1, 1], 0.0)
