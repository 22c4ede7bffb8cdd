"""ARD-RBF plus white-noise Gaussian-process regression (lathe thesis Eqs 4.8-4.19).

scikit-learn's ``GaussianProcessRegressor`` (L-BFGS-B on the log marginal likelihood) on
standardised inputs and outputs; the predictive std *includes* the noise (Eq. 4.17), refits
warm-start from the previous hyperparameters, and a floor on the prior std lets an unseen
state always raise the std (docs/agp_cd.md). The GP of the AGP model and of its offset models.
No rclpy here.
"""
from __future__ import annotations

import math
import warnings
from typing import Any, Mapping

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel


class AgpConfigError(ValueError):
    """Bad AGP configuration or state; the message names the key and value."""


def _kernel(n_inputs: int, length_scale_bounds: tuple[float, float],
            noise_bounds: tuple[float, float], signal_var_lower: float = 1e-3):
    lower = min(max(float(signal_var_lower), 1e-3), 1.0)
    return (ConstantKernel(1.0, (lower, 1e3)) * RBF(np.ones(n_inputs), length_scale_bounds)
            + WhiteKernel(1e-2, noise_bounds))


class ArdGaussianProcess:
    """ARD-RBF + white-noise GP regression on standardised inputs and outputs.

    ``fit`` maximises the log marginal likelihood with L-BFGS-B (``n_restarts`` extra random
    starts); with ``warm_start`` the optimiser starts from the previous fit's hyperparameters.

    ``min_signal_std`` (output units, 0 = off) is a floor on the prior std of the latent
    function: outputs are scaled by max(std(y), min_signal_std) and the signal variance is
    bounded below accordingly. It encodes the prior belief that a state unlike all training
    states may carry an error of that size; without it a calibration that saw little error
    variation yields a prior std below sigma_max, and an unseen state could never trigger a
    recalibration (observed on the twin's lathe-random-speed, whose first hours are calm).

    ``max_optimize_points`` (0 = off): above this many points the hyperparameters are optimised
    on an even thinning of the data and the posterior is then computed on all of it - the
    gradient of scikit-learn's likelihood costs O(N^2 x hyperparameters) memory and O(N^3) time
    per evaluation, and the optimum hardly moves with N.
    """

    def __init__(self, *, length_scale_bounds: tuple[float, float] = (1e-2, 1e2),
                 noise_bounds: tuple[float, float] = (1e-6, 1.0), n_restarts: int = 0,
                 min_input_scale: float = 0.05, min_signal_std: float = 0.0,
                 max_optimize_points: int = 0, seed: int = 0):
        self.length_scale_bounds = tuple(float(v) for v in length_scale_bounds)
        self.noise_bounds = tuple(float(v) for v in noise_bounds)
        self.n_restarts = int(n_restarts)
        self.min_input_scale = float(min_input_scale)
        self.min_signal_std = float(min_signal_std)
        self.max_optimize_points = int(max_optimize_points)
        self.seed = int(seed)
        self.gpr: GaussianProcessRegressor | None = None
        self.x_mean: np.ndarray | None = None
        self.x_scale: np.ndarray | None = None
        self.y_mean = 0.0
        self.y_scale = 1.0
        self.optimizer_warnings = 0

    @property
    def fitted(self) -> bool:
        return self.gpr is not None

    def _scale(self, x: np.ndarray) -> np.ndarray:
        return (x - self.x_mean) / self.x_scale

    def fit(self, x, y, *, warm_start: bool = True, optimize: bool = True) -> "ArdGaussianProcess":
        """Fit on (x, y). ``optimize=False`` keeps the hyperparameters and scalings of the last
        fit and only conditions on the data (cheap update after a control measurement)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float).ravel()
        if x.ndim != 2 or x.shape[0] != y.shape[0]:
            raise AgpConfigError(f"GP fit: x has shape {x.shape}, y has {y.shape[0]} values")
        if x.shape[0] < 2:
            raise AgpConfigError(f"GP fit: needs >= 2 training points, got {x.shape[0]}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise AgpConfigError("GP fit: training inputs/outputs contain NaN or inf")
        previous = self.gpr.kernel_ if (self.gpr is not None
                                        and self.gpr.kernel_.k1.k2.length_scale.size == x.shape[1]) else None
        if optimize or previous is None:
            self.x_mean = x.mean(axis=0)
            self.x_scale = np.maximum(x.std(axis=0), self.min_input_scale)
            self.y_mean = float(y.mean())
            self.y_scale = max(float(y.std()), self.min_signal_std, 1e-9)
        lower = (self.min_signal_std / self.y_scale) ** 2 if self.min_signal_std > 0 else 1e-3
        kernel = _kernel(x.shape[1], self.length_scale_bounds, self.noise_bounds, lower)
        if previous is not None and (warm_start or not optimize):
            theta = previous.theta.copy()
            b = kernel.bounds
            kernel.theta = np.clip(theta, b[:, 0], b[:, 1])
        xs, ys = self._scale(x), (y - self.y_mean) / self.y_scale
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            if optimize and self.max_optimize_points and x.shape[0] > self.max_optimize_points:
                # hyperparameters from an even thinning of the history (the likelihood surface
                # is flat in N: its optimum moves little), then the exact posterior on all points
                sub = np.unique(np.linspace(0, x.shape[0] - 1, self.max_optimize_points).round().astype(int))
                opt = GaussianProcessRegressor(kernel=kernel, normalize_y=False, optimizer="fmin_l_bfgs_b",
                                               n_restarts_optimizer=self.n_restarts, random_state=self.seed)
                opt.fit(xs[sub], ys[sub])
                kernel, optimize = opt.kernel_, False
            gpr = GaussianProcessRegressor(kernel=kernel, normalize_y=False,
                                           optimizer="fmin_l_bfgs_b" if optimize else None,
                                           n_restarts_optimizer=self.n_restarts if optimize else 0,
                                           random_state=self.seed)
            gpr.fit(xs, ys)
        self.optimizer_warnings += sum(issubclass(w.category, ConvergenceWarning) for w in caught)
        self.gpr = gpr
        return self

    def predict(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Mean and predictive std (including noise, thesis Eq. 4.17) in output units."""
        if self.gpr is None:
            raise AgpConfigError("GP is not fitted")
        x = np.atleast_2d(np.asarray(x, dtype=float))
        mean, std = self.gpr.predict(self._scale(x), return_std=True)
        return (np.asarray(mean, dtype=float) * self.y_scale + self.y_mean,
                np.asarray(std, dtype=float) * self.y_scale)

    @property
    def noise_std(self) -> float:
        """Fitted white-noise std in output units."""
        if self.gpr is None:
            return math.nan
        return float(math.sqrt(self.gpr.kernel_.k2.noise_level) * self.y_scale)

    @property
    def prior_std(self) -> float:
        """Predictive std far from all training data (signal and noise) in output units."""
        if self.gpr is None:
            return math.nan
        k = self.gpr.kernel_
        return float(math.sqrt(k.k1.k1.constant_value + k.k2.noise_level) * self.y_scale)

    @property
    def length_scales(self) -> np.ndarray:
        """ARD length scales in standardised input units (relevance = 1 / length scale)."""
        if self.gpr is None:
            raise AgpConfigError("GP is not fitted")
        return np.atleast_1d(np.asarray(self.gpr.kernel_.k1.k2.length_scale, dtype=float))

    @property
    def log_marginal_likelihood(self) -> float:
        return float(self.gpr.log_marginal_likelihood_value_) if self.gpr is not None else math.nan

    def to_state(self) -> dict:
        base = {"length_scale_bounds": list(self.length_scale_bounds), "noise_bounds": list(self.noise_bounds),
                "n_restarts": self.n_restarts, "min_input_scale": self.min_input_scale,
                "min_signal_std": self.min_signal_std, "max_optimize_points": self.max_optimize_points,
                "seed": self.seed}
        if self.gpr is None:
            return {"fitted": False, **base}
        x_train = self.gpr.X_train_ * self.x_scale + self.x_mean
        y_train = np.asarray(self.gpr.y_train_).ravel() * self.y_scale + self.y_mean
        return {"fitted": True, **base, "theta": self.gpr.kernel_.theta.tolist(),
                "x_mean": self.x_mean.tolist(), "x_scale": self.x_scale.tolist(),
                "y_mean": self.y_mean, "y_scale": self.y_scale,
                "x_train": x_train.tolist(), "y_train": y_train.tolist()}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "ArdGaussianProcess":
        try:
            gp = cls(length_scale_bounds=tuple(state["length_scale_bounds"]),
                     noise_bounds=tuple(state["noise_bounds"]), n_restarts=int(state["n_restarts"]),
                     min_input_scale=float(state["min_input_scale"]),
                     min_signal_std=float(state["min_signal_std"]),
                     max_optimize_points=int(state.get("max_optimize_points", 0)), seed=int(state["seed"]))
            if not state.get("fitted", False):
                return gp
            x = np.asarray(state["x_train"], dtype=float)
            y = np.asarray(state["y_train"], dtype=float)
            gp.x_mean = np.asarray(state["x_mean"], dtype=float)
            gp.x_scale = np.asarray(state["x_scale"], dtype=float)
            gp.y_mean, gp.y_scale = float(state["y_mean"]), float(state["y_scale"])
            kernel = _kernel(x.shape[1], gp.length_scale_bounds, gp.noise_bounds, 1e-3)
            kernel.theta = np.asarray(state["theta"], dtype=float)
        except KeyError as exc:
            raise AgpConfigError(f"GP state: missing key {exc}") from None
        gp.gpr = GaussianProcessRegressor(kernel=kernel, normalize_y=False, optimizer=None)
        gp.gpr.fit(gp._scale(x), (y - gp.y_mean) / gp.y_scale)
        return gp
