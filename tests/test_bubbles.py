"""The bubble predictor (``continuation.bubbles``) against closed forms, and on a branch."""

import types

import numpy as np
import pytest

from continuation import bubbles
from continuation.floquet import ParityBlock, SpectralData


def _point(Mu, signature, tolerance=1e-12):
    """A stand-in for an analysed branch point: Mu, its eigen-decomposition and signatures."""
    mu, R = np.linalg.eig(Mu)
    order = np.argsort(mu.real)
    mu, R = mu[order], R[:, order]
    spectral = SpectralData((ParityBlock(0, None, Mu, None, 0.0, mu, R),))
    return types.SimpleNamespace(spectral=spectral, mu=mu, signature=np.asarray(signature), tolerance=tolerance)


def _predict(a, b):
    return bubbles.predict(a, b, a.spectral, b.spectral)


def test_a_krein_collision_of_a_linear_family_is_predicted_exactly():
    # Mu(t) = diag(m) + t D with a 2 x 2 coupling of opposite sign (what opposite signatures allow)
    # between two multipliers that pass each other, and a third far away
    m = np.array([0.30, 0.50, -0.70])
    D = np.array([[0.4, 0.02, 0.0], [-0.03, -0.2, 0.0], [0.0, 0.0, 0.1]])
    a, b = _point(np.diag(m), [1, -1, 1]), _point(np.diag(m) + D, [1, -1, 1])
    # Points a is sorted by mu: -0.7 (+1), 0.3 (+1), 0.5 (-1)
    a.signature = np.array([1, 1, -1])
    found = _predict(a, b)
    assert len(found) == 1
    x = found[0]
    d0, d1, c = 0.3 - 0.5, 0.4 + 0.2, 0.02 * -0.03
    q = d1 * d1 + 4 * c
    assert x.t == pytest.approx(-d0 * d1 / q, rel=1e-12)
    assert x.half_width == pytest.approx(abs(d0) * np.sqrt(-4 * c) / q, rel=1e-12)
    # the exact eigenvalues of Mu(t) at the predicted centre: the same complex pair
    exact = np.linalg.eigvals(np.diag(m) + x.t * D)
    assert np.max(exact.imag) == pytest.approx(x.mu.imag, rel=1e-12)
    assert x.mu.real == pytest.approx(exact[np.argmax(exact.imag)].real, rel=1e-12)
    # the bubble's edges: real eigenvalues just outside, complex just inside
    for t, inside in ((x.t - 0.99 * x.half_width, True), (x.t - 1.01 * x.half_width, False)):
        assert (np.max(np.abs(np.linalg.eigvals(np.diag(m) + t * D).imag)) > 0) == inside


def test_equal_signatures_pass_through_and_nothing_is_predicted():
    m = np.array([0.30, 0.50])
    D = np.array([[0.4, 0.02], [0.03, -0.2]])  # same-sign coupling: real eigenvalues throughout
    a, b = _point(np.diag(m), [1, 1]), _point(np.diag(m) + D, [1, 1])
    assert _predict(a, b) == []
    a.signature = np.array([1, -1])  # opposite signatures with a coupling that cannot make a bubble
    assert _predict(a, b) == []


def test_chase_plan_keeps_wide_bubbles_and_a_point_between_neighbours():
    B = bubbles.Bubble
    found = [
        B(0.30, 0.01, 0.9 + 1e-4j, 1.001, 1),
        B(0.305, 0.01, 0.9 + 2e-4j, 1.002, 1),  # the same bubble from another pair: counted once
        B(0.34, 0.02, 0.9 + 1e-4j, 1.001, 1),  # a neighbour whose margin overlaps
        B(0.7, 1e-6, 0.5j, 1.1, 1),  # too narrow
    ]
    plan = bubbles.chase_fractions(found, step=1.0, min_width=1e-3)
    assert [c for c, _ in plan] == [0.305, 0.34]
    (_, (lo1, hi1)), (_, (lo2, hi2)) = plan
    assert 0.0 < lo1 < 0.305 and hi1 == pytest.approx(0.32) and 0.34 < hi2 < 1
    assert lo2 == pytest.approx(0.3225)  # not past the middle between the two centres


@pytest.mark.slow  # a few seconds: the fast set stays under 90 s on 2 cores
def test_predicted_bubbles_match_bisecting_every_pass_at_a_fraction_of_the_solves():
    # the paper chain at N = 41, where bisecting every opposite-signature pass ("all") is affordable
    # and finds every bubble wider than the resolution: the frequency branch from the optical band edge
    # into the gap (1.0165 -> 1.009) crosses nine stability changes (a period-doubling window and bubbles)
    from continuation.branch import continue_in_frequency
    from continuation.driver import ContinuationSettings
    from warpchain import ChainParams, Flow

    p = ChainParams(30.0, 160.0, 41)
    runs = {}
    for mode in ("all", "predict"):
        s = ContinuationSettings(ds=0.05, ds_min=1e-4, ds_max=0.6, grow=1.3, resolution=1e-3, bisect_krein=mode)
        runs[mode] = continue_in_frequency(p, None, omega_min=1.009, flow=Flow("kahan8", 32, "cpu"), settings=s)
    every, predicted = ([c for c in runs[m].stability_changes() if min(c["bracket"]) > 1.009] for m in runs)
    assert len(every) >= 9
    for change in every:  # each change is found, its bracket within a few resolutions (2e-5 in w_b each)
        centre = np.mean(change["bracket"])
        assert min(abs(np.mean(c["bracket"]) - centre) for c in predicted) < 1e-5, centre
        assert any(c["from_stable"] == change["from_stable"] for c in predicted)
    assert runs["predict"].stats["bubbles_confirmed"] >= 4
    omega = runs["predict"].column("omega")
    assert np.all(np.diff(omega) < 0)  # every solve a new point, in order along the branch
    assert runs["predict"].stats["solves"] < 0.5 * runs["all"].stats["solves"]
    # bubbles too narrow to chase are recorded per final step and merged into stretches on the branch
    foam = [e for e in runs["predict"].events if e["type"] == "bubble_foam"]
    assert len(foam) == runs["predict"].stats["foam_steps"]
    assert all(tuple(e["bracket"]) in set(zip(omega[:-1], omega[1:])) for e in foam)
    for stretch in runs["predict"].unresolved_bubbles():
        lo, hi = sorted((stretch["start"], stretch["end"]))
        assert omega.min() <= lo and hi <= omega.max()
        assert 0.0 <= stretch["unstable_fraction"] <= 1.0 and stretch["predicted"] >= 1


def test_covered_fraction_is_the_union_of_predicted_extents_clipped_to_the_step():
    B = bubbles.Bubble
    found = [B(0.2, 0.05, 0.5 + 1e-4j, 1.0001, 1), B(0.22, 0.05, 0.5 + 1e-4j, 1.0001, 1), B(0.99, 0.05, 0j, 1.0, 1)]
    # [0.15, 0.27] merged from the two overlapping ones, [0.94, 1.0] clipped at the step's end
    assert bubbles.covered_fraction(found) == pytest.approx(0.12 + 0.06)
    assert bubbles.covered_fraction([]) == 0.0


def _on_branch(**fields):
    """A stand-in for a ``BranchPoint``: its fields, and ``value(name)`` for the parameter ``name``."""
    point = types.SimpleNamespace(**fields)
    point.value = lambda name: getattr(point, name)
    return point


def _branch_point(K, stable, modulus=1.0, localized=False):
    inst = () if stable else (types.SimpleNamespace(localized=localized, kind="complex_quadruplet", mu=0.5 + 1e-5j),)
    return _on_branch(K=K, stable=stable, max_modulus=modulus, instabilities=inst)


def test_unresolved_bubble_stretches_join_foam_steps_across_weakly_unstable_points_only():
    from continuation import events as ev

    B = bubbles.Bubble
    pts = [
        _branch_point(1.0, True),
        _branch_point(2.0, True),
        _branch_point(3.0, False, 1.00002),  # a foam bubble caught by a branch point
        _branch_point(4.0, False, 1.00003),
        _branch_point(5.0, True),
        _branch_point(6.0, True),
        _branch_point(7.0, False, 1.00002, localized=True),  # a localized instability is not foam
        _branch_point(8.0, False, 1.00002, localized=True),
    ]
    narrow = [B(0.5, 0.1, 0.5 + 1e-5j, 1.00001, 1)]
    events = [ev.foam_event(pts[i], pts[i + 1], "K", narrow, 1.0) for i in (1, 4, 5)]
    events.append({"type": "stability_change", "bracket": [2.0, 3.0]})
    out = ev.unresolved_bubbles(pts, events, "K")
    # steps 2-3 (foam) and 3-4 (both ends weakly unstable, extended) join; 4-5 ends stable; 7-8 is localized
    assert [(s["start"], s["end"]) for s in out] == [(2.0, 4.0), (5.0, 7.0)]
    first = out[0]
    assert first["steps"] == 2 and first["predicted"] == 1
    assert first["unstable_fraction"] == pytest.approx(0.2)  # weighted over the predicted steps only
    assert first["unstable_points"] == 2 and first["max_modulus"] == pytest.approx(1.00003)
    assert out[1]["steps"] == 2 and out[1]["predicted"] == 2


def test_parametric_resonance_opens_where_the_acoustic_top_passes_half_the_frequency():
    from scipy.optimize import brentq

    from continuation import events as ev
    from warpchain.model import band_edges

    K_star = brentq(lambda K: band_edges(30.0, K)["acoustic_top"] - 0.505, 1.0, 3.0, xtol=1e-14)
    assert (1, "AA") not in ev.parametric_orders(30.0, K_star - 1e-6, 1.01)
    assert (1, "AA") in ev.parametric_orders(30.0, K_star + 1e-6, 1.01)
    a, b = (_on_branch(K=k, omega=1.01) for k in (1.864, 2.018))
    e = ev.parametric_event(a, b, "K", 30.0)
    assert e["opened"] == [[1, "AA"]] and e["closed"] == [] and e["at"] == pytest.approx(K_star, abs=1e-12)
    assert ev.parametric_event(a, a, "K", 30.0) is None
    # a foam stretch starting in the next step begins at the opening, not at its first recorded step
    pts = [_branch_point(1.864, True), _branch_point(2.018, True), _branch_point(2.274, True)]
    narrow = [bubbles.Bubble(0.5, 0.05, 0.5 + 1e-5j, 1.00001, 1)]
    out = ev.unresolved_bubbles(pts, [e, ev.foam_event(pts[1], pts[2], "K", narrow, 1.0)], "K")
    assert len(out) == 1 and out[0]["start"] == pytest.approx(K_star) and "n = 1 (AA) opened" in out[0]["onset"]
