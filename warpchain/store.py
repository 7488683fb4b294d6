"""zarr v3 output: fields chunked along time and written in whole chunks, with parameters and
provenance in attributes, readable by ``xarray.open_zarr(path, group=...)``.

Layout of a store::

    data.zarr/                      root attrs: params, provenance
      <group>/                      attrs: complete, n_written, t_written (+ scene attributes)
        u, v  (t, site) or (t, lattice, site)   float64, chunked along t
        t     (t,)                              single chunk
        site  (site,)                           single chunk, 0-based site index

A run that stops half way leaves ``complete = false`` and ``n_written`` / ``t_written`` saying
how far it got; every chunk present is whole and readable.
"""

from __future__ import annotations

import datetime
import functools
import math
import os
import platform
import subprocess
import sys
import warnings
from importlib import metadata
from pathlib import Path

import numpy as np
import zarr

from .variables import describe


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


@functools.lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux)."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit() -> str | None:
    """Commit of the checkout this package runs from (with ``-dirty`` for local changes)."""
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        ).stdout.strip()
        if not commit:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def device_description(device: str | None) -> str:
    """Human-readable name of a Warp device (GPU model, or the CPU model for ``cpu``)."""
    if device is None or device == "cpu":
        return f"cpu ({cpu_model()}, {os.cpu_count()} cores)"
    try:
        import warp as wp

        return f"{device} ({wp.get_device(device).name})"
    except Exception:  # pragma: no cover - depends on the machine
        return device


#: the command as the user typed it, set by a front end (``python -m scenarios`` sets it); when
#: empty, provenance falls back to sys.argv (which shows a module's path, not what was typed)
COMMAND_LINE = ""


def provenance(device: str | None = None, **extra) -> dict:
    """Package versions, device, git commit, command line and time of a run, as plain JSON."""
    info = {
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command_line": COMMAND_LINE or " ".join(sys.argv),
        "git_commit": git_commit(),
        "device": device_description(device),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "packages": {
            name: _version(name)
            for name in ("warpchain", "warp-lang", "numpy", "scipy", "zarr", "matplotlib", "xarray")
        },
    }
    info.update(extra)
    return info


def jsonable(value):
    """Nested numpy scalars/arrays -> plain JSON values (NaN -> None, +-inf -> "inf"/"-inf"), for
    zarr attributes and summary.json alike."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def crc32(values: np.ndarray, seed: int = 0) -> int:
    """CRC-32 of an array's bytes (C order, as stored), started from ``seed``: written beside the data and
    checked by the readers (``read_group``; the branch store and the sweep seed it with the row's or the
    task's position, so that data moved to another place no longer match)."""
    import zlib

    values = np.ascontiguousarray(values)
    if values.dtype.kind in "fc" and np.isnan(values).any():  # one NaN: zarr does not write a chunk equal to
        values = np.where(np.isnan(values), values.dtype.type(np.nan), values)  # its fill value, and reads back
        # the canonical NaN for one whose NaNs had another sign or payload (inf - inf is -nan): same data, same sum
    return zlib.crc32(values.reshape(-1).view(np.uint8), int(seed))


#: the attribute holding the CRC-32 of a group's other attributes (``write_attributes``)
SIGNATURE = "attrs_crc32"


def attributes_checksum(attrs: dict) -> int:
    """CRC-32 of a group's attributes (all but ``SIGNATURE``) as canonical JSON: what a writer signed and a
    reader checks, so that an edited count, event list, column list, parameter or flag is caught."""
    import json
    import zlib

    body = {k: v for k, v in jsonable(dict(attrs)).items() if k != SIGNATURE}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return zlib.crc32(text.encode())


def write_attributes(group: zarr.Group, changes: dict) -> None:
    """Merge ``changes`` into a group's attributes and sign the result, in one write of its metadata (a kill
    leaves the old attributes or the new ones, each signed). The one way this package writes attributes."""
    merged = {**dict(group.attrs), **jsonable(changes)}
    group.update_attributes({**jsonable(changes), SIGNATURE: attributes_checksum(merged)})


def check_attributes(where: str, attrs: dict, hint: str = "rerun the scene that wrote it") -> None:
    """Refuse attributes that are not signed or do not match their signature (``write_attributes``)."""
    if SIGNATURE not in attrs:
        raise StoreError(
            f"{where}: its attributes carry no checksum (written by an earlier warpchain, or the checksum was "
            f"removed); {hint}"
        )
    if attrs[SIGNATURE] != attributes_checksum(attrs):
        raise StoreError(f"{where}: its attributes do not match their checksum (edited or damaged); {hint}")


def column_checksum(name: str, values: np.ndarray) -> int:
    """CRC-32 of a table column or coordinate, started from its name's: a column stored under another name
    (two swapped with their checksums) no longer matches."""
    import zlib

    return crc32(values, zlib.crc32(name.encode()))


def consolidate(store) -> None:
    """Write consolidated metadata (path or zarr store) so xarray opens the store without probing
    (zarr warns that consolidation is not yet part of the v3 spec; the store stays valid without it).
    Every writer here calls it after writing, so the consolidated view never lags the arrays."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        zarr.consolidate_metadata(str(store) if isinstance(store, (str, os.PathLike)) else store)


def unconsolidate(path) -> None:
    """Remove the consolidated metadata of the store at ``path`` (while arrays grow: a run killed before it
    writes them again leaves none, so that readers see the arrays as they are, never a stale snapshot;
    xarray then reads without it and says so in a RuntimeWarning)."""
    import json

    meta_path = Path(path) / "zarr.json"
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return
    if meta.pop("consolidated_metadata", None) is not None:
        tmp = meta_path.with_name(f".zarr.json.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(meta, indent=2))
        os.replace(tmp, meta_path)  # atomic: a reader sees the old or the new file, never half of one


def open_store(
    path,
    *,
    params: dict | None = None,
    provenance_info: dict | None = None,
    mode: str = "w",
    attrs: dict | None = None,
) -> zarr.Group:
    """Create (``mode="w"``) or open (``"a"``, ``"r"``) a zarr v3 store; sets (signed) root attributes."""
    # never from consolidated metadata: arrays opened from that snapshot do not persist a resize
    root = zarr.open_group(str(path), mode=mode, zarr_format=3, use_consolidated=False if mode != "w" else None)
    if mode != "r":
        changes = dict(attrs or {})
        if params is not None:
            changes["params"] = jsonable(params)
        if provenance_info is not None:
            changes["provenance"] = jsonable(provenance_info)
        if changes or mode == "w":
            write_attributes(root, changes)
    return root


def append_rows(*stages, start: int) -> None:
    """Grow zarr arrays along their first axis and write rows at ``start``: the one append of the field writer and
    the branch store. Each stage is a list of (array, rows) pairs written at once (one round trip to zarr's event
    loop, not two per array); a stage starts once the one before has landed (a branch's checksums after its rows:
    a point whose rows were not all written does not match)."""
    import asyncio

    from zarr.core.sync import sync

    async def grow(arr, rows):
        await arr.async_array.resize((start + len(rows), *arr.shape[1:]))
        await arr.async_array.setitem(slice(start, start + len(rows)), rows)

    async def write():
        for stage in stages:
            await asyncio.gather(*(grow(arr, rows) for arr, rows in stage))

    sync(write())


class FieldWriter:
    """Streams time-dependent fields into a group, one whole time chunk at a time.

    Args:
        root: the store's root group; path: its file path (for consolidation).
        group: name of the group to create.
        fields: field name -> shape of one frame (e.g. ``{"u": (N,), "v": (N,)}``).
        dims: dimension names of a field, starting with ``"t"`` (e.g. ``("t", "site")``).
        chunk_t: frames per chunk.
        coords: extra coordinates, name -> (dims, values); ``site`` (1..N) is added when a dim
            is named ``site`` and no coordinate is given.
        expected_frames: total frames if known (sizes the single chunk of the ``t`` coordinate).
        attrs: attributes of the group.
    """

    def __init__(
        self,
        root: zarr.Group,
        path,
        group: str,
        fields: dict,
        dims: tuple,
        chunk_t: int,
        coords: dict | None = None,
        expected_frames: int | None = None,
        attrs: dict | None = None,
    ):
        if not dims or dims[0] != "t":
            raise ValueError(f"field dims must start with 't', got {dims}")
        if chunk_t < 1:
            raise ValueError("chunk_t must be >= 1")
        self.path, self.chunk_t, self.dims = path, int(chunk_t), tuple(dims)
        self.group = root.require_group(group)
        self.arrays = {}
        for name, frame_shape in fields.items():
            frame_shape = tuple(frame_shape)
            if len(frame_shape) != len(dims) - 1:
                raise ValueError(f"field {name}: frame shape {frame_shape} does not match dims {dims}")
            self.arrays[name] = self.group.create_array(
                name,
                shape=(0, *frame_shape),
                chunks=(self.chunk_t, *frame_shape),
                dtype="f8",
                fill_value=np.nan,
                dimension_names=self.dims,
                overwrite=True,
                attributes=describe(name, group, required=False),
            )  # a missing chunk reads as NaN
        t_chunk = max(int(expected_frames or 0), 1 << 16)
        self.t = self.group.create_array(
            "t",
            shape=(0,),
            chunks=(t_chunk,),
            dtype="f8",
            dimension_names=("t",),
            fill_value=np.nan,
            overwrite=True,
            attributes=describe("t", group, required=False),
        )
        coords = dict(coords or {})
        first = next(iter(fields.values())) if fields else ()
        if "site" in dims and "site" not in coords:
            n_sites = tuple(first)[dims.index("site") - 1]
            coords["site"] = (("site",), np.arange(n_sites))
        for name, (cdims, values) in coords.items():
            values = np.asarray(values)
            arr = self.group.create_array(
                name,
                shape=values.shape,
                chunks=values.shape or (1,),
                dtype=values.dtype,
                dimension_names=tuple(cdims),
                overwrite=True,
            )
            arr[...] = values
            arr.update_attributes(
                {
                    **describe(name, group, integer=values.dtype.kind in "iu", required=False),
                    "crc32": column_checksum(name, np.asarray(values, dtype=arr.dtype)),
                }
            )
        self._chunk_crc: dict[str, list[int]] = {name: [] for name in [*self.arrays, "t"]}
        write_attributes(
            self.group,
            jsonable(
                {
                    **(attrs or {}),
                    "complete": False,
                    "n_written": 0,
                    "t_written": None,
                    "chunk_crc32": self._chunk_crc,
                    "crc_frames": self.chunk_t,
                }
            ),
        )
        self.n_written = 0
        self._pending_t: list[np.ndarray] = []
        self._pending: dict[str, list[np.ndarray]] = {name: [] for name in self.arrays}
        consolidate(self.path)

    @property
    def _n_pending(self) -> int:
        return int(sum(len(t) for t in self._pending_t))

    def append(self, t, **frames) -> None:
        """Queue frames: ``t`` shape (n,), each field shape (n, *frame_shape); writes whole chunks."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if set(frames) != set(self.arrays):
            raise ValueError(f"append needs exactly the fields {sorted(self.arrays)}, got {sorted(frames)}")
        for name, values in frames.items():
            values = np.asarray(values, dtype=np.float64)
            if values.shape != (len(t), *self.arrays[name].shape[1:]):
                raise ValueError(
                    f"field {name}: got shape {values.shape}, expected {(len(t), *self.arrays[name].shape[1:])}"
                )
            self._pending[name].append(values)
        self._pending_t.append(t)
        if self._n_pending >= self.chunk_t:
            self._flush(whole_only=True)

    def _flush(self, whole_only: bool) -> None:
        n = self._n_pending
        if n == 0:
            return
        take = (n // self.chunk_t) * self.chunk_t if whole_only else n
        if take == 0:
            return
        t_all = np.concatenate(self._pending_t)
        start, stop = self.n_written, self.n_written + take
        values = {name: np.concatenate(self._pending[name]) for name in self.arrays}
        append_rows(
            [(self.arrays[name], v[:take]) for name, v in values.items()] + [(self.t, t_all[:take])], start=start
        )
        for name, v in values.items():
            self._chunk_crc[name] += self._blocks(v[:take])
            self._pending[name] = [v[take:]] if take < n else []
        self._chunk_crc["t"] += self._blocks(t_all[:take])
        self._pending_t = [t_all[take:]] if take < n else []
        self.n_written = stop
        write_attributes(
            self.group, {"n_written": int(stop), "t_written": float(t_all[take - 1]), "chunk_crc32": self._chunk_crc}
        )
        consolidate(self.path)

    def _blocks(self, values) -> list[int]:
        """CRC-32 of every ``chunk_t`` frames (the flushes start at multiples of ``chunk_t``)."""
        return [crc32(values[k : k + self.chunk_t]) for k in range(0, len(values), self.chunk_t)]

    def close(self, **attrs) -> None:
        """Write what is left (the last, possibly partial, chunk) and mark the group complete."""
        self._flush(whole_only=False)
        write_attributes(self.group, {**attrs, "complete": True})
        consolidate(self.path)


def write_fields(
    root: zarr.Group,
    path,
    group: str,
    t,
    fields: dict,
    dims: tuple,
    chunk_t: int = 256,
    coords: dict | None = None,
    attrs: dict | None = None,
) -> None:
    """Write complete fields (name -> array of shape (n_t, ...)) to a new group in one go."""
    t = np.asarray(t, dtype=np.float64)
    writer = FieldWriter(
        root,
        path,
        group,
        {k: np.shape(v)[1:] for k, v in fields.items()},
        dims,
        min(chunk_t, max(len(t), 1)),
        coords=coords,
        expected_frames=len(t),
        attrs=attrs,
    )
    writer.append(t, **fields)
    writer.close()


def write_table(
    root: zarr.Group, group: str, columns: dict, dim: str = "point", attrs: dict | None = None
) -> zarr.Group:
    """Write 1-D or N-D numeric arrays sharing a leading dimension ``dim`` (e.g. points along a
    branch). Strings are not stored as arrays (zarr v3 has no stable string type): put labels in
    ``attrs``."""
    g = root.require_group(group)
    for name, values in columns.items():
        values = np.asarray(values)
        if values.dtype.kind not in "biufc":
            raise TypeError(f"column {name!r} has dtype {values.dtype}; store labels in attrs instead")
        dims = (dim,) + tuple(f"{name}_{k}" for k in range(1, values.ndim))
        arr = g.create_array(
            name,
            shape=values.shape,
            chunks=values.shape if values.size else (1,) * values.ndim,
            dtype=values.dtype,
            dimension_names=dims,
            overwrite=True,
            fill_value=np.nan if values.dtype.kind in "fc" else 0,
        )
        arr[...] = values
        arr.update_attributes(
            {
                **describe(name, group, integer=values.dtype.kind in "iub", required=False),
                "crc32": column_checksum(name, values),
            }
        )
    write_attributes(g, {**(attrs or {}), "checksums": True, "columns": list(columns)})
    consolidate(root.store)
    return g


class StoreError(ValueError):
    """A store that is missing, half-written or damaged; the message names the store, group and array."""


def read_group(path, group: str, *, require_complete: bool = True) -> tuple[dict, dict]:
    """Read every array of a group into numpy; returns (arrays, attributes).

    A field group (written by ``FieldWriter``) is checked: it must be marked complete (unless
    ``require_complete=False``), and its fields and ``t`` must be finite in every written frame (a
    missing chunk reads as NaN, the fill value), so a damaged or half-written group is never read as
    valid.

    Raises:
        StoreError: naming the store, the group, the array and the first bad frame.
    """
    where = f"store {path}, group '{group}'"
    try:
        root = zarr.open_group(str(path), mode="r", zarr_format=3, use_consolidated=False)
        g = root[group]
        attrs = dict(g.attrs)
        arrays = {name: arr[...] for name, arr in g.arrays()}
    except (KeyError, FileNotFoundError) as exc:
        raise StoreError(f"{where}: not found ({exc}); run the scene that writes it first") from None
    except Exception as exc:  # zarr raises many kinds on damaged metadata or chunks
        raise StoreError(f"{where}: unreadable ({type(exc).__name__}: {exc}); rerun the scene that wrote it") from None
    check_attributes(where, attrs)
    _check_sums(where, g, attrs, arrays)
    if "n_written" in attrs:  # a field group
        if require_complete and not attrs.get("complete", False):
            raise StoreError(
                f"{where}: half-written (not marked complete; {attrs.get('n_written')} frames): the run "
                "that wrote it did not finish"
            )
        n = int(attrs["n_written"])
        for name, values in arrays.items():
            if values.dtype.kind == "f" and values.ndim and values.shape[0] == n > 0 and name != "site":
                bad = ~np.isfinite(values.reshape(n, -1)).all(axis=1)
                if bad.any():
                    raise StoreError(
                        f"{where}, array '{name}': frame {int(np.flatnonzero(bad)[0])} is missing or "
                        "not finite (a lost or damaged chunk); rerun the scene that wrote it"
                    )
    return arrays, attrs


def _check_sums(where: str, g, attrs: dict, arrays: dict) -> None:
    """Every array against its checksum: ``crc32`` (tables, coordinates: the whole array) or the group's
    ``chunk_crc32`` (fields and ``t``: one per chunk of frames, and as many frames as ``n_written``). A
    group that declares checksums (``checksums`` or ``chunk_crc32``) and has an array without one is damaged."""
    chunks = attrs.get("chunk_crc32")
    declared = bool(attrs.get("checksums")) or isinstance(chunks, dict)
    hint = "rerun the scene that wrote it"
    listed = list(chunks or {}) + list(attrs.get("columns") or [])
    for name in listed:  # an array whose metadata is lost is not listed by zarr: never silently left out
        if name not in arrays:
            raise StoreError(f"{where}, array '{name}': missing (its metadata is lost); {hint}")
    for name, values in arrays.items():
        crc = g[name].attrs.get("crc32")
        if crc is not None:
            if column_checksum(name, values) != crc:
                raise StoreError(
                    f"{where}, array '{name}': does not match its checksum (a lost or altered chunk); {hint}"
                )
            continue
        if isinstance(chunks, dict) and name in chunks:
            n, step = int(attrs.get("n_written", -1)), int(attrs.get("crc_frames", 1))
            if values.shape[0] != n or len(chunks[name]) != -(-n // step):
                raise StoreError(
                    f"{where}, array '{name}': {values.shape[0]} frames in {len(chunks[name])} checksummed chunks, "
                    f"but n_written says {n} (the group's count was altered, or the run did not finish); {hint}"
                )
            for k, want in enumerate(chunks[name]):
                if crc32(values[k * step : (k + 1) * step]) != want:
                    raise StoreError(
                        f"{where}, array '{name}': frames {k * step} to {min((k + 1) * step, n) - 1} do not match "
                        f"their checksum (a lost, altered or misplaced chunk); {hint}"
                    )
            continue
        if declared:
            raise StoreError(f"{where}, array '{name}': no checksum in a group that keeps them; {hint}")


def read_attrs(path) -> dict:
    """Root attributes (params, provenance) of a store, checked against their signature."""
    try:
        attrs = dict(zarr.open_group(str(path), mode="r", zarr_format=3, use_consolidated=False).attrs)
    except Exception as exc:
        raise StoreError(
            f"store {path}: unreadable ({type(exc).__name__}: {exc}); rerun the scene that wrote it"
        ) from None
    check_attributes(f"store {path} (root)", attrs)
    return attrs
