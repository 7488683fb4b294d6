"""Matrix-free Newton (``find_breather(solver="krylov")``, ``continuation.krylov``) against the dense reference
on the CPU: the same breather to 1e-10, converged in as many Newton steps; the linear lattice's preconditioner
is what makes GMRES converge in a few products; the operator is the inverse of the linear lattice's map."""

import numpy as np
import pytest

import continuation as ct
from continuation.krylov import KrylovSettings, LinearLatticePreconditioner
from warpchain import ChainParams, Flow


@pytest.fixture(scope="module")
def paper_chain():
    return ChainParams(30.0, 160.0, 101)


def test_krylov_newton_finds_the_dense_breather(paper_chain):
    p = paper_chain
    seed = ct.nls_seed(p, 1.01)
    dense = ct.require(ct.find_breather(p, 1.01, seed, solver="dense", device="cpu"))
    krylov = ct.require(ct.find_breather(p, 1.01, seed, solver="krylov", device="cpu"))
    assert dense.stats["solver"] == "dense" and krylov.stats["solver"] == "krylov"
    assert abs(krylov.energy - dense.energy) <= 1e-10
    assert np.max(np.abs(krylov.state - dense.state)) <= 1e-10
    assert krylov.iterations == dense.iterations and krylov.residual <= 1e-10
    products = krylov.stats["krylov_iterations"]
    assert len(products) == krylov.iterations and max(products) <= 40  # a few dozen products, not 2N = 202
    assert krylov.stats["tangent_columns"] == sum(products) < dense.stats["tangent_columns"]
    # the same multipliers from either solution (Floquet itself stays dense)
    assert np.allclose(np.sort(np.abs(ct.floquet(krylov).multipliers)), np.sort(np.abs(ct.floquet(dense).multipliers)))


def test_the_preconditioner_is_what_makes_gmres_converge(paper_chain):
    p = paper_chain
    seed = ct.nls_seed(p, 1.01)
    plain = ct.find_breather(p, 1.01, seed, solver="krylov", device="cpu", krylov=KrylovSettings(preconditioner="none"))
    with_p = ct.find_breather(p, 1.01, seed, solver="krylov", device="cpu")
    assert sum(with_p.stats["krylov_iterations"]) * 4 < sum(plain.stats["krylov_iterations"])  # 49 against 266


def test_the_preconditioner_inverts_the_linear_lattice_map():
    """On a small-amplitude orbit (the linear regime) P J is the identity up to the integrator's error."""
    p = ChainParams(30.0, 160.0, 15)
    flow = Flow("kahan8", 256, device="cpu")
    n_half, dt = flow.grid(1.01)
    x0 = np.zeros((4, p.N))
    lin = flow.linearize(p, x0, n_half, dt)
    J = lin.unit_columns("positions")[2 * p.N :, :]
    P = LinearLatticePreconditioner(p.M, p.K, p.N, n_half * dt, regularization=1e-12)
    PJ = np.stack([P.apply(J[:, i]) for i in range(2 * p.N)], axis=1)
    assert np.max(np.abs(PJ - np.eye(2 * p.N))) < 1e-6


def test_solver_choice_is_checked(paper_chain):
    p = paper_chain
    seed = ct.nls_seed(p, 1.01)
    with pytest.raises(ValueError, match="solver must be"):
        ct.find_breather(p, 1.01, seed, solver="gmres", device="cpu")
    with pytest.raises(ValueError, match="reversible formulation"):
        ct.find_breather(p, 1.01, seed, solver="krylov", formulation="general", device="cpu")
    with pytest.raises(ValueError, match="eta_min"):
        KrylovSettings(eta_min=0.5, eta_max=0.1)
    assert ct.find_breather(p, 1.01, seed, device="cpu").stats["solver"] == "dense"  # auto: below the crossover


def test_auto_goes_matrix_free_only_where_the_preconditioner_exists():
    from continuation.shooting import KRYLOV_MIN_SITES, auto_solver

    big = KRYLOV_MIN_SITES + 1
    assert auto_solver(ChainParams(30.0, 160.0, big), "reversible", "tangent", False) == "krylov"
    assert auto_solver(ChainParams(30.0, 160.0, big - 2), "reversible", "tangent", False) == "dense"
    for boundary in ("free", "periodic"):  # no preconditioner: plain GMRES does not converge there
        assert auto_solver(ChainParams(30.0, 160.0, big, boundary), "reversible", "tangent", False) == "dense"
    assert auto_solver(ChainParams(30.0, 160.0, big), "general", "tangent", False) == "dense"
    assert auto_solver(ChainParams(30.0, 160.0, big), "reversible", "tangent", True) == "dense"  # a chord hint
    plain = KrylovSettings(preconditioner="none")
    assert auto_solver(ChainParams(30.0, 160.0, big), "reversible", "tangent", False, plain) == "dense"


def test_an_unconverged_gmres_solve_is_replaced_by_a_dense_step(paper_chain):
    p = paper_chain
    starved = KrylovSettings(preconditioner="none", max_iterations=20, restart=20)  # 20 products: not enough
    b = ct.require(ct.find_breather(p, 1.01, ct.nls_seed(p, 1.01), solver="krylov", krylov=starved, device="cpu"))
    assert b.stats["krylov_unconverged"] == b.iterations == 4
    assert b.stats["tangent_columns"] == sum(b.stats["krylov_iterations"]) + 4 * 2 * p.N
