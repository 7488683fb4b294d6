import math

import numpy as np
import pytest

from warpchain import ChainParams, accelerations, band_edges, dispersion, energy, linear_modes, lowest_optical_mode
from warpchain.model import contact_force, contact_potential, stiffness_and_mass


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(M=0.0, K=1.0), "M"),
        (dict(M=-1.0, K=1.0), "M"),
        (dict(M=1.0, K=-1.0), "K"),
        (dict(M=1.0, K=1.0, N=0), "N"),
        (dict(M=1.0, K=1.0, N=2.5), "N"),
        (dict(M=1.0, K=1.0, boundary="open"), "boundary"),
        (dict(M=float("nan"), K=1.0), "M"),
    ],
)
def test_params_validated(kwargs, word):
    with pytest.raises(ValueError, match=word):
        ChainParams(**kwargs)


def test_band_edges_closed_forms_and_design_numbers():
    e = band_edges(30.0, 160.0)
    # closed forms of warpchain.model.band_edges
    assert e["acoustic_top"] == pytest.approx(0.999181, abs=1e-6)
    assert e["optical_bottom"] == pytest.approx(1.016530, abs=1e-6)
    assert e["optical_top"] == pytest.approx(4.6226, abs=1e-4)
    a = 4 * 160 + 30 + 1
    assert e["acoustic_top"] == pytest.approx(math.sqrt((a - math.sqrt(a * a - 16 * 160 * 30)) / 60), rel=1e-10)
    # the dispersion relation reaches the edges at q = 0 and q = pi
    ac, op = dispersion(np.array([0.0, np.pi]), 30.0, 160.0)
    assert op[0] == pytest.approx(e["optical_bottom"], rel=1e-14)
    assert ac[1] == pytest.approx(e["acoustic_top"], rel=1e-12)
    assert op[1] == pytest.approx(e["optical_top"], rel=1e-14)
    # and satisfies M w^4 - [2K(1 - cos q) + M + 1] w^2 + 2K(1 - cos q) = 0 everywhere
    q = np.linspace(0, np.pi, 50)
    s = 2 * 160 * (1 - np.cos(q))
    for w in dispersion(q, 30.0, 160.0):
        assert np.max(np.abs(30 * w**4 - (s + 31) * w**2 + s)) < 1e-9


def test_linear_modes_mass_orthogonal_and_lowest_optical():
    p = ChainParams(30.0, 160.0, 201)
    freqs, shapes = linear_modes(p)
    _, mass = stiffness_and_mass(p)
    vecs = shapes.reshape(2 * p.N, 2 * p.N)
    gram = vecs @ mass @ vecs.T
    assert np.max(np.abs(gram - np.eye(2 * p.N))) < 1e-10
    w, shape = lowest_optical_mode(p)
    assert w == pytest.approx(1.016551, abs=1e-6)
    assert band_edges(30, 160)["optical_bottom"] < w < band_edges(30, 160)["optical_top"]
    # single-humped, out of phase (optical)
    assert shape[0, 100] > 0 > shape[1, 100]


@pytest.mark.parametrize("boundary", ["fixed", "free", "periodic"])
def test_accelerations_are_minus_energy_gradient(boundary):
    rng = np.random.default_rng(1)
    p = ChainParams(2.5, 3.0, 9, boundary)
    x = np.zeros((1, 4, p.N))
    x[0, :2] = 0.3 * rng.standard_normal((2, p.N))
    acc = accelerations(p, x)[0]
    h = 1e-6
    grad = np.zeros((2, p.N))
    for c in range(2):
        for j in range(p.N):
            xp, xm = x.copy(), x.copy()
            xp[0, c, j] += h
            xm[0, c, j] -= h
            grad[c, j] = (energy(p, xp)[0] - energy(p, xm)[0]) / (2 * h)
    assert np.allclose(-grad[0] / p.M, acc[0], atol=1e-7)
    assert np.allclose(-grad[1], acc[1], atol=1e-7)


def test_contact_law_and_rest_energy():
    assert contact_force(0.0) == 0.0
    assert contact_force(-1.5) == pytest.approx(-2.0 / 3.0)  # contact lost: only the preload acts
    assert contact_potential(0.0) == pytest.approx(0.0, abs=1e-16)
    assert energy(ChainParams(30, 160, 5), np.zeros((4, 5)))[0] == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize("boundary", ["fixed", "free", "periodic"])
@pytest.mark.parametrize("n", [1, 2, 7])
def test_site_energies_sum_to_the_energy(boundary, n):
    """``site_energies`` (observe's oracle) holds the wall bonds of ``energy`` site by site, for every boundary."""
    from warpchain.model import BOUNDARIES, site_energies

    assert boundary in BOUNDARIES
    p = ChainParams(3.0, 4.0, n, boundary)
    x = np.random.default_rng(n).normal(scale=0.3, size=(2, 4, n))
    M, K = np.array([3.0, 5.0]), np.array([4.0, 0.5])
    e = site_energies(p, x, M, K)
    assert e.shape == (2, n)
    np.testing.assert_allclose(e.sum(axis=-1), energy(p, x, M, K), rtol=1e-13, atol=1e-15)
