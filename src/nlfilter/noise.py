"""Noise laws for *simulation*. Filters see only the moments (``mean``, ``cov``) they need;
the grid and particle references also use ``logpdf``.

Three kinds:

* :class:`Gaussian` — zero-mean (or given-mean) normal with covariance ``cov``;
* :class:`Independent` — independent components, each a frozen ``scipy.stats`` distribution
  (uniform, Laplace, a mixture made by the user ...);
* :class:`Sampler` — any user function ``sample(rng, shape) -> (*shape, d)`` with its moments.
"""

from __future__ import annotations

import numpy as np

from . import _validate as V
from .streams import PathRNG, as_paths


class NoiseLaw:
    """Base class: ``dim``, ``mean`` (d,), ``cov`` (d, d), ``sample(rng, shape)``, ``logpdf(z)``."""

    dim: int
    mean: np.ndarray
    cov: np.ndarray

    def sample(self, rng: np.random.Generator, shape=()) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def logpdf(self, z: np.ndarray) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__}: has no density (logpdf); "
                                  "give a law with a density to use the grid or particle reference")

    @property
    def has_density(self) -> bool:
        return type(self).logpdf is not NoiseLaw.logpdf


class Gaussian(NoiseLaw):
    """Normal law N(mean, cov). ``cov`` may be singular (then ``logpdf`` is unavailable)."""

    def __init__(self, cov, mean=None):
        self.cov = V.covariance("cov", cov)
        self.dim = self.cov.shape[0]
        self.mean = np.zeros(self.dim) if mean is None else V.as_float_array("mean", mean, shape_tail=(self.dim,))
        w, U = np.linalg.eigh(self.cov)
        self._sqrt = U * np.sqrt(np.clip(w, 0.0, None))  # cov = S S^T
        self._singular = bool(np.min(w) <= 1e-14 * max(1.0, np.max(w)))
        if not self._singular:
            self._chol = np.linalg.cholesky(self.cov)
            self._chol_inv = np.linalg.inv(self._chol)
            self._logdet = 2.0 * np.sum(np.log(np.diag(self._chol)))

    def sample(self, rng, shape=()):
        shape = tuple(np.atleast_1d(shape)) if np.ndim(shape) else ((shape,) if shape != () else ())
        z = rng.standard_normal((*shape, self.dim))
        return self.mean + z @ self._sqrt.T

    @property
    def has_density(self) -> bool:
        """False when ``cov`` is singular (no density with respect to Lebesgue measure)."""
        return not self._singular

    def logpdf(self, z):
        if self._singular:
            raise ValueError("cov: singular Gaussian has no density")
        d = np.asarray(z) - self.mean
        sol = d @ self._chol_inv.T if self.dim > 1 else d / self._chol[0, 0]  # L⁻¹ d
        return -0.5 * np.sum(sol**2, axis=-1) - 0.5 * self._logdet - 0.5 * self.dim * np.log(2 * np.pi)

    def __repr__(self):
        return f"Gaussian(cov={self.cov.tolist()})"


class Independent(NoiseLaw):
    """Independent components, each a frozen ``scipy.stats`` distribution (continuous)."""

    def __init__(self, *dists):
        if len(dists) == 1 and isinstance(dists[0], (list, tuple)):
            dists = tuple(dists[0])
        if not dists:
            raise ValueError("dists: expected at least one frozen scipy.stats distribution, got none")
        for i, d in enumerate(dists):
            if not all(hasattr(d, a) for a in ("rvs", "mean", "var", "logpdf")):
                raise TypeError(f"dists[{i}]: expected a frozen scipy.stats distribution, got {type(d).__name__}")
        self.dists = dists
        self.dim = len(dists)
        self.mean = np.array([float(d.mean()) for d in dists])
        self.cov = np.diag([float(d.var()) for d in dists])
        V.finite("dists (their variances)", self.cov)

    def sample(self, rng, shape=()):
        shape = tuple(np.atleast_1d(shape)) if np.ndim(shape) else ((shape,) if shape != () else ())
        return np.stack([d.rvs(size=shape, random_state=rng) for d in self.dists], axis=-1)

    def logpdf(self, z):
        z = np.asarray(z)
        return sum(d.logpdf(z[..., i]) for i, d in enumerate(self.dists))

    def __repr__(self):
        return f"Independent({', '.join(d.dist.name for d in self.dists)})"


class Sampler(NoiseLaw):
    """A user sampler ``sample(rng, shape) -> (*shape, dim)`` with its mean and covariance
    (and optionally a ``logpdf(z)`` for the references)."""

    def __init__(self, sample, mean, cov, logpdf=None):
        if not callable(sample):
            raise TypeError(f"sample: expected a callable sample(rng, shape), got {type(sample).__name__}")
        self.cov = V.covariance("cov", cov)
        self.dim = self.cov.shape[0]
        self.mean = V.as_float_array("mean", mean, shape_tail=(self.dim,)).reshape(self.dim)
        self._sample = sample
        self._logpdf = logpdf

    def sample(self, rng, shape=()):
        shape = tuple(np.atleast_1d(shape)) if np.ndim(shape) else ((shape,) if shape != () else ())
        z = np.asarray(self._sample(rng, shape), dtype=float)
        if z.shape != (*shape, self.dim):
            raise ValueError(f"sample: expected the user sampler to return shape {(*shape, self.dim)}, got {z.shape}")
        return z

    @property
    def has_density(self):
        return self._logpdf is not None

    def logpdf(self, z):
        if self._logpdf is None:
            return super().logpdf(z)
        return np.asarray(self._logpdf(np.asarray(z)), dtype=float)


def as_law(name: str, law, cov) -> NoiseLaw:
    """The law used to simulate a noise: ``law`` if given (its covariance must match ``cov`` when
    both are given), else ``Gaussian(cov)``."""
    if law is None:
        return Gaussian(cov)
    if not isinstance(law, NoiseLaw):
        raise TypeError(f"{name}: expected a nlfilter.noise law (Gaussian, Independent, Sampler), "
                        f"got {type(law).__name__}")
    if np.max(np.abs(law.mean)) > 1e-12 * max(1.0, np.max(np.abs(law.cov))):
        raise ValueError(f"{name}: expected a zero-mean law (filters take noises as zero-mean), "
                         f"got mean {law.mean.tolist()}; centre it and move the mean into f or h")
    return law


def initial_states(n, paths, rng, *, m0=None, P0=None, x0=None, initial: NoiseLaw | None = None,
                   shape=()):
    """``(P, *shape, n)`` initial states of the paths ``paths`` (an int ``P`` or a ``range``; ``rng``
    a seed, SeedSequence, Generator or a :class:`~nlfilter.streams.PathRNG` over them): given
    ``x0``, or drawn per path (``shape`` draws each) from the law ``initial`` or N(m0, P0)."""
    P = len(rng) if isinstance(rng, PathRNG) else len(as_paths(paths))

    def fits(name, a):  # one for all paths, or one per path: it must broadcast to (P, *shape, n)
        try:
            ok = np.broadcast_shapes(a.shape, (P, *shape, n)) == (P, *shape, n)
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f"{name}: expected shape ({n},) or one per path ({P}, {n}), got shape {a.shape}")
        return a

    if x0 is not None:
        x0 = fits("x0", V.finite("x0", V.as_float_array("x0", x0, shape_tail=(n,))))
        return np.broadcast_to(x0, (P, *shape, n)).copy()
    if initial is not None:
        if not isinstance(initial, NoiseLaw) or initial.dim != n:
            raise TypeError(f"initial: expected a noise law of dimension {n}, got {initial!r}")
        return PathRNG.of(rng, paths).sample(initial, shape)
    if m0 is None or P0 is None:
        raise ValueError("m0/P0: expected the prior mean and covariance (or x0, or initial), got None")
    m0 = fits("m0", V.mean("m0", m0, n))
    return m0 + PathRNG.of(rng, paths).sample(Gaussian(V.covariance("P0", P0, n)), shape)
