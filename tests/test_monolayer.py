"""Breathers of the monolayer on the numpy reference (issue #50's 2D pilot, reference side; issue #51's first
step): Newton shooting and the complete reduced Floquet verdict on square and triangular patches, checked
against the dense monodromy of the same discrete map, computed column by column here."""

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

import continuation as ct
import warpchain as wc
from warpchain import reference
from warpchain.lattice import LatticeParams, square, triangular


def _dense_multipliers(params, b) -> np.ndarray:
    """Every multiplier of the breather's period map, from 4N tangent columns of the reference."""
    n = params.N
    eye = np.eye(4 * n).reshape(4 * n, 4, n)
    out = reference.integrate(b.flow.method, params, b.state[None], b.dt, 2 * b.nsteps, dx0=eye[None])
    assert np.abs(out["x"][0] - b.state).max() < 1e-9  # the orbit closes
    return np.linalg.eigvals(out["dx"][0].reshape(4 * n, 4 * n).T)


@pytest.mark.parametrize(
    "build, centred, verdict",
    [(square, "site", True), (triangular, "site", True), (square, "bond", False), (triangular, "bond", False)],
)
def test_a_monolayer_breather_and_its_complete_verdict_equal_the_dense_monodromy(build, centred, verdict):
    """Site-centred breathers (the single-site orbit at the patch's centre) are stable at K = 1, w_b = 1.005;
    bond-centred ones (two neighbouring sites in phase) have a real pair. The reduced path (even and odd
    blocks under the 180-degree rotation, which the site numbering's reversal is on a patch) gives every
    multiplier of the dense 4N x 4N monodromy."""
    params = LatticeParams(30.0, 1.0, build(7, 7, "fixed"))
    seed = ct.anticontinuum_seed(params, 1.005)
    assert np.argmax(np.abs(seed[1])) == params.lattice.centre
    if centred == "bond":
        seed = seed + np.roll(seed, 1, axis=1)
    b = ct.require(ct.find_breather(params, 1.005, seed, flow=wc.ReferenceFlow("kahan8", 32), solver="dense"))
    assert b.residual < 1e-10 and b.energy > 0
    fl = ct.floquet(b, solver="dense")
    assert fl.complete and fl.stable is verdict and fl.path == "reduced"
    dense = _dense_multipliers(params, b)
    assert abs(fl.max_modulus - np.abs(dense).max()) < 1e-7 or verdict  # stable: both 1 up to the trivial pair
    if not verdict:
        assert fl.instabilities[0].kind == "real_pair" and abs(fl.max_modulus - np.abs(dense).max()) < 1e-9
    cost = np.abs(fl.multipliers[:, None] - dense[None, :])
    rows, cols = linear_sum_assignment(cost)
    assert cost[rows, cols].max() < 1e-6  # the trivial pair splits like the square root of rounding in dense


def test_the_discrete_nls_threshold():
    """``dnls_threshold``: the norm's minimum hardly depends on the patch once the breather fits (15 x 15 against
    21 x 21: 1.3e-5 on the triangular rhombus, whose walls come nearer the centre), the energy scales with K and
    the frequency offset too (the DNLS has one coupling scale), and the continuum limit is the Townes norm times
    sites per area and the symbol's curvature (sqrt(3) more on the triangular lattice than on the square one)."""
    import math

    from continuation import dnls_threshold, nls_coefficients
    from continuation.seeds import TOWNES_NORM
    from warpchain.lattice import square, triangular

    M = 30.0
    w0 = math.sqrt((M + 1.0) / M)
    D, G = nls_coefficients(M)
    for build in (square, triangular):
        small, large = dnls_threshold(build(15, 15), M, 1.0), dnls_threshold(build(21, 21), M, 1.0)
        assert abs(small["norm"] / large["norm"] - 1.0) < 3e-5 and abs(small["ratio"] - large["ratio"]) < 1e-3
        double = dnls_threshold(build(15, 15), M, 2.0)
        assert double["energy"] == pytest.approx(2.0 * small["energy"], rel=1e-12)
        assert w0 - double["omega"] == pytest.approx(2.0 * (w0 - small["omega"]), rel=1e-9)
        assert small["norm"] < 0.5 * small["townes_energy"] * G / (2.0 * D)  # far below the continuum's
    sq, tri = dnls_threshold(square(15, 15), M, 1.0), dnls_threshold(triangular(15, 15), M, 1.0)
    assert sq["townes_energy"] == pytest.approx(2.0 * D / G * TOWNES_NORM, rel=1e-12)
    assert tri["townes_energy"] == pytest.approx(math.sqrt(3.0) * sq["townes_energy"], rel=1e-12)
    assert sq["norm"] == pytest.approx(5.70125, abs=2e-4) and tri["norm"] == pytest.approx(8.77593, abs=2e-4)


def test_the_scene_seeds_each_family_and_embeds_a_patch():
    """``monolayer``'s seeds: the single-site orbit at the centre, in phase on its +x neighbour (a bond) and on its
    +y neighbour too (a triangle of mutual neighbours on the triangular lattice); a small patch's state embedded at
    the centre of a larger one."""
    from scenarios.monolayer import _embed, _seed

    params = LatticeParams(30.0, 1.0, triangular(7, 7, "fixed"))
    c, nx = params.lattice.centre, 7
    for family, sites in (("site", [c]), ("bond", [c, c + 1]), ("triangle", [c, c + 1, c + nx])):
        seed = _seed(params, 1.005, family)
        peaks = np.flatnonzero(np.abs(seed[1]) == np.abs(seed[1]).max())
        assert sorted(peaks) == sorted(sites), family
    nb = params.lattice.neighbours
    assert c + 1 in nb[c] and c + nx in nb[c] and c + nx in nb[c + 1]  # mutual neighbours
    state = np.arange(4 * 49, dtype=float).reshape(4, 49)
    big = _embed(state, 7, 11)
    assert big.shape == (4, 121) and big[:, triangular(11, 11).centre].tolist() == state[:, c].tolist()
    assert np.count_nonzero(big) == np.count_nonzero(state)


@pytest.mark.parametrize("build", [square, triangular])
def test_the_out_of_phase_bond_is_stable_where_the_in_phase_one_is_not(build):
    """9 x 9 patches at K = 0.25, w_b = 1.014 (complete dense verdicts): the bond in phase has one real pair, the bond
    out of phase (the neighbour at the orbit's other turning point, z_min, not -z_max) is stable; on the triangular
    lattice the triangle with one site out of phase keeps one real pair (the in-phase triangle has two). The energies
    are those of the 15 x 15 patches to 6 digits (docs/findings/scenes.md)."""
    from scenarios.monolayer import _seed

    params = LatticeParams(30.0, 0.25, build(9, 9, "fixed"))
    orbit = ct.anticontinuum_orbit(1.014, 30.0)
    families = {"bond": ["real_pair"], "bond-out": []}
    if build is triangular:
        families.update({"triangle": ["real_pair", "real_pair"], "triangle-out": ["real_pair"]})
    for family, kinds in families.items():
        seed = _seed(params, 1.014, family)
        z = seed[0] - seed[1]
        assert np.isclose(z.min(), orbit.z_min if family.endswith("-out") else 0.0)
        b = ct.require(ct.find_breather(params, 1.014, seed, device="cpu", solver="dense"))
        fl = ct.floquet(b, solver="dense")
        assert fl.complete and [i.kind for i in fl.instabilities] == kinds, family
        assert fl.stable is (not kinds)


@pytest.mark.parametrize("build", [square, triangular])
def test_newton_from_the_discrete_nls_seed_near_the_band_edge(build):
    """``continuation.dnls_seed``: the discrete NLS soliton on the patch as a seed reaches a wide breather near the
    optical bottom in a few Newton iterations; outside the gap it is refused."""
    params = LatticeParams(30.0, 1.0, build(11, 11, "fixed"))
    omega = params.omega0 - 5e-4
    seed = ct.dnls_seed(params, omega)
    b = ct.require(ct.find_breather(params, omega, seed, flow=wc.ReferenceFlow("kahan8", 32), solver="dense"))
    assert b.residual < 1e-9 and b.energy > 0
    z, z_seed = b.state[0] - b.state[1], seed[0] - seed[1]
    assert np.argmax(np.abs(z)) == params.lattice.centre and abs(np.abs(z).max() / np.abs(z_seed).max() - 1) < 0.2
    with pytest.raises(ValueError, match="below the optical band"):
        ct.dnls_seed(params, params.omega0)
