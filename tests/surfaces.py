"""Small synthetic surfaces shared by the tests (plain functions; pytest puts ``tests/`` on the path)."""
import numpy as np


def grid(n):
    """Row and column coordinates (float32) of an ``n`` x ``n`` grid."""
    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    return y, x


def noisy(ground, seed=0, sd=0.03):
    """``ground`` plus Gaussian noise of ``sd`` (seeded), as float32."""
    rng = np.random.default_rng(seed)
    return (ground + rng.normal(0.0, sd, ground.shape)).astype(np.float32)
