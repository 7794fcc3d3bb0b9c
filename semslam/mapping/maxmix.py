"""Max-mixture factors with a null hypothesis (Olson & Agarwal, RSS 2012).

A measurement with components i = 1..K, each Gaussian with residual
``r_i(x)``, covariance ``Sigma_i`` and prior weight ``w_i``, has the
max-mixture negative log-likelihood (up to a constant)

    min_i  [ -log w_i + 1/2 log det Sigma_i + 1/2 chi2_i(x) ],   chi2_i = r_i' Sigma_i^-1 r_i.

Each component's constant ``c_i = -log w_i + 1/2 log det Sigma_i`` is
counted exactly once (log det, not det; no second normaliser through gtsam:
the factors here use unit noise models and whiten themselves). The factor's
error is made continuous across a switch of component by appending one row
``sqrt(2 (c_k - c_min))`` to the chosen component's whitened residual, so
``1/2 |e|^2 = min_i (1/2 chi2_i + c_i) - c_min``: Levenberg-Marquardt's
accept test sees the true cost. The Jacobian is the chosen component's
(zero on the appended row and on keys the chosen component does not use).

A null-only mixture (the measurement or "it is an outlier") needs no custom
factor: :func:`null_hypothesis_noise` is a robust loss for gtsam's native
factors with exactly this cost.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from semslam.geometry import FloatArray

# residual(values, want_jacobians) -> (r (d,), {key: J (d, dim(key))} or None)
ResidualFunction = Callable[[gtsam.Values, bool], tuple[FloatArray, dict[int, FloatArray] | None]]


def component_constants(
    weights: Sequence[float], log_det_covariances: Sequence[float]
) -> FloatArray:
    """``c_i - min_j c_j`` with ``c_i = -log w_i + 1/2 log det Sigma_i``."""
    c = -np.log(np.asarray(weights, dtype=float)) + 0.5 * np.asarray(
        log_det_covariances, dtype=float
    )
    return c - c.min()


def choose_component(chi2: Sequence[float], constants: Sequence[float]) -> int:
    """Index of the component with the least ``1/2 chi2_i + c_i``."""
    return int(np.argmin(0.5 * np.asarray(chi2, dtype=float) + np.asarray(constants, dtype=float)))


def mixture_cost(chi2: Sequence[float], constants: Sequence[float]) -> float:
    """``min_i (1/2 chi2_i + c_i)``: the max-mixture cost (with ``min c = 0``)."""
    return float(np.min(0.5 * np.asarray(chi2, dtype=float) + np.asarray(constants, dtype=float)))


# --------------------------------------------------------------------------- null-only mixture


@dataclass(frozen=True)
class NullHypothesis:
    """The outlier component of a two-component mixture.

    Attributes:
        weight: prior probability that the measurement is an outlier (w0); the
            measurement's own component has weight 1 - w0.
        information_scale: the null component's information is the
            measurement's times this (its covariance is the measurement's over it).
    """

    weight: float = 0.01
    information_scale: float = 1e-6

    def switch_chi2(self, dim: int) -> float:
        """Chi-square above which the null component wins, for a ``dim``-dimensional residual."""
        return 2.0 * self.offset(dim) / (1.0 - self.information_scale)

    def offset(self, dim: int) -> float:
        """``c_null - c_measurement`` = log(w1 / w0) - dim/2 log(information_scale)."""
        return math.log((1.0 - self.weight) / self.weight) - 0.5 * dim * math.log(
            self.information_scale
        )


def null_hypothesis_loss(
    null: NullHypothesis, dim: int
) -> tuple[Callable[[float], float], Callable[[float], float]]:
    """(weight, loss) functions of the whitened residual norm ``r`` for a null-only mixture.

    ``loss(r) = min(r^2 / 2, s r^2 / 2 + offset)`` (continuous, zero at zero); its IRLS
    weight ``loss'(r) / r`` is 1 on the measurement's side and ``s`` on the null side.
    """
    s = null.information_scale
    offset = null.offset(dim)

    def loss(r: float) -> float:
        return min(0.5 * r * r, 0.5 * s * r * r + offset)

    def weight(r: float) -> float:
        return 1.0 if 0.5 * r * r <= 0.5 * s * r * r + offset else s

    return weight, loss


def null_hypothesis_noise(covariance: FloatArray, null: NullHypothesis) -> gtsam.noiseModel.Robust:
    """A gtsam robust noise model whose loss is the max-mixture of the measurement's Gaussian
    with ``covariance`` and the null hypothesis ``null`` (use on any native factor)."""
    dim = covariance.shape[0]
    weight, loss = null_hypothesis_loss(null, dim)
    estimator = gtsam.noiseModel.mEstimator.Custom(
        weight, loss, gtsam.noiseModel.mEstimator.Base.ReweightScheme.Block, "maxmix-null"
    )
    return gtsam.noiseModel.Robust.Create(
        estimator, gtsam.noiseModel.Gaussian.Covariance(covariance)
    )


def is_null_chosen(
    factor: gtsam.NonlinearFactor, values: gtsam.Values, null: NullHypothesis
) -> bool:
    """Whether a factor with :func:`null_hypothesis_noise` sits on its null component."""
    base = factor.noiseModel().noise()  # the Gaussian inside the robust model
    whitened = base.whiten(factor.unwhitenedError(values))
    chi2 = float(whitened @ whitened)
    return chi2 > null.switch_chi2(len(whitened))


# --------------------------------------------------------------------------- general mixture


@dataclass(frozen=True)
class Component:
    """One hypothesis of a max-mixture factor.

    Attributes:
        residual: function of the values giving the residual (d,) and, when asked,
            its Jacobian per key it depends on.
        sqrt_information: (d, d) matrix R with Sigma^-1 = R' R.
        weight: prior probability of this hypothesis.
    """

    residual: ResidualFunction
    sqrt_information: FloatArray
    weight: float

    @property
    def log_det_covariance(self) -> float:
        return -2.0 * float(np.sum(np.log(np.abs(np.diag(np.linalg.qr(self.sqrt_information)[1])))))


class MaxMixture:
    """The error function of a max-mixture over components of equal residual dimension.

    ``keys`` are all keys any component uses, ``key_dims`` their tangent
    dimensions. Call :meth:`factor` for the gtsam factor; :meth:`chosen` tells
    which component is active at given values (for the association audit).
    """

    def __init__(
        self, keys: Sequence[int], key_dims: Sequence[int], components: Sequence[Component]
    ) -> None:
        dims = {c.sqrt_information.shape[0] for c in components}
        if len(dims) != 1:
            raise ValueError("max-mixture components need residuals of one dimension")
        self.keys = list(keys)
        self.key_dims = dict(zip(keys, key_dims, strict=True))
        self.components = list(components)
        self.dim = dims.pop()
        self.constants = component_constants(
            [c.weight for c in components], [c.log_det_covariance for c in components]
        )

    def evaluate(self, values: gtsam.Values, want_jacobians: bool):
        """(chosen index, error (d+1,), Jacobians per key or None)."""
        best = None
        for i, comp in enumerate(self.components):
            r, J = comp.residual(values, want_jacobians)
            w = comp.sqrt_information @ r
            cost = 0.5 * float(w @ w) + self.constants[i]
            if best is None or cost < best[0]:
                best = (cost, i, w, J)
        assert best is not None
        _, i, w, J = best
        error = np.append(w, math.sqrt(2.0 * self.constants[i]))
        if not want_jacobians:
            return i, error, None
        R = self.components[i].sqrt_information
        H = {}
        for key in self.keys:
            block = np.zeros((self.dim + 1, self.key_dims[key]))
            if J is not None and key in J:
                block[: self.dim] = R @ J[key]
            H[key] = block
        return i, error, H

    def chosen(self, values: gtsam.Values) -> int:
        return self.evaluate(values, False)[0]

    def factor(self) -> gtsam.CustomFactor:
        def error_function(this: gtsam.CustomFactor, values: gtsam.Values, H) -> FloatArray:
            _, error, jac = self.evaluate(values, H is not None)
            if H is not None and jac is not None:
                for n, key in enumerate(self.keys):
                    H[n] = jac[key]
            return error

        return gtsam.CustomFactor(
            gtsam.noiseModel.Unit.Create(self.dim + 1), self.keys, error_function
        )
