import dataclasses
import itertools

import numpy as np
import scipy.linalg
import pytest
from scipy.optimize import minimize

from warpchain import model
from warpchain.lattice import MISSING, WALL, Lattice, chain, square, triangular

BOUNDARIES = model.BOUNDARIES


def bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def fields(n, seed=0):
    """A random batch (3, n) and an integer-valued one (exact cancellations, zeros)."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(3, n)), rng.integers(-2, 3, size=(3, n)).astype(np.float64)


def all_lattices():
    for b in BOUNDARIES:
        yield chain(9, b)
        yield chain(2, b)
        yield chain(5, b, weight=0.7)
        yield square(5, 4, b)
        yield square(3, 3, b, weights=(1.0, 0.5))
        yield square(6, 1, b, weights=(1.0, 0.0))
        yield triangular(4, 5, b)
        yield triangular(4, 4, b, weights=(1.0, 0.5, 2.0))
    yield square(2, 3, "periodic")
    yield triangular(2, 2, "periodic")
    yield triangular(1, 3, "periodic")


LATTICES = list(all_lattices())
IDS = [repr(lat) for lat in LATTICES]


def grid_symbol(lat):
    """lam(2 pi k / n) over the Bloch grid of a periodic lattice."""
    if len(lat.shape) == 1:
        return lat.lam(2 * np.pi * np.arange(lat.shape[0]) / lat.shape[0])
    nx, ny = lat.shape
    k1, k2 = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    return lat.lam((2 * np.pi * k1 / nx, 2 * np.pi * k2 / ny)).ravel()


# ----------------------------------------------------------------------------- the chain is model's


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("N", [1, 2, 3, 17])
def test_chain_laplacian_is_models_bit_for_bit(boundary, N):
    for u in fields(N):
        assert np.array_equal(bits(chain(N, boundary).laplacian(u)), bits(model.laplacian(u, boundary)))
    u = fields(N)[0]
    assert np.array_equal(chain(N, boundary).laplacian(u[0]), model.laplacian(u[0], boundary))  # one field


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_chain_tables_and_numbering(boundary):
    lat = chain(5, boundary)
    left, right = lat.neighbours[:, 0], lat.neighbours[:, 1]
    assert left[1:].tolist() == [0, 1, 2, 3] and right[:-1].tolist() == [1, 2, 3, 4]
    end = {"fixed": WALL, "free": MISSING}.get(boundary)
    assert (left[0], right[-1]) == ((4, 0) if end is None else (end, end))
    assert lat.weights[0, 0] == (0.0 if boundary == "free" else 1.0)
    assert lat.neighbours.dtype == np.int32 and lat.weights.dtype == np.float64
    assert np.array_equal(lat.positions, np.stack([np.arange(5), np.zeros(5)], axis=1))
    assert lat.centre == 2 and chain(6).centre == 3 and (lat.n_sites, lat.degree) == (5, 2)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_chain_linear_waves_are_models(boundary):
    lat = chain(17, boundary)
    for M, K in [(30.0, 160.0), (0.5, 0.0), (2.0, 1.3)]:
        # the same closed forms, K * 4 and 2 K (1 - cos q) scaled by powers of 2: equal, not just close
        assert lat.band_edges(M, K) == model.band_edges(M, K)
        q = np.linspace(-np.pi, np.pi, 41)
        for a, b in zip(lat.dispersion(q, M, K), model.dispersion(q, M, K)):
            assert np.array_equal(a, b)
        # model's stiffness and modes are the lattice's (ChainParams.lattice): against the chain's own Laplacian
        eye = np.eye(17)
        stiff = np.block([[K * model.laplacian(eye, boundary) + eye, -eye], [-eye, eye]])
        mass = np.diag(np.concatenate([np.full(17, M), np.ones(17)]))
        params = model.ChainParams(M, K, 17, boundary)
        for a, b in zip(model.stiffness_and_mass(params), (stiff, mass)):
            assert np.array_equal(a, b)
        w2, vecs = scipy.linalg.eigh(stiff, mass)
        freqs, shapes = model.linear_modes(params)
        np.testing.assert_allclose(freqs, np.sqrt(np.maximum(w2, 0.0)), rtol=0, atol=1e-12)
        for m in range(34):  # each mode up to its sign (largest entry positive)
            v = vecs[:, m] * np.sign(vecs[np.argmax(np.abs(vecs[:, m])), m])
            if abs(w2[m] - w2[m - 1]) > 1e-9 and (m == 33 or abs(w2[m + 1] - w2[m]) > 1e-9):  # non-degenerate
                np.testing.assert_allclose(shapes[m].ravel(), v, rtol=0, atol=1e-10)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_chain_bond_energy_is_models_spring_energy(boundary):
    u = fields(17)[0]
    state = model.state_from_positions(u, u)  # z = 0: no contact energy, at rest
    energy = model.energy(model.ChainParams(1.0, 1.0, 17, boundary), state)
    np.testing.assert_allclose(chain(17, boundary).bond_energy(u), energy, rtol=1e-14)
    np.testing.assert_allclose(chain(17, boundary, weight=2.5).bond_energy(u), 2.5 * energy, rtol=1e-14)


# ----------------------------------------------------------------------------- strips and independent chains


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("N", [1, 2, 3, 11])
def test_strip_is_the_chain(boundary, N):
    strip, line = square(N, 1, boundary, weights=(1.0, 0.0)), chain(N, boundary)
    for u in fields(N, seed=N):
        assert np.array_equal(bits(strip.laplacian(u)), bits(model.laplacian(u, boundary)))
        np.testing.assert_allclose(strip.bond_energy(u), line.bond_energy(u), rtol=1e-15)
    assert (strip.laplacian_matrix() != line.laplacian_matrix()).nnz == 0
    assert strip.band_edges(3.0, 2.0) == line.band_edges(3.0, 2.0)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_square_with_no_y_bonds_is_independent_chains(boundary):
    nx, ny = 7, 5
    lat = square(nx, ny, boundary, weights=(1.0, 0.0))
    for u in fields(nx * ny, seed=3):
        rows = u.reshape(3, ny, nx)  # s = i + nx j: row j is the chain along x
        assert np.array_equal(bits(lat.laplacian(u)), bits(model.laplacian(rows, boundary).reshape(3, -1)))


# ----------------------------------------------------------------------------- the Laplacian, its matrix and spectrum


@pytest.mark.parametrize("lat", LATTICES, ids=IDS)
def test_laplacian_matrix_symmetric_psd_and_equal_to_laplacian(lat):
    L = lat.laplacian_matrix()
    assert L.format == "csr" and L.shape == (lat.n_sites,) * 2
    dense = L.toarray()
    assert np.array_equal(dense, dense.T)
    assert np.linalg.eigvalsh(dense).min() > -1e-12
    u = fields(lat.n_sites)[0]
    np.testing.assert_allclose(lat.laplacian(u), u @ dense.T, rtol=0, atol=1e-13)
    np.testing.assert_allclose(lat.laplacian(np.eye(lat.n_sites)), dense, rtol=0, atol=0)


@pytest.mark.parametrize("lat", LATTICES, ids=IDS)
def test_bond_energy_is_half_the_quadratic_form(lat):
    u = fields(lat.n_sites, seed=7)[0]
    L = lat.laplacian_matrix()
    quadratic = 0.5 * np.einsum("bi,bi->b", u, (L @ u.T).T)
    np.testing.assert_allclose(lat.bond_energy(u), quadratic, rtol=1e-12)
    assert lat.bond_energy(u).shape == (3,) and lat.bond_energy(u[0]).shape == ()


@pytest.mark.parametrize("lat", LATTICES, ids=IDS)
def test_site_bond_energy_sums_to_the_bond_energy_and_picks_sites(lat):
    """The density sums to ``bond_energy``; at given sites (monolayer-spot's breather discs) it is the density's
    columns, the same bits."""
    u = fields(lat.n_sites, seed=8)[0]
    density = lat.site_bond_energy(u)
    np.testing.assert_allclose(density.sum(axis=-1), lat.bond_energy(u), rtol=1e-12)
    at = np.unique(np.random.default_rng(3).integers(0, lat.n_sites, size=5))
    assert np.array_equal(lat.site_bond_energy(u, at), density[:, at])


@pytest.mark.parametrize(
    "lat",
    [chain(7, "periodic"), chain(2, "periodic"), chain(1, "periodic")]
    + [square(nx, ny, "periodic") for nx, ny in [(6, 6), (5, 4), (2, 3), (1, 1), (2, 2), (1, 5)]]
    + [triangular(nx, ny, "periodic") for nx, ny in [(6, 6), (5, 4), (2, 3), (1, 1), (2, 2), (3, 1)]]
    + [triangular(6, 5, "periodic", weights=(1.0, 0.3, 2.0)), square(4, 6, "periodic", weights=(0.5, 1.5))],
    ids=repr,
)
def test_periodic_spectrum_is_the_symbol_on_the_bloch_grid(lat):
    eig = np.linalg.eigvalsh(lat.laplacian_matrix().toarray())
    np.testing.assert_allclose(np.sort(eig), np.sort(grid_symbol(lat)), rtol=0, atol=1e-12)
    assert np.max(grid_symbol(lat)) <= lat.lam_max + 1e-12


@pytest.mark.parametrize("build", [lambda b: chain(9, b), lambda b: square(5, 4, b), lambda b: triangular(4, 5, b)])
def test_fixed_is_positive_definite_free_has_one_zero_mode(build):
    fixed = np.linalg.eigvalsh(build("fixed").laplacian_matrix().toarray())
    free = np.linalg.eigvalsh(build("free").laplacian_matrix().toarray())
    assert fixed.min() > 1e-3
    assert np.sum(np.abs(free) < 1e-10) == 1 and np.sort(free)[1] > 1e-3


# ----------------------------------------------------------------------------- the symbol and the bands


def test_symbol_closed_forms():
    q1, q2 = np.meshgrid(np.linspace(-4, 4, 9), np.linspace(-3, 3, 7))
    np.testing.assert_allclose(chain(3).lam(q1), 2 * (1 - np.cos(q1)), rtol=1e-15)
    np.testing.assert_allclose(square(3, 3).lam((q1, q2)), 2 * (2 - np.cos(q1) - np.cos(q2)), rtol=1e-14)
    expected = 2 * (3 - np.cos(q1) - np.cos(q2) - np.cos(q1 - q2))
    np.testing.assert_allclose(triangular(3, 3).lam(np.stack([q1, q2])), expected, rtol=1e-14)
    assert (chain(3).lam_max, square(3, 3).lam_max, triangular(3, 3).lam_max) == (4.0, 8.0, 9.0)
    assert triangular(3, 3).lam((2 * np.pi / 3, -2 * np.pi / 3)) == pytest.approx(9.0, rel=1e-15)
    assert triangular(3, 3, weights=(1.0, 1.0, 0.0)).lam_max == 8.0  # the square lattice


@pytest.mark.parametrize(
    "weights", [(1.0, 2.0, 0.5), (1.0, 1.0, 3.0), (0.2, 1.0, 1.0), (1.0, 0.0, 2.0), (2.0, 2.0, 2.0)]
)
def test_triangular_lam_max_is_the_maximum(weights):
    lat = triangular(3, 3, weights=weights)
    grid = np.linspace(-np.pi, np.pi, 181)
    q = np.stack(np.meshgrid(grid, grid))
    values = lat.lam(q)
    start = q[(slice(None),) + np.unravel_index(np.argmax(values), values.shape)]
    best = -minimize(lambda x: -lat.lam(x), start, method="Nelder-Mead", options=dict(xatol=1e-12, fatol=1e-15)).fun
    assert values.max() <= lat.lam_max + 1e-12
    assert best == pytest.approx(lat.lam_max, rel=1e-10)


def test_two_dimensional_band_edges():
    M, K = 30.0, 10.0
    for lat, q_top in [(square(4, 4), (np.pi, np.pi)), (triangular(4, 4), (2 * np.pi / 3, -2 * np.pi / 3))]:
        edges = lat.band_edges(M, K)
        acoustic, optical = lat.dispersion(q_top, M, K)
        assert edges["optical_bottom"] == model.band_edges(M, K)["optical_bottom"]
        assert edges["acoustic_top"] == pytest.approx(float(acoustic), rel=1e-14)
        assert edges["optical_top"] == pytest.approx(float(optical), rel=1e-14)
        assert float(lat.dispersion((0.0, 0.0), M, K)[1]) == pytest.approx(edges["optical_bottom"], rel=1e-15)
        assert edges["gap_width"] == edges["optical_bottom"] - edges["acoustic_top"]
        w = edges["acoustic_top"]
        assert M * w**4 - (K * lat.lam_max + M + 1) * w**2 + K * lat.lam_max == pytest.approx(0.0, abs=1e-10)


def test_two_dimensional_linear_modes_are_mass_orthonormal():
    lat = triangular(4, 3, "free")
    freqs, shapes = lat.linear_modes(2.0, 1.5)
    _, mass = lat.stiffness_and_mass(2.0, 1.5)
    vecs = shapes.reshape(2 * lat.n_sites, -1)
    np.testing.assert_allclose(vecs @ mass @ vecs.T, np.eye(2 * lat.n_sites), atol=1e-12)
    assert np.all(np.diff(freqs) >= 0) and freqs[0] == pytest.approx(0.0, abs=1e-7)  # the free translation
    assert freqs[-1] <= lat.band_edges(2.0, 1.5)["optical_top"] + 1e-12


# ----------------------------------------------------------------------------- geometry


def test_numbering_positions_and_centre():
    sq, tri = square(4, 3), triangular(4, 3)
    s = 1 + 4 * 2  # (i, j) = (1, 2)
    assert np.array_equal(sq.positions[s], [1.0, 2.0])
    np.testing.assert_allclose(tri.positions[s], [1 + 2 / 2, 2 * np.sqrt(3) / 2], rtol=1e-15)
    assert sorted(sq.neighbours[s].tolist()) == sorted([0 + 4 * 2, 2 + 4 * 2, 1 + 4 * 1, WALL])
    assert tri.neighbours[s].tolist() == [0 + 8, 2 + 8, 1 + 4, WALL, WALL, 2 + 4]  # -x, +x, -y, +y, (-1, 1), (1, -1)
    assert (sq.centre, tri.centre, square(5, 5).centre) == (2 + 4 * 1, 2 + 4 * 1, 12)


def brute_distances(lat, site, reach=6):
    wraps = [lat.boundary == "periodic" and axis < len(lat.shape) for axis in range(2)]
    sizes = np.array((lat.shape + (1,))[:2])
    best = np.full(lat.n_sites, np.inf)
    for a in range(-reach, reach + 1) if wraps[0] else [0]:
        for b in range(-reach, reach + 1) if wraps[1] else [0]:
            shift = (sizes * (a, b)) @ lat.basis
            best = np.minimum(best, np.linalg.norm(lat.positions + shift - lat.positions[site], axis=1))
    return best


@pytest.mark.parametrize("lat", LATTICES + [triangular(2, 9, "periodic"), triangular(11, 2, "periodic")], ids=repr)
def test_distances(lat):
    for site in {0, lat.centre, lat.n_sites - 1}:
        d = lat.distances(site)
        np.testing.assert_allclose(d, brute_distances(lat, site), rtol=0, atol=1e-12)
        assert d[site] == 0.0
    if lat.boundary == "periodic" and min(lat.shape) >= 3:  # every real neighbour is one lattice constant away
        d = lat.distances(lat.centre)
        assert np.allclose(d[lat.neighbours[lat.centre]], 1.0, atol=1e-12)
    if lat.name == "chain" and lat.boundary == "periodic":
        N = lat.n_sites
        offsets = np.abs(np.arange(N) - lat.centre)
        np.testing.assert_allclose(lat.distances(lat.centre), np.minimum(offsets, N - offsets), atol=1e-15)


def neighbour_multiset(lat, s, relabel):
    return sorted((relabel[t] if t >= 0 else int(t), float(w)) for t, w in zip(lat.neighbours[s], lat.weights[s]))


@pytest.mark.parametrize("lat", LATTICES + [square(5, 5), triangular(5, 5, "periodic"), triangular(6, 6)], ids=repr)
def test_symmetries_are_automorphisms(lat):
    identity = np.arange(lat.n_sites)
    for name, p in lat.symmetries().items():
        assert np.array_equal(np.sort(p), identity) and not np.array_equal(p, identity), name
        for s in range(lat.n_sites):
            assert neighbour_multiset(lat, s, p) == neighbour_multiset(lat, p[s], identity), (name, s)
        # hence L commutes with the permutation, and the bond energy is invariant
        u = fields(lat.n_sites, seed=5)[0]
        moved = np.empty_like(u)
        moved[:, p] = u
        out = np.empty_like(u)
        out[:, p] = lat.laplacian(u)
        np.testing.assert_allclose(lat.laplacian(moved), out, atol=1e-13)
        np.testing.assert_allclose(lat.bond_energy(moved), lat.bond_energy(u), rtol=1e-13)


def test_symmetry_groups():
    names = lambda lat: set(lat.symmetries())  # noqa: E731
    assert names(chain(7)) == names(chain(6, "periodic")) == {"mirror"}
    assert np.array_equal(chain(6).symmetries()["mirror"], np.arange(6)[::-1])  # continuation's j -> N + 1 - j
    assert names(square(5, 5)) == {"rot90", "rot180", "rot270", "mirror_0", "mirror_45", "mirror_90", "mirror_135"}
    assert names(square(5, 4)) == names(square(5, 5, weights=(1.0, 0.5))) == {"rot180", "mirror_0", "mirror_90"}
    assert names(triangular(4, 4)) == {"rot180", "mirror_30", "mirror_120"}
    assert names(triangular(4, 3)) == names(triangular(4, 4, weights=(1.0, 0.5, 1.0))) == {"rot180"}
    assert len(names(triangular(5, 5, "periodic"))) == 11  # the hexagonal group D6 about a site
    assert names(chain(1)) == set()
    p = square(4, 3).symmetries()["mirror_90"]
    assert p[0 + 4 * 1] == 3 + 4 * 1  # (i, j) -> (nx - 1 - i, j)
    p = triangular(3, 3).symmetries()["mirror_30"]
    assert p[1 + 3 * 2] == 2 + 3 * 1  # (i, j) -> (j, i)


def graph_reach(lat, distance):
    """Sites within ``distance`` bonds of weight != 0, by breadth-first search."""
    adjacent = [
        {int(t) for t, w in zip(lat.neighbours[s], lat.weights[s]) if t >= 0 and w != 0} for s in range(lat.n_sites)
    ]
    reach = []
    for s in range(lat.n_sites):
        seen, frontier = {s}, {s}
        for _ in range(distance):
            frontier = set().union(*(adjacent[t] for t in frontier)) - seen
            seen |= frontier
        reach.append(seen - {s})
    return reach


@pytest.mark.parametrize("distance", [1, 2, 3])
@pytest.mark.parametrize("lat", LATTICES, ids=IDS)
def test_colouring_is_valid(lat, distance):
    colours = lat.colouring(distance)
    assert colours.shape == (lat.n_sites,) and colours.min() == 0
    for s, near in enumerate(graph_reach(lat, distance)):
        assert all(colours[t] != colours[s] for t in near)


@pytest.mark.parametrize(
    "builder, tiles", [(square, lambda b: 2 * b * b + 2 * b + 1), (triangular, lambda b: 3 * b * b + 3 * b + 1)]
)
def test_wide_colourings_take_as_many_colours_as_a_tiling_ball(builder, tiles):
    """The probe's colourings (distance 2 b: no two sites within 2 b bonds share a colour) on patches without wrapped
    axes: valid, and with as many colours as a ball of b bonds has sites, the least any colouring can have (the
    greedy one took 256 and 464 at b = 10)."""
    from warpchain.colouring import balls_of

    lat = builder(23, 19, "fixed")
    for b in (2, 4, 6):
        colours = lat.colouring(2 * b)
        assert colours.max() + 1 == tiles(b)
        ball, _ = balls_of(lat, 2 * b)
        for s in range(lat.n_sites):
            near = ball.indices[ball.indptr[s] : ball.indptr[s + 1]]
            assert np.count_nonzero(colours[near] == colours[s]) == 1  # itself only


def test_colourings_of_strips_and_of_distances_beyond_the_patch():
    """A strip one site wide is coloured as the chain (s mod (distance + 1)); a distance that covers the patch gives
    every site its own colour at once (no search over offsets that cannot occur); wide distances stay cheap."""
    assert np.array_equal(square(41, 1, "fixed").colouring(8), np.arange(41) % 9)
    assert np.array_equal(triangular(5, 5, "fixed").colouring(12), np.arange(25))
    colours = square(101, 101, "fixed").colouring(128)  # ~1 GB per array before the offsets were bounded
    assert colours.shape == (10201,) and colours.max() + 1 < 10201


def test_chain_colouring_is_s_mod_3():
    for boundary in ("fixed", "free"):
        assert np.array_equal(chain(10, boundary).colouring(), np.arange(10) % 3)
    assert np.array_equal(chain(9, "periodic").colouring(), np.arange(9) % 3)
    assert chain(10, "periodic").colouring().max() == 3  # 10 is no multiple of 3: the ring needs a fourth


# ----------------------------------------------------------------------------- data, validation


def test_lattice_is_frozen_data():
    lat = triangular(3, 2, "periodic")
    for name in ("neighbours", "weights", "positions", "basis", "directions"):
        with pytest.raises(ValueError):
            getattr(lat, name)[0, 0] = 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        lat.boundary = "fixed"
    assert all(not p.flags.writeable for p in lat.symmetries().values())
    assert repr(lat) == "Lattice(triangular 3x2 periodic: 6 sites, degree 6)"
    assert square(4, 1, weights=(1.0, 0.0)).describe() == "square 4x1 fixed: 4 sites, degree 4, weights (1.0, 0.0)"
    assert lat.laplacian(np.zeros(6, dtype=np.int64)).dtype == np.float64


def test_a_lattice_can_be_built_by_hand_and_is_checked():
    lat = chain(4, "free")
    fields_ = {f.name: getattr(lat, f.name) for f in dataclasses.fields(Lattice)}
    again = Lattice(**fields_)
    assert np.array_equal(again.laplacian(np.arange(4.0)), lat.laplacian(np.arange(4.0)))
    broken = np.array(lat.neighbours)
    broken[1, 1] = 3  # site 1's right neighbour is 3, but 3's left one is 2
    with pytest.raises(ValueError, match="symmetric"):
        Lattice(**{**fields_, "neighbours": broken})
    heavy = np.array(lat.weights)
    heavy[0, 0] = 1.0  # a weight on a MISSING slot
    with pytest.raises(ValueError, match="weights"):
        Lattice(**{**fields_, "weights": heavy})
    with pytest.raises(ValueError, match="boundary"):
        Lattice(**{**fields_, "boundary": "open"})


@pytest.mark.parametrize(
    "call, word",
    [
        (lambda: chain(0), "N"),
        (lambda: chain(2.5), "N"),
        (lambda: chain(True), "N"),
        (lambda: chain(5, "open"), "boundary"),
        (lambda: chain(5, ["fixed"]), "boundary"),
        (lambda: chain(5, weight=-1.0), "weight"),
        (lambda: chain(5, weight=float("nan")), "weight"),
        (lambda: square(0, 3), "nx"),
        (lambda: square(3, 1.0), "ny"),
        (lambda: square(3, 3, weights=(1.0,)), "weights"),
        (lambda: square(3, 3, weights=1.0), "weights"),
        (lambda: square(3, 3, weights=(1.0, -0.5)), r"weights\[1\]"),
        (lambda: triangular(3, 3, weights=(1.0, 1.0)), "weights"),
        (lambda: triangular(3, -1), "ny"),
        (lambda: chain(5).laplacian(np.zeros(4)), "u"),
        (lambda: chain(5).bond_energy(1.0), "u"),
        (lambda: chain(2).laplacian(np.ones(2, dtype=complex)), "u"),
        (lambda: chain(5).distances(5), "from_site"),
        (lambda: chain(5).distances(-1), "from_site"),
        (lambda: chain(5).colouring(0), "distance"),
        (lambda: chain(5).band_edges(0.0, 1.0), "M"),
        (lambda: chain(5).dispersion(0.3, 1.0, -1.0), "K"),
        (lambda: chain(5).stiffness_and_mass(1.0, float("inf")), "K"),
        (lambda: square(3, 3).lam(0.3), "q"),
        (lambda: triangular(3, 3).lam(np.zeros((3, 4))), "q"),
    ],
)
def test_arguments_are_validated(call, word):
    with pytest.raises(ValueError, match=word):
        call()


def test_small_periodic_axes_are_period_images():
    # a ring of 2 holds a double bond (model's), a ring of 1 a bond of zero length
    assert chain(2, "periodic").laplacian_matrix().toarray().tolist() == [[2.0, -2.0], [-2.0, 2.0]]
    assert chain(1, "periodic").laplacian_matrix().nnz == 0
    lat = triangular(2, 1, "periodic")
    assert set(itertools.chain.from_iterable(lat.neighbours.tolist())) == {0, 1}


# ----------------------------------------------------------------------------- the numpy reference on a lattice


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_the_reference_on_a_lattice_is_the_chain_bit_for_bit(boundary):
    """``LatticeParams`` through the numpy reference (the kernels' oracle): the chain as a lattice, a 1 x N strip
    and a square lattice without cross bonds (independent chains) give the chain's steps bit for bit."""
    from warpchain import ChainParams, reference
    from warpchain.lattice import LatticeParams

    rng = np.random.default_rng(7)
    N, ny = 17, 3
    cp = ChainParams(30.0, 10.0, N, boundary)
    x0 = 0.05 * rng.standard_normal((2, 4, N))
    want = reference.integrate("kahan8", cp, x0, 0.05, 40)["x"]
    for lat in (chain(N, boundary), square(N, 1, boundary, weights=(1.0, 0.0))):
        got = reference.integrate("kahan8", LatticeParams(30.0, 10.0, lat), x0, 0.05, 40)["x"]
        assert np.array_equal(got, want), lat
    rows = 0.05 * rng.standard_normal((2, 4, ny, N))
    plane = LatticeParams(30.0, 10.0, square(N, ny, boundary, weights=(1.0, 0.0)))
    got = reference.integrate("kahan8", plane, rows.reshape(2, 4, ny * N), 0.05, 40)["x"].reshape(2, 4, ny, N)
    one_by_one = reference.integrate("kahan8", cp, rows.transpose(0, 2, 1, 3).reshape(2 * ny, 4, N), 0.05, 40)["x"]
    assert np.array_equal(got, one_by_one.reshape(2, ny, 4, N).transpose(0, 2, 1, 3))


@pytest.mark.parametrize("build", [square, triangular])
def test_a_monolayer_on_the_reference_keeps_its_energy_and_its_symmetry(build):
    """A resonator kicked at the centre of an 11 x 11 patch: kahan8 keeps the energy to rounding, and the motion
    keeps every point symmetry of the patch (each maps the state onto itself)."""
    from warpchain import model, reference
    from warpchain.lattice import LatticeParams

    params = LatticeParams(30.0, 10.0, build(11, 11, "fixed"))
    x0 = np.zeros((1, 4, params.N))
    x0[0, 1, params.lattice.centre] = -0.3
    x = reference.integrate("kahan8", params, x0, 0.05, 400)["x"]
    e0, e1 = model.energy(params, x0)[0], model.energy(params, x)[0]
    assert abs(e1 - e0) <= 1e-12 * e0 and np.abs(x[0, 0]).max() > 1e-3  # it spread to the neighbours
    for name, p in params.lattice.symmetries().items():
        if p[params.lattice.centre] == params.lattice.centre:
            np.testing.assert_allclose(x[0][:, p], x[0], rtol=0, atol=1e-14, err_msg=name)


@pytest.mark.parametrize("build", [square, triangular])
def test_long_wave_curvature_and_the_monolayer_coupling(build):
    """lam(q) = kappa |k|^2 for small cartesian k in every direction (isotropic to O(k^4)); the lattice at
    K / kappa has the chain's long-wave acoustic speed at K (``physical.monolayer_coupling``)."""
    from warpchain.physical import monolayer_coupling

    lat = build(5, 5)
    eps = 1e-4
    for theta in np.linspace(0.0, np.pi, 7):
        k = eps * np.array([np.cos(theta), np.sin(theta)])
        q = lat.basis @ k  # axial Bloch numbers: q_i = k . a_i
        assert abs(lat.lam(q) / eps**2 - lat.long_wave_curvature) < 1e-6
    assert chain(5).long_wave_curvature == 1.0
    M, K = 30.0, 160.0
    K_lattice = monolayer_coupling(K, lat)
    speed = np.sqrt(lat.long_wave_curvature * K_lattice / (M + 1.0))
    assert abs(speed - np.sqrt(K / (M + 1.0))) < 1e-14
    assert abs(K_lattice - (K / 1.5 if build is triangular else K)) < 1e-12
