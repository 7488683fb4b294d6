"""Bad input at the public boundary: a clear ValueError (or a documented result), never a silent answer."""

import warnings

import numpy as np
import pytest

import continuation as ct
import warpchain as wc

P = wc.ChainParams(3.0, 4.0, 11)
X = np.zeros((4, 11))
X[1, 5] = -0.3


def test_numpy_scalars_and_0d_arrays_are_numbers():
    for t_final, dt in ((np.int64(1), np.int64(1) / 10), (np.array(1.0), np.float32(0.1)), (1, 0.1)):
        assert wc.simulate(P, X, t_final, dt, device="cpu").nsteps == 10
    assert wc.ChainParams(np.float64(3.0), np.array(4.0), np.int32(11)).N == 11


@pytest.mark.parametrize(
    "options, match",
    [
        (lambda: dict(guard=wc.Guard(max_energy_error=-1)), "Guard.max_energy_error"),
        (lambda: dict(guard=wc.Guard(chunks=-3)), "Guard.chunks"),
        (lambda: dict(guard=wc.Guard(chunks=2.5)), "Guard.chunks"),
        (lambda: dict(record=wc.Record(every=1000)), "larger than the run"),
        (lambda: dict(record=wc.Record(every=0)), "Record.every"),
        (lambda: dict(placement=wc.Placement(layout="grid")), "Placement.layout"),
    ],
)
def test_simulate_options_are_range_checked(options, match):
    with pytest.raises(ValueError, match=match):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", **options())


def test_the_flat_keywords_of_earlier_releases_still_work_with_a_warning():
    """``save_every=``, ``chunks=``, ``layout=`` ... fold into the options with one DeprecationWarning naming
    them; a keyword beside its own option object, a frames array without save_every, an unknown keyword or
    an option of the wrong type are refused."""
    new = wc.simulate(P, X, 1.0, 0.1, device="cpu", record=wc.Record(every=2), guard=wc.Guard(chunks=2))
    with pytest.warns(DeprecationWarning, match=r"record=Record\(every=...\); guard=Guard\(chunks=...\)"):
        old = wc.simulate(P, X, 1.0, 0.1, device="cpu", save_every=2, chunks=2)
    assert np.array_equal(old.u, new.u) and np.array_equal(old.energy_t, new.energy_t)
    with pytest.raises(ValueError, match="given beside guard="):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", chunks=2, guard=wc.Guard(chunks=3))
    with pytest.raises(ValueError, match="give save_every too"):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", frames_out=(np.zeros((11, 1, P.N)), np.zeros((11, 1, P.N))))
    with pytest.raises(TypeError, match="unexpected keyword argument 'save_evry'"):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", save_evry=2)
    with pytest.raises(TypeError, match="record must be a warpchain.Record"):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", record=2)


@pytest.mark.parametrize(
    "t_final, dt, match",
    [
        (1j, 0.1, "t_final"),
        (-1.0, 0.1, "t_final"),
        (1.0, 0.0, "dt"),
        (1.0, np.nan, "dt"),
        (True, 0.1, "t_final"),
        ("1", 0.1, "t_final"),
    ],
)
def test_bad_times_are_refused(t_final, dt, match):
    with pytest.raises(ValueError, match=match):
        wc.simulate(P, X, t_final, dt, device="cpu")


def test_states_are_checked_wherever_they_enter():
    with pytest.raises(ValueError, match="complex"):
        wc.simulate(P, X + 1j, 1.0, 0.1, device="cpu")
    with pytest.raises(ValueError, match=r"shape \(4, 11\)"):
        wc.energy(P, np.zeros((4, 12)))
    with pytest.raises(ValueError, match="shape"):
        wc.energy(P, np.zeros(7))
    with pytest.raises(ValueError, match="batch of 2"):
        ct.find_breather(P, 1.01, np.stack([X, X]))


def test_model_functions_refuse_unphysical_parameters():
    with pytest.raises(ValueError, match="M must be > 0"):
        wc.band_edges(-1, 160)
    with pytest.raises(ValueError, match="K must be >= 0"):
        wc.band_edges(30, -1)


def test_newton_and_floquet_options():
    q = wc.ChainParams(30.0, 160.0, 21)
    with pytest.raises(ValueError, match="max_iterations"):
        ct.find_breather(q, 1.01, ct.nls_seed(q, 1.01), max_iterations=-1)
    with pytest.raises(ValueError, match="tol"):
        ct.find_breather(q, 1.01, ct.nls_seed(q, 1.01), tol=-1.0)
    with pytest.raises(TypeError, match="ShootingResult"):
        ct.floquet("b")


def test_an_nls_seed_in_the_acoustic_band_warns():
    q = wc.ChainParams(30.0, 40.0, 41)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ct.nls_seed(q, 0.99)
    assert any("acoustic band" in str(w.message) for w in caught)


def test_a_flat_keyword_beside_its_option_object_is_refused_and_none_means_the_default():
    with pytest.raises(ValueError, match="every given beside record="):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", record=wc.Record(every=1), save_every=5)
    with pytest.raises(ValueError, match="on_chunk given beside record="):
        wc.simulate(P, X, 1.0, 0.1, device="cpu", record=wc.Record(every=5), on_chunk=print)
    with pytest.warns(DeprecationWarning):  # as before: no save_every, nothing recorded, on_chunk never called
        assert wc.simulate(P, X, 1.0, 0.1, device="cpu", on_chunk=print).u is None
    run = wc.simulate(P, X, 1.0, 0.1, device="cpu", guard=None, placement=None)  # None: the defaults
    assert run.nsteps == 10 and run.layout == "thread"
    with pytest.warns(DeprecationWarning):  # None beside a flat keyword of the same option: the default plus it
        run = wc.simulate(P, X, 1.0, 0.1, device="cpu", guard=None, chunks=2, placement=None, layout="thread")
    assert run.stats["chunks"] == 2 and run.layout == "thread"


def test_overlapping_tuning_overrides_leave_nothing_behind():
    from warpchain.engine import tuning

    base = tuning.active()
    a = tuning.override(slices=3)
    b = tuning.override(max_slices=5)
    a.__enter__()
    b.__enter__()
    a.__exit__(None, None, None)  # out of order, as two threads could
    assert tuning.active().max_slices == 5
    b.__exit__(None, None, None)
    assert tuning.active() == base
    with pytest.raises(RuntimeError):
        with tuning.override(chunk_work=7):
            assert tuning.active().chunk_work == 7
            raise RuntimeError
    assert tuning.active() == base
