"""The numba robust quadratic fit equals the least-squares passes it replaced."""
import numpy as np

from tlessbot_ros.core.localise import robust_quadratic_fit


def _reference(sample, iterations):
    gy, gx = np.mgrid[0:sample.shape[0], 0:sample.shape[1]]
    x = gx.ravel() / max(sample.shape[1] - 1, 1) - 0.5
    y = gy.ravel() / max(sample.shape[0] - 1, 1) - 0.5
    A = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    z = sample.ravel()
    keep = np.ones(z.size, bool)
    coef = np.zeros(6)
    for _ in range(iterations):
        if keep.sum() < 12:
            break
        coef = np.linalg.lstsq(A[keep], z[keep], rcond=None)[0]
        resid = z - A @ coef
        keep = np.abs(resid) < 2.5 * (1.4826 * np.median(np.abs(resid[keep])) + 1e-9)
    return coef


def test_fit_equals_lstsq_and_ignores_the_parts():
    rng = np.random.default_rng(2)
    gy, gx = np.mgrid[0:60, 0:80]
    truth = np.array([0.4, 0.05, -0.03, 0.02, 0.01, -0.04])
    x, y = gx / 79 - 0.5, gy / 59 - 0.5
    sample = (truth[0] + truth[1] * x + truth[2] * y + truth[3] * x * x + truth[4] * x * y
              + truth[5] * y * y + rng.normal(0, 0.002, x.shape))
    sample[10:25, 20:40] += 0.3                   # a part: must not pull the surface
    coef = robust_quadratic_fit(sample, 3)
    np.testing.assert_allclose(coef, _reference(sample, 3), atol=1e-10)
    np.testing.assert_allclose(coef, truth, atol=2e-3)


def test_too_few_samples_give_zero_coefficients():
    assert not robust_quadratic_fit(np.ones((2, 3)), 3).any()
