"""The thread-per-lattice kernel's fused sweeps (``kernels.fused_stage``: a stage in one pass over contiguous
rows) against the numpy reference, bit for bit, where their edges are: the shortest
lattices (the sites at both ends are taken out of the loop), every boundary, recorded frames and stiffness
history, and the generic path they fall back to (strided rows, N = 1)."""

import numpy as np
import pytest
import warp as wp

from conftest import localized_state
from warpchain import Placement, Record
from warpchain import ChainParams, propagate_tangent, reference, simulate
from warpchain.engine import site as S
from warpchain.engine import thread_kernels as K
from warpchain.reference import inverse_mass


@pytest.mark.parametrize("boundary", ["fixed", "free", "periodic"])
@pytest.mark.parametrize("n_sites", [1, 2, 3, 4, 11])
@pytest.mark.parametrize("method", ["verlet", "yoshida4"])
def test_short_lattices_every_boundary_bit_for_bit(method, n_sites, boundary):
    p = ChainParams(3.0, 4.0, n_sites, boundary)
    x0 = localized_state(n_sites, amplitude=0.9, batch=3, centre=n_sites // 3, seed=n_sites)
    M, K_ = np.array([3.0, 1.5, 6.0]), np.array([4.0, 2.0, 7.0])
    run = simulate(
        p,
        x0,
        60 * 0.05,
        0.05,
        method=method,
        device="cpu",
        M=M,
        K=K_,
        record=Record(every=7),
        placement=Placement(layout="thread"),
    )
    ref = reference.integrate(method, p, x0, 0.05, run.nsteps, M=M, K=K_, save_every=7)
    assert np.array_equal(run.x, ref["x"])
    assert np.array_equal(run.u, ref["u"]) and np.array_equal(run.v, ref["v"])


@pytest.mark.parametrize("boundary", ["fixed", "free", "periodic"])
@pytest.mark.parametrize("n_sites", [1, 2, 3, 6])
@pytest.mark.parametrize("method", ["verlet", "yoshida4"])
def test_tangent_columns_of_short_lattices_bit_for_bit(method, n_sites, boundary):
    """The base run records f'(z) in the fused sweep, the tangent kernel's own fused sweep reads it: the
    columns match the reference's bit for bit."""
    p = ChainParams(3.0, 4.0, n_sites, boundary)
    x0 = localized_state(n_sites, amplitude=0.7, batch=2, seed=5)
    ncols = 4 * n_sites
    eye = np.eye(ncols).reshape(ncols, 4, n_sites)
    dx0 = np.concatenate([eye, eye])
    base = np.repeat([0, 1], ncols)
    tan = propagate_tangent(p, x0, dx0, 30, 0.05, method=method, column_base=base, device="cpu", layout="thread")
    ref = reference.integrate(method, p, x0, 0.05, 30, dx0=dx0.reshape(2, ncols, 4, n_sites))
    assert np.array_equal(tan.x, ref["x"])
    assert np.array_equal(tan.columns, ref["dx"].reshape(2 * ncols, 4, n_sites))


def _strided(values: np.ndarray):
    """A CPU warp array holding ``values`` whose last axis has stride 2 (every other double of a buffer)."""
    buf = np.zeros(values.shape[:-1] + (2 * values.shape[-1],))
    buf[..., ::2] = values
    owner = wp.array(buf, dtype=wp.float64, device="cpu")
    strides = tuple(s for s in owner.strides[:-1]) + (16,)
    view = wp.array(ptr=owner.ptr, shape=values.shape, strides=strides, dtype=wp.float64, device="cpu")
    return owner, view


def test_strided_rows_take_the_generic_path():
    """Rows that are not contiguous (never built by ``ensemble``) run the per-pass loops, same results."""
    p = ChainParams(3.0, 4.0, 9, "periodic")
    x0 = localized_state(p.N, amplitude=0.9, batch=2, seed=2)
    M, K_ = np.array([3.0, 5.0]), np.array([4.0, 1.0])
    owner, x = _strided(x0)
    f64, none = wp.float64, wp.zeros((1, 1, 1), dtype=wp.float64, device="cpu")
    lattice = S.Lattice()  # the chains' parameters, no losses
    lattice.mass, lattice.inv_mass, lattice.coupling = (wp.array(a, dtype=f64) for a in (M, inverse_mass(M), K_))
    lattice.lossy, lattice.damp, lattice.boundary = wp.zeros(2, dtype=wp.int32), none, S.BOUNDARY_PERIODIC
    no_base = [0, wp.zeros(1, dtype=wp.int32, device="cpu")]  # a base run (not a tangent column)
    record = S.Recording()  # nothing recorded
    record.u = record.v = record.hist = none
    acc = wp.zeros((2, 2, p.N), dtype=f64, device="cpu")
    inputs = [
        x,
        acc,
        *no_base,
        lattice,
        wp.array(np.array([1.0]), dtype=f64),
        wp.array(np.array([0.5, 0.5]), dtype=f64),
    ]
    inputs += [f64(0.05), 40, record, S.Observer()]
    wp.launch(K.splitting_kernel, dim=2, inputs=inputs, device="cpu")
    ref = reference.integrate("verlet", p, x0, 0.05, 40, M=M, K=K_)["x"]
    assert np.array_equal(owner.numpy()[..., ::2], ref)
