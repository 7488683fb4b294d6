"""The zarr side of a sweep (``sweep.runner``): the grid's description (:class:`SweepSpec`, :class:`Variable`), the
group that holds it, the per-task ``completed`` flags and CRC-32 checksums, and the writing of one task's result.

The layout and the design (disjoint chunks, ``completed`` written last, resume, mismatch refused) are described in
``sweep.runner``'s docstring.
"""

from __future__ import annotations

import contextlib
import dataclasses
import warnings

import numpy as np
import zarr

from warpchain.variables import describe
from warpchain.store import check_attributes, crc32, jsonable, write_attributes

COMPLETED = "completed"
CHECKSUM = "checksum"  # (task dims..., variable): CRC-32 of each variable's region, written before the flag


class SweepMismatchError(ValueError):
    """The group already holds a sweep over a different grid (or something that is not a sweep)."""


@dataclasses.dataclass(frozen=True)
class Variable:
    """One output array: dims start with the sweep's task dims; floats fill with NaN (or ``fill``),
    integer dtypes need an explicit ``fill`` (the value a task that has not run reads as)."""

    dims: tuple[str, ...]
    dtype: str = "float64"
    fill: float | int | None = None
    attrs: dict = dataclasses.field(default_factory=dict)

    def fill_value(self):
        kind = np.dtype(self.dtype).kind
        if self.fill is not None:
            return np.dtype(self.dtype).type(self.fill).item()
        if kind in "fc":
            return np.nan
        if kind == "b":
            return False
        raise ValueError(f"variable of dtype {self.dtype} needs an explicit fill value (Variable(fill=...))")


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """The grid: coordinates of every dim, the dims tasks run over, the variables, group attributes."""

    group: str
    coords: dict[str, np.ndarray]
    task_dims: tuple[str, ...]
    variables: dict[str, Variable]
    attrs: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "task_dims", tuple(self.task_dims))
        coords = {str(k): np.asarray(v) for k, v in self.coords.items()}
        object.__setattr__(self, "coords", coords)
        problems = []
        for dim, values in coords.items():
            if values.ndim != 1:
                problems.append(f"coordinate {dim!r} must be 1-D, got shape {values.shape}")
        if not self.task_dims:
            problems.append("task_dims is empty")
        for dim in self.task_dims:
            if dim not in coords:
                problems.append(f"task dim {dim!r} has no coordinate")
        if len(set(self.task_dims)) != len(self.task_dims):
            problems.append(f"task_dims repeat a dim: {self.task_dims}")
        if not self.variables:
            problems.append("no variables")
        for name, var in self.variables.items():
            dims = tuple(var.dims)
            if name in (COMPLETED, CHECKSUM) or name in coords:
                problems.append(f"variable name {name!r} is reserved (the completed flags or a coordinate)")
            if dims[: len(self.task_dims)] != self.task_dims:
                problems.append(f"variable {name!r}: dims {dims} must start with the task dims {self.task_dims}")
            if len(set(dims)) != len(dims):
                problems.append(f"variable {name!r}: dims {dims} repeat a dim")
            for dim in dims:
                if dim not in coords:
                    problems.append(f"variable {name!r}: dim {dim!r} has no coordinate")
            try:
                var.fill_value()
            except (ValueError, TypeError) as exc:
                problems.append(f"variable {name!r}: {exc}")
        if COMPLETED in coords:
            problems.append(f"a dim may not be named {COMPLETED!r}")
        if problems:
            raise ValueError("invalid SweepSpec: " + "; ".join(problems))

    @property
    def task_shape(self) -> tuple[int, ...]:
        return tuple(len(self.coords[d]) for d in self.task_dims)

    def shape(self, name: str) -> tuple[int, ...]:
        return tuple(len(self.coords[d]) for d in self.variables[name].dims)

    def signature(self) -> dict:
        """What must match for a stored group to be resumed (coordinate values are compared apart)."""
        return {
            "task_dims": list(self.task_dims),
            "dims": {d: len(v) for d, v in self.coords.items()},
            "variables": {
                name: {"dims": list(v.dims), "dtype": np.dtype(v.dtype).name, "fill": jsonable(v.fill_value())}
                for name, v in self.variables.items()
            },
            "attr_keys": sorted(str(k) for k in self.attrs),
        }


# --------------------------------------------------------------------------------------------- store


def _open_root(store_path, mode: str = "a") -> zarr.Group:
    # never from consolidated metadata (it may lag the arrays; see warpchain.store.open_store)
    return zarr.open_group(str(store_path), mode=mode, zarr_format=3, use_consolidated=False)


def _coord_dtype(values: np.ndarray):
    return str if values.dtype.kind in "UO" else values.dtype


def _same_values(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape:
        return False
    if a.dtype.kind in "fc" and b.dtype.kind in "fc":
        return bool(np.array_equal(a, b, equal_nan=True))
    if (a.dtype.kind in "UOT") != (b.dtype.kind in "UOT"):
        return False
    return bool(np.array_equal(a.astype(object) if a.dtype.kind in "UOT" else a, b))


def _short(values: np.ndarray) -> str:
    return np.array2string(np.asarray(values), threshold=8, precision=6, separator=", ")


def _check_group(group: zarr.Group, spec: SweepSpec, where: str) -> None:
    stored_attrs = dict(group.attrs)
    hint = "write to a new output folder (or delete that group); grids are never mixed"
    if "sweep" not in stored_attrs:
        raise SweepMismatchError(f"{where} exists but was not written by run_sweep; {hint}")
    problems = []
    old, new = stored_attrs["sweep"], jsonable(spec.signature())
    for key in ("task_dims", "dims", "variables", "attr_keys"):
        if old.get(key) != new[key]:
            problems.append(f"{key}: stored {old.get(key)}, asked {new[key]}")
    members = set(group.array_keys())
    for dim, values in spec.coords.items():
        if dim not in members:
            problems.append(f"coordinate {dim!r} missing")
            continue
        stored = group[dim][...]
        if not _same_values(np.asarray(stored), values):
            problems.append(f"coordinate {dim!r}: stored {_short(stored)}, asked {_short(values)}")
    for key, value in jsonable(spec.attrs).items():
        if stored_attrs.get(key) != value:
            problems.append(f"attribute {key!r}: stored {stored_attrs.get(key)!r}, asked {value!r}")
    for name in [*spec.variables, COMPLETED]:
        if name not in members:
            problems.append(f"array {name!r} missing")
    if problems:
        raise SweepMismatchError(f"{where} holds a different sweep ({'; '.join(problems)}); {hint}")


def open_sweep(store_path, spec: SweepSpec) -> zarr.Group:
    """Create the sweep's group (arrays, coordinates, ``completed``, attributes) or open an existing one
    after checking it holds the same grid (raises :class:`SweepMismatchError` otherwise). The store's
    root (attributes, other groups) is opened with mode ``"a"`` and left as it is."""
    root = _open_root(store_path, "a")
    where = f"group {spec.group!r} of {store_path}"
    if spec.group in set(root.group_keys()):
        group = root[spec.group]
        _check_group(group, spec, where)
        check_attributes(where, dict(group.attrs), "write to a new output folder")
        if CHECKSUM not in set(group.array_keys()):  # a store from before checksums: its tasks are verified as none
            _create_checksum(group, spec)
        for name, var in spec.variables.items():  # descriptive attributes may be refreshed
            if var.attrs:
                group[name].update_attributes(jsonable(var.attrs))
        return group
    if spec.group in set(root.array_keys()):
        raise SweepMismatchError(f"{where} is an array, not a group; write to a new output folder")
    group = root.require_group(spec.group)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zarr's notes on string dtypes not yet in the v3 spec
        for dim, values in spec.coords.items():
            arr = group.create_array(
                dim,
                shape=values.shape,
                chunks=(max(len(values), 1),),
                dtype=_coord_dtype(values),
                dimension_names=(dim,),
                overwrite=True,
                attributes=describe(dim, spec.group, required=False),
            )
            if len(values):
                arr[...] = values
    for name, var in spec.variables.items():
        shape = spec.shape(name)
        chunks = tuple(1 if d in spec.task_dims else max(n, 1) for d, n in zip(var.dims, shape))
        arr = group.create_array(
            name,
            shape=shape,
            chunks=chunks,
            dtype=np.dtype(var.dtype),
            fill_value=var.fill_value(),
            dimension_names=tuple(var.dims),
            overwrite=True,
        )
        arr.update_attributes(
            {
                **describe(name, spec.group, integer=np.dtype(var.dtype).kind == "i", required=False),
                **jsonable(var.attrs),
            }
        )
    _create_checksum(group, spec)
    group.create_array(
        COMPLETED,
        shape=spec.task_shape,
        chunks=(1,) * len(spec.task_dims),
        dtype="int8",
        fill_value=0,
        compressors=None,  # one byte per chunk file
        dimension_names=spec.task_dims,
        overwrite=True,
    ).update_attributes(
        {
            **describe(COMPLETED, spec.group, integer=True),
            "description": "1 once the task's region of every variable is written",
        }
    )
    # the signature last: a group interrupted while being created is not taken for a sweep
    write_attributes(
        group, {**jsonable(spec.attrs), "task_dims": list(spec.task_dims), "sweep": jsonable(spec.signature())}
    )
    return group


def _crc(values: np.ndarray, index: tuple) -> int:
    """CRC-32 of a task's region of one variable as stored, started from the task's index (a region moved
    to another task no longer matches)."""
    import zlib

    return crc32(values, zlib.crc32(repr(tuple(int(i) for i in index)).encode()))


def _create_checksum(group: zarr.Group, spec: SweepSpec) -> None:
    names = sorted(spec.variables)
    group.create_array(
        CHECKSUM,
        shape=(*spec.task_shape, len(names)),
        chunks=(*(1,) * len(spec.task_dims), len(names)),
        dtype="int64",
        fill_value=-1,
        dimension_names=(*spec.task_dims, "sweep_variable"),
        overwrite=True,
    ).update_attributes(
        {
            **describe(CHECKSUM, spec.group),
            "variables": names,
            "description": "CRC-32 of each variable's region of the task",
        }
    )


def damaged_tasks(store_path, spec: SweepSpec, done: np.ndarray) -> list[tuple[tuple, str]]:
    """Tasks flagged completed whose data do not match their checksums (a lost, altered or misplaced
    chunk, or no checksum): [(index, what is wrong)]. Reads every completed task's regions."""
    group = _open_root(store_path, "r")[spec.group]
    names = sorted(spec.variables)
    out = []
    for index in zip(*np.nonzero(done)):
        index = tuple(int(i) for i in index)
        try:
            stored = [int(c) for c in group[CHECKSUM][index]]
            for name, crc in zip(names, stored):
                if crc == -1:
                    raise ValueError("no checksum stored")
                if _crc(np.asarray(group[name][index]), index) != crc:
                    raise ValueError(f"variable {name!r} does not match its checksum (a lost or altered chunk)")
        except Exception as exc:  # noqa: BLE001 - an unreadable chunk is damage too
            out.append((index, str(exc) if isinstance(exc, ValueError) else f"unreadable ({type(exc).__name__})"))
    return out


def completed(store_path, spec: SweepSpec) -> np.ndarray:
    """Boolean array over the task dims: True where the task's region is written. All False when the
    group does not exist yet. An unreadable flag (a worker killed while writing it) reads False."""
    try:
        root = _open_root(store_path, "r")
        arr = root[spec.group][COMPLETED]
    except (FileNotFoundError, KeyError):
        return np.zeros(spec.task_shape, dtype=bool)
    if tuple(arr.shape) != spec.task_shape:
        raise SweepMismatchError(
            f"group {spec.group!r} of {store_path}: completed flags have shape {arr.shape}, the grid "
            f"{spec.task_shape}; write to a new output folder"
        )
    try:
        return np.asarray(arr[...]) == 1
    except Exception:
        done = np.zeros(spec.task_shape, dtype=bool)
        for index in np.ndindex(*spec.task_shape):
            with contextlib.suppress(Exception):
                done[index] = arr[index] == 1
        return done


# ------------------------------------------------------------------------------------------ one task


def _layout(spec: SweepSpec) -> dict:
    """What a worker needs to validate and write a task's result (small, sent with every task)."""
    n_task = len(spec.task_dims)
    return {
        "group": spec.group,
        "task_dims": spec.task_dims,
        "variables": {name: (spec.shape(name)[n_task:], np.dtype(v.dtype).str) for name, v in spec.variables.items()},
    }


def _write_result(group: zarr.Group, layout: dict, index: tuple[int, ...], result) -> None:
    """Checks a task's result, writes each variable's region (whole chunks), then the completed flag."""
    if not isinstance(result, dict):
        raise TypeError(f"the task returned {type(result).__name__}, expected a dict of arrays")
    expected = layout["variables"]
    missing, extra = sorted(set(expected) - set(result)), sorted(set(result) - set(expected))
    if missing or extra:
        raise ValueError(f"the task returned variables {sorted(result)}: missing {missing}, unexpected {extra}")
    arrays = {}
    for name, (shape, dtype) in expected.items():
        value = np.asarray(result[name])
        if value.shape != tuple(shape):
            raise ValueError(f"variable {name!r}: the task returned shape {value.shape}, expected {tuple(shape)}")
        try:
            arrays[name] = value.astype(np.dtype(dtype), casting="same_kind", copy=False)
        except TypeError as exc:
            raise TypeError(f"variable {name!r}: cannot store {value.dtype} as {np.dtype(dtype)}") from exc
    for name, value in arrays.items():  # all checked before any is written
        group[name][index] = value
    group[CHECKSUM][index] = [_crc(arrays[name], index) for name in sorted(arrays)]
    group[COMPLETED][index] = 1
