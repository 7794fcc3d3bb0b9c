"""Chi-square quantiles for the gates, without importing ``scipy.stats``.

``scipy.stats`` takes 1-2 s to import on a slow machine, and every ``semslam map`` and
``semslam localize`` gates with a few chi-square quantiles; ``scipy.special`` (loaded
anyway by ``scipy.spatial``) has the inverse survival function itself.
"""

from __future__ import annotations

from scipy.special import chdtri


def chi2_quantile(probability: float, dof: int) -> float:
    """The value a chi-square variable with ``dof`` degrees of freedom stays below with
    ``probability`` (``scipy.stats.chi2.ppf(probability, dof)``)."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {probability!r}")
    return float(chdtri(dof, 1.0 - probability))
