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


# ----------------------------------------------------------------------------- lattice patches


@pytest.mark.parametrize("name", ["square", "triangular"])
def test_krylov_newton_on_a_patch_is_the_dense_breather(name):
    """11 x 11 patches (issue #51's agreement target): the matrix-free breather equals the dense one (energy to 1e-10,
    state to 1e-10, multipliers to 1e-9), and the patch's sine-basis preconditioner keeps GMRES to a few dozen
    products per Newton step (the chain's, applied along the site numbering, needed 70 to 90 on 15 x 15)."""
    from warpchain.lattice import LatticeParams, square, triangular

    p = LatticeParams(30.0, 1.0, {"square": square, "triangular": triangular}[name](11, 11, "fixed"))
    seed = ct.anticontinuum_seed(p, 1.014)
    dense = ct.require(ct.find_breather(p, 1.014, seed, solver="dense", device="cpu"))
    krylov = ct.require(ct.find_breather(p, 1.014, seed, solver="krylov", device="cpu"))
    assert abs(krylov.energy - dense.energy) <= 1e-10
    assert np.max(np.abs(krylov.state - dense.state)) <= 1e-10
    assert max(krylov.stats["krylov_iterations"]) <= 30
    a, b = ct.floquet(krylov, solver="dense"), ct.floquet(dense, solver="dense")
    assert np.max(np.abs(np.sort_complex(a.mu) - np.sort_complex(b.mu))) <= 1e-9 and a.stable is b.stable is True


@pytest.mark.parametrize("name", ["square", "triangular"])
def test_the_patch_preconditioner_inverts_the_linear_map_where_it_is_diagonal(name):
    """On a 7 x 5 patch at rest: P J is the identity on the square lattice (the 2-D sine modes are its linear
    modes); on the triangular one P is the inverse of J's part that is diagonal in that basis, so P J is the
    identity plus what the diagonal bond couples, and J P's spectrum clusters at 1 all the same."""
    from warpchain.lattice import LatticeParams, square, triangular

    lattice = {"square": square, "triangular": triangular}[name](7, 5, "fixed")
    p = LatticeParams(30.0, 1.0, lattice)
    flow = Flow("kahan8", 256, device="cpu")
    n_half, dt = flow.grid(1.01)
    lin = flow.linearize(p, np.zeros((4, p.N)), n_half, dt)
    J = lin.unit_columns("positions")[2 * p.N :, :]
    P = LinearLatticePreconditioner(p.M, p.K, p.N, n_half * dt, regularization=1e-12, lattice=lattice)
    PJ = np.stack([P.apply(J[:, i]) for i in range(2 * p.N)], axis=1)
    off = np.max(np.abs(PJ - np.eye(2 * p.N)))
    if name == "square":
        assert off < 1e-6
    else:
        assert 1e-3 < off and np.max(np.abs(np.linalg.eigvals(PJ) - 1.0)) < 1.0
