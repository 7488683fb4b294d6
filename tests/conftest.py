import numpy as np
import pytest

from warpchain import METHODS, ChainParams, SplittingMethod
from sweep.runner import _environment_kept


#: the methods the Warp engine steps (RK4 runs on the numpy reference only)
SPLITTING = sorted(name for name, m in METHODS.items() if isinstance(m, SplittingMethod))


def localized_state(N, amplitude=0.6, width=2.0, batch=1, centre=None, seed=None):
    """A localized, large-amplitude profile at rest (optionally with small random velocities)."""
    j = np.arange(N)
    c = N // 2 if centre is None else centre
    bump = np.exp(-(((j - c) / width) ** 2))
    x = np.zeros((batch, 4, N))
    for b in range(batch):
        scale = 1.0 + 0.25 * b
        x[b, 0] = amplitude * scale * bump / 30.0
        x[b, 1] = -amplitude * scale * bump
    if seed is not None:
        rng = np.random.default_rng(seed)
        x[:, 2:] = 0.05 * rng.standard_normal((batch, 2, N))
    return x


@pytest.fixture
def small_chain():
    return ChainParams(M=3.0, K=4.0, N=31)


@pytest.fixture(autouse=True)
def _environment_restored():
    """No test leaves os.environ changed for the next (a Dask LocalCluster started in a test wrote its workers'
    MALLOC_TRIM_THRESHOLD_ and one-thread BLAS settings here, and the scenes later tests start as subprocesses ran
    15 times slower)."""
    with _environment_kept():
        yield
