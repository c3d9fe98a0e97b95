"""CMA-ES, ask/tell, in numpy: the local search of refinement when ``RefineConfig.method == "cmaes"``.

The standard (μ/μ_w, λ)-CMA-ES (Hansen, "The CMA Evolution Strategy: A Tutorial", 2016): weighted recombination of
the best half, cumulative step-size adaptation and rank-one + rank-μ covariance updates, eigendecomposition every
generation (21 dimensions: microseconds). Box bounds are handled by repair: samples are clipped to the bounds and the
clipped points are what ``tell`` learns from. Pure compute, no rendering: the refiner scores what ``ask`` proposes.
"""

from __future__ import annotations

import math

import numpy as np


class CMAES:
    """Minimiser over ``lower ≤ x ≤ upper`` started at ``mean (n,)`` with step ``sigma``; ``ask() → (λ, n)``,
    ``tell(x (λ, n), f (λ,))``. ``popsize`` defaults to ``4 + ⌊3 ln n⌋``."""

    def __init__(
        self,
        mean: np.ndarray,
        sigma: float,
        lower: np.ndarray,
        upper: np.ndarray,
        popsize: int | None = None,
        rng: np.random.Generator | None = None,
    ):
        self.mean = np.clip(np.asarray(mean, dtype=np.float64), lower, upper)
        self.n = n = len(self.mean)
        if sigma <= 0:
            raise ValueError(f"CMA-ES sigma must be > 0, got {sigma}")
        self.sigma = float(sigma)
        self.lower, self.upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
        self.lam = lam = int(popsize or 4 + math.floor(3 * math.log(n)))
        if lam < 2:
            raise ValueError(f"CMA-ES population must be ≥ 2, got {lam}")
        self.rng = rng or np.random.default_rng()
        self.mu = mu = lam // 2
        w = math.log(mu + 0.5) - np.log(np.arange(1, mu + 1))
        self.weights = w / w.sum()  # (μ,) recombination weights
        self.mueff = mueff = 1.0 / float((self.weights**2).sum())
        self.cc = (4 + mueff / n) / (n + 4 + 2 * mueff / n)
        self.cs = (mueff + 2) / (n + mueff + 5)
        self.c1 = 2 / ((n + 1.3) ** 2 + mueff)
        self.cmu = min(1 - self.c1, 2 * (mueff - 2 + 1 / mueff) / ((n + 2) ** 2 + mueff))
        self.damps = 1 + 2 * max(0.0, math.sqrt((mueff - 1) / (n + 1)) - 1) + self.cs
        self.chi_n = math.sqrt(n) * (1 - 1 / (4 * n) + 1 / (21 * n * n))
        self.C = np.eye(n)  # covariance
        self.B = np.eye(n)  # its eigenvectors (columns)
        self.D = np.ones(n)  # the square roots of its eigenvalues
        self.pc = np.zeros(n)  # evolution path of C
        self.ps = np.zeros(n)  # evolution path of sigma
        self.generation = 0

    def ask(self) -> np.ndarray:
        """``λ`` candidates ``(λ, n)``, clipped to the bounds."""
        z = self.rng.standard_normal((self.lam, self.n))
        x = self.mean + self.sigma * (z * self.D) @ self.B.T
        return np.clip(x, self.lower, self.upper)

    def tell(self, x: np.ndarray, f: np.ndarray) -> None:
        """Update from candidates ``x (λ, n)`` and their losses ``f (λ,)`` (lower is better; finite)."""
        n, cs, cc = self.n, self.cs, self.cc
        best = np.argsort(np.asarray(f), kind="stable")[: self.mu]
        y = (np.asarray(x)[best] - self.mean) / self.sigma  # (μ, n) selected steps
        y_w = self.weights @ y
        self.mean = np.clip(self.mean + self.sigma * y_w, self.lower, self.upper)
        c_inv_half_y = self.B @ ((self.B.T @ y_w) / self.D)
        self.ps = (1 - cs) * self.ps + math.sqrt(cs * (2 - cs) * self.mueff) * c_inv_half_y
        self.generation += 1
        ps_norm = float(np.linalg.norm(self.ps))
        hsig = ps_norm / math.sqrt(1 - (1 - cs) ** (2 * self.generation)) / self.chi_n < 1.4 + 2 / (n + 1)
        self.pc = (1 - cc) * self.pc + hsig * math.sqrt(cc * (2 - cc) * self.mueff) * y_w
        rank_mu = (y * self.weights[:, None]).T @ y
        self.C = (
            (1 - self.c1 - self.cmu) * self.C
            + self.c1 * (np.outer(self.pc, self.pc) + (1 - hsig) * cc * (2 - cc) * self.C)
            + self.cmu * rank_mu
        )
        self.sigma *= math.exp((cs / self.damps) * (ps_norm / self.chi_n - 1))
        self.C = (self.C + self.C.T) / 2
        d2, self.B = np.linalg.eigh(self.C)
        self.D = np.sqrt(np.maximum(d2, 1e-20))
