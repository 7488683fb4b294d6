"""A branch in a zarr v3 group, written point by point through the driver's ``on_point`` hook.

Layout (group ``branch`` of ``data.zarr``): one chunk per point along ``point``; scalars per point
(K, omega, energy, max_modulus, tolerance, min_contact, iterations, s, stable), the state
(point, component, site), the reduced multipliers mu (point, pair) with their Krein signature,
parity, participation and central weight, the Newton residuals (point, newton_iteration), and the
instabilities (point, instability; kind, mu, participation, central weight, localized, parity; at
most ``MAX_INSTABILITIES`` per point, largest first; ``instability_count`` holds all of the point's, so a
reader sees where the list is cut). Scenes with several branches (``site-bond``)
keep one such group per family in one store. Float arrays have a NaN
fill value and integer arrays a -128 fill value, so a missing chunk can never read as a valid point.
The group's attributes hold ``n_points`` (updated after every whole point), ``complete``,
``stop_reason``, ``message`` and ``events``. ``checksum`` (point, array) holds the CRC-32 of every
array's row of every point (started from the point's index), written after the rows, in the order of
the group's ``checksum_arrays`` attribute: a row lost, altered, or swapped with another point's (two
valid chunks exchanged) no longer matches, and ``n_points`` must agree with the checksum rows.

``load_branch`` validates what it reads (every array has ``n_points`` rows and matches its checksum;
states, parameters and multipliers finite; frequencies and couplings positive; flags in range; every
array the writer writes is checked, integer ones included) and raises ``StoreError``
naming the store, the array and the point; a damaged point is never returned, so it is never resumed
from.
"""

from __future__ import annotations

import json
import queue
import threading
from pathlib import Path

import numpy as np

from continuation.results import Branch, BranchPoint, WalkState
from continuation.floquet import KINDS, Instability, multipliers_from_mu, outer_modulus
from continuation.shooting import frequency_report
from warpchain.variables import describe
from warpchain import ChainParams
from warpchain import store
from warpchain.store import (
    check_attributes,
    consolidate,
    jsonable,
    open_store,
    provenance,
    unconsolidate,
    write_attributes,
)

MAX_INSTABILITIES = 16
CHECKSUM = "checksum"
#: points (and walk states) the background writer takes from its queue at once: written as one slab per array
BATCH = 256
#: points per chunk along ``point``, written once each when full (or after LINGER s): zarr's Python per chunk
#: and array competes with the computation for the GIL (quick K branch, N = 101, 2-core CPU: +30 % branch time
#: with 16 points per chunk, +12-17 % with 64; one chunk per point had made the scene 3x slower)
CHUNK = 64
#: seconds a computed point may wait for its chunk to fill before it is written anyway
LINGER = 2.0
_LINGER = object()  # what the writer's queue gives when LINGER seconds passed without an item
INT_FILL = -128


StoreError = store.StoreError  # one error type for every damaged store (names store, array and point)


def _float(shape):
    return shape, "f8", np.nan


def _int(shape):
    return shape, "i1", INT_FILL


def _array_spec(N: int, max_newton: int) -> dict:
    """name -> (shape of one point, dtype, fill value) of every array a branch group holds."""
    spec = {name: _float(()) for name in ("K", "omega", "energy", "max_modulus", "tolerance", "min_contact", "s")}
    spec.update(
        {
            "iterations": _int(()),
            "stable": _int(()),
            "floquet_complete": _int(()),
            "state": _float((4, N)),
            "mu_real": _float((2 * N,)),
            "mu_imag": _float((2 * N,)),
            "signature": _int((2 * N,)),
            "parity": _int((2 * N,)),
            "participation": _float((2 * N,)),
            "central_weight": _float((2 * N,)),
            "newton_residuals": _float((max_newton + 1,)),
            "instability_kind": _int((MAX_INSTABILITIES,)),
            "instability_mu_real": _float((MAX_INSTABILITIES,)),
            "instability_mu_imag": _float((MAX_INSTABILITIES,)),
            "instability_participation": _float((MAX_INSTABILITIES,)),
            "instability_central_weight": _float((MAX_INSTABILITIES,)),
            "instability_localized": _int((MAX_INSTABILITIES,)),
            "instability_parity": _int((MAX_INSTABILITIES,)),
            "instability_count": ((), "i4", -1),  # all of the point's: above MAX_INSTABILITIES, the rows are cut
        }
    )
    return spec


class BranchStore:
    """Writes a branch to a zarr group, one whole point (one chunk of every array) at a time.

    Args:
        path: the store (``.../data.zarr``); group: the group's name.
        params: the chain (root attribute ``params``).
        attrs: the group's attributes (what was continued, how).
        max_newton: Newton iterations stored per point.
        resume: open an existing group and append to it (its points are checked first).
        keep: with ``resume``, the stored points to keep (those of the last completed step: the walk
            state's ``points``); later ones are written again by the resumed walk.
        device: for provenance.
        new_store: start a new store (False: add the group to an existing one, as scenes with
            several branches do).
    """

    def __init__(
        self,
        path,
        group: str,
        params: ChainParams,
        attrs: dict,
        *,
        max_newton: int = 40,
        resume: bool = False,
        keep: int | None = None,
        device=None,
        new_store: bool = True,
    ):
        self.path, self.group_name, self.params, self.max_newton = Path(path), group, params, int(max_newton)
        self._thread: threading.Thread | None = None  # the background writer (``background``)
        self._queue: queue.Queue = queue.Queue()
        self._error: BaseException | None = None
        N = params.N
        root = open_store(
            self.path,
            params=params.as_dict(),
            provenance_info=provenance(device),
            mode="w" if new_store and not resume else "a",
        )
        g = root.require_group(group)
        self.group = g
        spec = _array_spec(N, self.max_newton)
        dims = {"state": ("point", "component", "site"), "newton_residuals": ("point", "newton_iteration")}
        for name in ("mu_real", "mu_imag", "signature", "parity", "participation", "central_weight"):
            dims[name] = ("point", "pair")
        for name in spec:
            if name.startswith("instability_") and name != "instability_count":
                dims[name] = ("point", "instability")
        existing = set(g.array_keys()) if resume else set()
        if resume and existing and CHECKSUM not in existing:
            raise StoreError(
                f"{self.path}/{group}: written before points carried checksums; recompute the branch "
                "(run the scene without --resume)"
            )
        self.arrays = {}
        for name, (shape, dtype, fill) in spec.items():
            if name in existing:
                self.arrays[name] = g[name]
            else:
                self.arrays[name] = g.create_array(
                    name,
                    shape=(0, *shape),
                    chunks=(CHUNK, *shape),
                    dtype=dtype,
                    fill_value=fill,
                    dimension_names=dims.get(name, ("point",)),
                    overwrite=True,
                    attributes=describe(name, group, integer=np.dtype(dtype).kind == "i"),
                )
        names = list(self.arrays)
        if CHECKSUM in existing:
            self.checksum = g[CHECKSUM]
        else:
            self.checksum = g.create_array(
                CHECKSUM,
                shape=(0, len(names)),
                chunks=(CHUNK, len(names)),
                dtype="i8",
                fill_value=-1,
                dimension_names=("point", "stored_array"),
                overwrite=True,
                attributes=describe(CHECKSUM, group),
            )
        if not resume:
            write_attributes(
                g,
                {
                    "checksum_arrays": names,
                    **jsonable(attrs),
                    "complete": False,
                    "n_points": 0,
                    "events": [],
                    "stop_reason": None,
                    "kinds": list(KINDS),
                },
            )
        else:
            n = self.n_points if keep is None else min(int(keep), self.n_points)
            write_attributes(g, {"complete": False, "stop_reason": None, "n_points": n})
        # consolidated metadata (what xarray reads first) is written by finish and interrupted; while the
        # arrays grow there is none, so a killed run never leaves a stale one (rewriting it after every point
        # cost 13 ms of a 49 ms append)
        unconsolidate(self.path)

    @property
    def n_points(self) -> int:
        return int(self.group.attrs.get("n_points", 0))

    # ------------------------------------------------------------------ writing behind the computation
    def background(self) -> "BranchStore":
        """Write appended points on a thread of their own from now on, so that the next point is computed
        while this one is written (an append is ~50 ms of zarr work per point at N = 201, 1/3 of a
        point's time on an H200). ``flush``, ``finish`` and ``interrupted`` wait until every queued
        point is written; an error on the thread is raised there (and by the next ``append``)."""
        if self._thread is None:
            self._drained = threading.Event()
            self._thread = threading.Thread(target=self._drain, name=f"store {self.group_name}", daemon=True)
            self._thread.start()
        return self

    def _drain(self) -> None:
        """The writer: points are written when they fill the chunk they end in (each chunk written once, in
        one slab per array), or when they have waited ``LINGER`` seconds, or on ``flush``; a walk state after
        its points. What a SIGKILL loses (at most a chunk's points, or ``LINGER`` seconds of them) a resume
        computes again, the same to the bit."""
        try:
            self._drain_queue()
        finally:
            self._drained.set()

    def _drain_queue(self) -> None:
        import time as _time

        pending, state, since, done = [], None, None, False
        while not done:
            timeout = None if since is None else max(0.0, LINGER - (_time.perf_counter() - since))
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                item = _LINGER
            if item is None:
                done = True
            elif isinstance(item, WalkState):
                state = item
            elif item is not _LINGER:
                pending.append(item)
                since = since or _time.perf_counter()
            full = pending and (self.n_points + len(pending)) % CHUNK == 0
            if self._error is None and (done or full or item is _LINGER or len(pending) >= BATCH):
                try:  # the points, and in the same attribute write the last state whose points are all in
                    ready = state if state is not None and state.points <= self.n_points + len(pending) else None
                    if pending:
                        self._write_points(pending, ready)
                    elif ready is not None:
                        self._write_state(ready)
                    if ready is not None:
                        state = None
                except BaseException as exc:  # raised to the caller by append/flush
                    self._error = exc
                pending, since = [], None

    def flush(self) -> None:
        """Wait until every queued point is written (no-op without ``background``)."""
        if self._thread is not None:
            self._queue.put(None)
            # Ctrl-C or SIGTERM (KeyboardInterrupt) while the writer drains: let it finish, then raise. Not
            # Thread.join: an interrupted join marks the thread as ended while it still writes (CPython 3.11,
            # cpython#90882), and the store was marked interrupted with reported points still in the queue
            interrupt = None
            while not self._drained.is_set():
                try:
                    self._drained.wait(0.05)
                except KeyboardInterrupt as exc:
                    interrupt = exc
            self._thread = None
            if interrupt is not None:
                raise interrupt
        self._raise_error()

    def _raise_error(self) -> None:
        if self._error is not None:
            raise StoreError(f"{self.path}/{self.group_name}: writing a point failed: {self._error!r}") from self._error

    def append(self, point: BranchPoint) -> None:
        """Write one point (queued when ``background`` is on); ``n_points`` is raised only after every
        array holds it."""
        self._submit(point, self._write)

    def step(self, state: WalkState) -> None:
        """Record the walk's state after a completed step (queued behind its points with ``background``):
        the events so far and ``walk_state``, from which ``--resume`` continues exactly."""
        self._submit(state, self._write_state)

    def _submit(self, item, write) -> None:
        self._raise_error()
        if self._thread is not None:
            self._queue.put(item)
        else:
            write(item)

    def _write_state(self, state: WalkState) -> None:
        if state.points > self.n_points:
            where = f"{self.path}/{self.group_name}"
            raise StoreError(f"{where}: walk state after {state.points} points, {self.n_points} stored")
        write_attributes(self.group, self._state_attrs(state))

    @staticmethod
    def _state_attrs(state: WalkState) -> dict:
        return {"walk_state": jsonable(state.as_dict()), "events": jsonable(list(state.events))}

    def _rows(self, point: BranchPoint) -> dict:
        """name -> the point's row of every array, as stored."""
        N2 = 2 * self.params.N
        inst = list(point.instabilities)[:MAX_INSTABILITIES]

        def table(fn, fill):
            out = np.full(MAX_INSTABILITIES, fill, dtype=float)
            out[: len(inst)] = [fn(i) for i in inst]
            return out

        hist = np.full(self.max_newton + 1, np.nan)
        h = np.asarray(point.residual_history, dtype=float)[: self.max_newton + 1]
        hist[: len(h)] = h

        def padded(a, fill):
            """A point's per-mu array as a row of 2N: all of them (dense Floquet), the window's first with the
            fill after (a window, as stores before 2026-11-27 could hold), or the fill alone (no Floquet)."""
            out = np.full(N2, fill)  # complex, float or int, as the fill
            if a is not None:
                out[: len(a)] = a
            return out

        mu = padded(point.mu, np.nan + 0j)

        def ints(a):
            return padded(a, INT_FILL)

        values = {
            "K": point.K,
            "omega": point.omega,
            "energy": point.energy,
            "max_modulus": point.max_modulus,
            "tolerance": point.tolerance,
            "min_contact": point.min_contact,
            "s": point.s,
            "iterations": point.iterations,
            "stable": INT_FILL if point.stable is None else int(point.stable),
            "floquet_complete": int(point.complete),
            "state": point.state,
            "mu_real": np.real(mu),
            "mu_imag": np.imag(mu),
            "signature": ints(point.signature),
            "parity": ints(point.parity),
            "participation": padded(point.participation, np.nan),
            "central_weight": padded(point.central_weight, np.nan),
            "newton_residuals": hist,
            "instability_kind": table(lambda i: KINDS.index(i.kind), INT_FILL),
            "instability_mu_real": table(lambda i: i.mu.real, np.nan),
            "instability_mu_imag": table(lambda i: i.mu.imag, np.nan),
            "instability_participation": table(lambda i: i.participation, np.nan),
            "instability_central_weight": table(lambda i: i.central_weight, np.nan),
            "instability_localized": table(lambda i: int(i.localized), INT_FILL),
            "instability_parity": table(lambda i: i.parity, INT_FILL),
            "instability_count": len(point.instabilities),
        }
        return {
            name: np.asarray(values[name], dtype=arr.dtype).reshape(arr.shape[1:]) for name, arr in self.arrays.items()
        }

    def _write(self, point: BranchPoint) -> None:
        self._write_points([point])

    def _write_points(self, points: list, state: WalkState | None = None) -> None:
        """Points n .. n + k - 1 in one write per array (zarr writes the k chunks at once), then their
        checksums, then ``n_points``: a group commit, so a writer that fell behind catches up."""
        n = self.n_points
        rows = [self._rows(p) for p in points]
        crc = np.array([[row_checksum(r[name], n + i) for name in self.arrays] for i, r in enumerate(rows)])
        slabs = [(a, np.stack([r[name] for r in rows])) for name, a in self.arrays.items()]
        store.append_rows(slabs, [(self.checksum, crc)], start=n)  # the checksums after the rows
        # the count and the walk state in one write of the group's metadata: never a count without its state
        write_attributes(
            self.group, {"n_points": n + len(points), **(self._state_attrs(state) if state is not None else {})}
        )

    def finish(self, branch: Branch) -> None:
        self.flush()
        write_attributes(
            self.group,
            {
                "complete": True,
                "stop_reason": branch.stop_reason.value,
                "message": branch.message,
                "events": jsonable(list(branch.events)),
                "stats": jsonable(branch.stats),
            },
        )
        consolidate(self.path)

    def interrupted(self, why: str) -> None:
        self.flush()
        write_attributes(self.group, {"complete": False, "stop_reason": "interrupted", "message": why})
        consolidate(self.path)


def row_checksum(row: np.ndarray, point: int) -> int:
    """CRC-32 of point ``point``'s row of an array, as stored (dtype and shape of the array's chunk),
    started from the point's index: a whole point moved to another index no longer matches either."""
    return store.crc32(row, point)


def _fail(path, group, name, i, what):
    where = f"array '{name}'" + (f", point {i}" if i is not None else "")
    raise StoreError(
        f"damaged branch store {path} (group '{group}', {where}): {what}. Recompute the branch "
        f"(run the scene without --resume), or resume from a copy whose damaged points were removed"
    )


def load_branch(path, group: str = "branch") -> tuple[ChainParams, list, dict]:
    """Read and validate a stored branch: (params, points, group attributes).

    Raises:
        StoreError: the store or group is missing, unreadable or damaged (names the array and point).
    """
    import zarr

    path = Path(path)
    if not path.exists():
        raise StoreError(f"no branch store at {path}: run the scene first (without --resume)")
    try:
        root = zarr.open_group(str(path), mode="r", zarr_format=3, use_consolidated=False)
        hint = "recompute the branch (run the scene without --resume)"
        check_attributes(f"branch store {path} (root)", dict(root.attrs), hint)
        params = ChainParams(**dict(root.attrs)["params"])
        g = root[group]
        attrs = dict(g.attrs)
        check_attributes(f"branch store {path} (group '{group}')", attrs, hint)
        names = list(g.array_keys())
    except StoreError:
        raise
    except (KeyError, ValueError, TypeError, json.JSONDecodeError, OSError) as exc:
        raise StoreError(
            f"cannot read branch store {path} (group '{group}'): {type(exc).__name__}: {exc}. "
            "Recompute the branch (run the scene without --resume)"
        ) from None
    n = attrs.get("n_points")
    if not isinstance(n, int) or n < 0:
        _fail(path, group, "n_points (attribute)", None, f"not a point count: {n!r}")
    required = tuple(_array_spec(params.N, 0))  # every array the writer writes
    a = {}
    for name in names:
        try:
            arr = g[name]
            if arr.shape[0] < n:
                _fail(path, group, name, None, f"{arr.shape[0]} rows but the group says {n} points")
            a[name] = arr[:n]
        except StoreError:
            raise
        except Exception as exc:  # zarr raises many kinds on a corrupt chunk
            _fail(path, group, name, None, f"unreadable ({type(exc).__name__}: {exc})")
    for name in required:
        if name not in a:
            _fail(path, group, name, None, "missing")
    rows = g[CHECKSUM].shape[0] if CHECKSUM in names else n
    if rows < n or (attrs.get("complete") and rows != n):  # more rows than points: a batch being written
        _fail(path, group, CHECKSUM, None, f"{rows} rows but the group says {n} points")
    order = attrs.get("checksum_arrays")
    if CHECKSUM not in a or not isinstance(order, list) or sorted(order) != sorted(required):
        _fail(path, group, CHECKSUM, None, "missing, or not naming every array (a store older than checksums?)")
    for i in range(n):
        for k, name in enumerate(order):
            if int(a[CHECKSUM][i][k]) != row_checksum(a[name][i], i):
                if int(a[CHECKSUM][i][k]) == -1:
                    _fail(path, group, CHECKSUM, i, "reads as its fill value (a lost chunk)")
                row = a[name][i]
                fill = np.isnan(row).all() if row.dtype.kind == "f" else (row == INT_FILL).all()
                why = "reads as its fill value: a lost chunk" if fill else "an altered or misplaced chunk"
                _fail(path, group, name, i, f"does not match the point's checksum ({why})")
    N = params.N
    for i in range(n):
        for name in ("K", "omega", "energy", "min_contact"):
            if not np.isfinite(a[name][i]):
                _fail(path, group, name, i, "not a finite number (a missing or damaged chunk)")
        for name in ("K", "omega"):
            if a[name][i] <= 0:
                _fail(path, group, name, i, f"{a[name][i]} is not positive")
        if not np.isfinite(a["state"][i]).all():
            _fail(path, group, "state", i, "non-finite entries (a missing or damaged chunk)")
        complete = a["floquet_complete"][i]
        if complete not in (0, 1):
            _fail(path, group, "floquet_complete", i, f"flag {complete} is not 0 or 1 (a missing or damaged chunk)")
        if a["stable"][i] not in ((0, 1) if complete else (INT_FILL,)):
            allowed = "0 or 1 at a point with a complete verdict" if complete else f"{INT_FILL} (not decided)"
            _fail(path, group, "stable", i, f"flag {a['stable'][i]} where it must be {allowed} (a damaged chunk)")
        stored, count = int((a["instability_kind"][i] != INT_FILL).sum()), int(a["instability_count"][i])
        if count < stored or (stored < MAX_INSTABILITIES and count != stored):
            _fail(path, group, "instability_count", i, f"{count} with {stored} instabilities stored")
        if a["iterations"][i] < 0:
            _fail(path, group, "iterations", i, "negative (a missing or damaged chunk)")
        # a point with multipliers (finite max_modulus) has all of them, or the krylov window's first and NaN
        # after (never a gap); one without (a branch run with floquet=False) has none and is not marked stable:
        # anything else is damage
        mu_finite = np.isfinite(a["mu_real"][i]) & np.isfinite(a["mu_imag"][i])
        prefix = int(np.argmin(mu_finite)) if not mu_finite.all() else len(mu_finite)
        if np.isfinite(a["max_modulus"][i]) and (prefix == 0 or mu_finite[prefix:].any()):
            _fail(path, group, "mu_real", i, "non-finite multipliers at an analysed point (a missing or damaged chunk)")
        if not np.isfinite(a["max_modulus"][i]) and (mu_finite.any() or a["stable"][i] == 1):
            _fail(
                path, group, "max_modulus", i, "not a finite number at an analysed point (a missing or damaged chunk)"
            )
    points = []
    for i in range(n):
        mu = a["mu_real"][i] + 1j * a["mu_imag"][i]
        count = int(np.sum(np.isfinite(mu)))  # all 2N, or the krylov window's (a prefix, checked above)
        have_mu = count > 0
        mu = mu[:count]
        insts = []
        for k in range(MAX_INSTABILITIES):
            code = int(a["instability_kind"][i][k])
            if code == INT_FILL:
                break
            if not 0 <= code < len(KINDS):
                _fail(path, group, "instability_kind", i, f"unknown kind code {code}")
            imu = complex(a["instability_mu_real"][i][k], a["instability_mu_imag"][i][k])
            insts.append(
                Instability(
                    kind=KINDS[code],
                    mu=imu,
                    modulus=float(outer_modulus(np.array([imu]))[0]),
                    participation=float(a["instability_participation"][i][k]),
                    central_weight=float(a["instability_central_weight"][i][k]),
                    localized=bool(a["instability_localized"][i][k] == 1),
                    parity=int(a["instability_parity"][i][k]),
                )
            )
        hist = a["newton_residuals"][i]
        pr = params.replace(K=float(a["K"][i]))

        def ints(name):
            return None if (a[name][i] == INT_FILL).all() else a[name][i][:count].astype(int)

        points.append(
            BranchPoint(
                parameters={"K": float(a["K"][i]), "omega": float(a["omega"][i])},
                state=np.array(a["state"][i]),
                energy=float(a["energy"][i]),
                iterations=int(a["iterations"][i]),
                residual_history=tuple(hist[np.isfinite(hist)]),
                multipliers=multipliers_from_mu(mu) if have_mu else np.full(4 * N, np.nan + 0j),
                mu=mu if have_mu else None,
                signature=ints("signature") if have_mu else None,
                parity=ints("parity") if have_mu else None,
                participation=a["participation"][i][:count] if have_mu else None,
                central_weight=a["central_weight"][i][:count] if have_mu else None,
                max_modulus=float(a["max_modulus"][i]),
                tolerance=float(a["tolerance"][i]),
                stable=bool(a["stable"][i]) if a["floquet_complete"][i] else None,
                complete=bool(a["floquet_complete"][i]),
                instabilities=tuple(insts),
                min_contact=float(a["min_contact"][i]),
                harmonics_in_bands=tuple(frequency_report(pr, float(a["omega"][i]))["harmonics_in_bands"]),
                s=float(a["s"][i]),
            )
        )
    return params, points, attrs
