"""``sqrt_psd`` (:mod:`nlfilter.filters.linalg`) on a rank-2 PSD matrix ``v vᵀ + u uᵀ`` (3×3) whose
smallest eigenvalue eigh computes as +8.6e-18 while Cholesky fails in rounding: the factor is the
eigen root (a semi-definite matrix), not a LinAlgError out of the filter's step (found by the
``square-root`` experiment's near-noiseless sweep)."""

import numpy as np

from nlfilter.filters.linalg import sqrt_psd

H = [["0x1.b74a31ef8ebc9p-6", "-0x1.2a31c091cecb2p-4", "0x1.e52dc30a9f354p-4"],
     ["-0x1.2a31c091cecb2p-4", "0x1.37b2e56bb2a26p-2", "-0x1.1cfa3da85bbc2p-2"],
     ["0x1.e52dc30a9f354p-4", "-0x1.1cfa3da85bbc2p-2", "0x1.14efd1083970ep-1"]]


def test_a_tiny_positive_eigenvalue_that_cholesky_rounds_away_takes_the_root():
    """Beside a well-conditioned path (its Cholesky factor, exactly np.linalg.cholesky's): the
    root reproduces P to 1e-15 (rounding of entries of order 0.5), and no path is reported bad."""
    P = np.array([[float.fromhex(v) for v in row] for row in H])
    assert np.linalg.eigvalsh(P)[0] > 0
    batch = np.stack([P, np.eye(3) + 0.1])
    L, bad = sqrt_psd(batch)
    assert not bad.any()
    np.testing.assert_allclose(L[0] @ L[0].T, P, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(L[1], np.linalg.cholesky(batch[1]))
