"""A run's sums over its photons and their standard errors: :class:`Result`, what every estimator returns.

A row's standard error comes from its sums of per-photon products (N photons, N independent samples), or from its
sums per batch where the photons are not independent one by one (the control variate's sensor rows, the ``reuse``
and ``field`` estimators): :func:`effective_samples` says which.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kernel.tallies import C_BATCHES


@dataclass
class Result:
    """Sums over N traced photons.

    ``tally`` (K + M + 4, B): expected photon hits per row and band for the N
    photons emitted — rows: S sensors, R receiver incident, R receiver
    absorbed, then the fates: M materials (absorbed), escaped, cut at max
    depth, lost, and the per-photon total (closure: N in expectation);
    ``tally_prod`` (rows, B, B) the sums of products between bands of
    per-photon contributions (covariances: a sum of bands or a ratio of two
    gets an honest σ from :meth:`combination`) -- per batch of photons for the
    sensor rows of a run with the control variate (:func:`effective_samples`).
    """

    photons: int
    tally: np.ndarray
    tally_prod: np.ndarray
    counters: np.ndarray         # rays, candidate overflows, scratch flushes, lost, shadow rays
    seconds: float
    threads: int
    seed: int
    n_sensors: int
    n_receivers: int
    estimator: str = "weighted"
    materials: list = field(default_factory=list)   # names of the fate rows' materials
    nee_stats: np.ndarray | None = None   # (M + E + P, 3) rays cast, paths found, weight deposited (materials, lamp elements, mirror planes)
    partial: bool = False
    interrupted: bool = False     # stopped by KeyboardInterrupt (Ctrl-C), not by ``stop()``
    extra: dict = field(default_factory=dict)
    batches: int = 0              # > 0: every row's products are per batch, that many independent samples (reuse)

    @property
    def _fate0(self) -> int:
        return self.n_sensors + 2 * self.n_receivers

    @property
    def fate(self) -> np.ndarray:
        """(M + 3, B) weight absorbed per material, escaped, cut at max depth, lost."""
        return self.tally[self._fate0:-1]

    @property
    def fate_std(self) -> np.ndarray:
        return self.tally_std[self._fate0:-1]

    @property
    def closure(self):
        """(accounted, std): per band, the photons' total deposits (N in expectation), each (B,)."""
        return self.tally[-1], self.tally_std[-1]

    @property
    def samples(self) -> np.ndarray:
        """Independent samples behind each row's sums of products, (rows,): see :func:`effective_samples`."""
        if self.batches:
            return np.full(len(self.tally), float(self.batches))
        return effective_samples(self.photons, self.counters, len(self.tally), self.n_sensors)

    @property
    def tally_std(self) -> np.ndarray:
        """Standard error of each tally, (K, B)."""
        return standard_error(self.tally, self.tally_sq, self.photons, self.samples)

    @property
    def tally_sq(self) -> np.ndarray:
        """Sums of squared contributions, (rows, B): the diagonal of ``tally_prod``."""
        return np.diagonal(self.tally_prod, axis1=1, axis2=2)

    def covariance(self, rows) -> np.ndarray:
        """Covariance matrix between bands of the estimated totals of ``rows``, (len(rows), B, B)."""
        n = self.photons
        t = self.tally[rows]
        m = self.samples[rows][:, None, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(m >= 2, n / (m - 1.0), np.nan) * (self.tally_prod[rows] - t[:, :, None] * t[:, None, :] / n)

    def combination(self, rows, weights):
        """Σ_b weights[b] · tally[row, b] and its standard error (bands' covariances included), each (len(rows),)."""
        w = np.asarray(weights, dtype=float)
        t = self.tally[rows]
        value = np.zeros(len(t))
        for b, wb in enumerate(w):      # not t @ w: BLAS's rounding depends on the machine's kernel, this does not
            value += t[:, b] * wb
        var = np.einsum("b,rbc,c->r", w, self.covariance(rows), w)
        return value, np.sqrt(np.maximum(var, 0.0))

    def sensors(self):
        """(photons, photons_std) for the transparent sensors, each (S, B)."""
        s = self.n_sensors
        return self.tally[:s], self.tally_std[:s]

    def receivers_incident(self):
        s, r = self.n_sensors, self.n_receivers
        return self.tally[s:s + r], self.tally_std[s:s + r]

    def receivers_absorbed(self):
        s, r = self.n_sensors, self.n_receivers
        return self.tally[s + r:s + 2 * r], self.tally_std[s + r:s + 2 * r]

    @property
    def rays(self) -> int:
        return int(self.counters[0])


def effective_samples(n, counters, n_rows, n_sensors) -> np.ndarray:
    """Independent samples behind each tally row's sums of products, (n_rows,) float.

    Every row sums per-photon products, so N photons are N samples -- except the sensor rows of a
    ``nee`` run with the control variate, whose products are taken per batch of photons
    (:func:`lpy_light.kernel.control.control_products`): ``counters[C_BATCHES]`` samples there.
    """
    m = np.full(n_rows, float(n))
    batches = int(counters[C_BATCHES]) if len(counters) > C_BATCHES else 0
    if batches:
        m[:n_sensors] = batches
    return m


def standard_error(total, sq, n, samples):
    """Standard error of totals of n photons from their sums of squares, (rows, B); ``samples`` (rows,):
    N / (m − 1) · (Σ x² − T² / N) with m the row's independent samples (N, or its batches)."""
    m = np.asarray(samples, dtype=float).reshape(-1, *([1] * (np.ndim(total) - 1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.where(m >= 2, n / (m - 1.0), np.nan) * np.maximum(sq - total * total / max(n, 1), 0.0)
    return np.sqrt(var)


def relative_sigma(tally, tally_prod, n, rows, samples=None) -> np.ndarray:
    """σ / value of the given tally rows (all bands), for rows with a value > 0; shape (k,).
    ``samples`` (all rows,): :func:`effective_samples` (default: n for every row)."""
    t, sq = tally[rows], np.diagonal(tally_prod[rows], axis1=1, axis2=2)
    if n < 2:
        return np.full(t.size, np.inf)
    m = np.full(len(tally), float(n)) if samples is None else np.asarray(samples, dtype=float)
    std = standard_error(t, sq, n, m[rows])
    keep = t > 0
    with np.errstate(invalid="ignore"):
        rel = np.where(np.isfinite(std), std, np.inf)[keep] / t[keep]
    return rel.ravel()
