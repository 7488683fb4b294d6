"""Read a store as xarray, after checking it: the way to read what the scenes write.

``read_store(path)`` validates every group of a zarr store written by this package and returns an
``xarray.DataTree`` (one node per group, the root's ``params`` and ``provenance`` as its attributes);
``read_store(path, group)`` returns that group's ``xarray.Dataset``. What is checked is what the writers sign:

* every group's attributes against their signature (``store.write_attributes``), the root's included;
* tables and fields (``store.read_group``): every column against its checksum (started from its name), fields
  chunk by chunk, a field group marked complete;
* branches (``continuation.branch_store.load_branch``): every point's row of every array against its checksum,
  the flags, the multipliers, the count;
* sweeps (``sweep.store``): every completed task's region of every variable against its checksum.

A damaged, half-written or edited store raises ``store.StoreError`` naming store, group, array and point; no
data are returned from it. ``xarray.open_zarr`` reads the same arrays but checks none of this.

What the Datasets add to the stored arrays: every variable keeps its ``long_name`` and ``units``; a branch's
``point`` dimension becomes its parameter (``K`` or ``omega``, whichever varies along it; ``s`` and the other
one are coordinates, the point's index is ``point``), ``stable`` is a bool (True only where the Floquet verdict
is complete and stable; ``floquet_complete`` says where there is a verdict at all) and the integer codes
(instability kinds, parities, flags) keep CF ``flag_values`` / ``flag_meanings``; checksums and the writers'
bookkeeping (walk state, chunk checksums) are left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import zarr

from .variables import describe
from .store import SIGNATURE, StoreError, check_attributes, read_attrs, read_group

#: group attributes that are the writers' bookkeeping, not results: left out of the Datasets
BOOKKEEPING = frozenset({SIGNATURE, "checksum_arrays", "chunk_crc32", "crc_frames", "walk_state", "checksums"})


def read_store(path, group: str | None = None):
    """The store at ``path``, checked, as an ``xarray.DataTree`` (or one group's ``xarray.Dataset``).

    Raises:
        StoreError: the store, a group, an array or a point is missing, damaged, half-written or edited.
    """
    import xarray as xr

    path = Path(path)
    if not (path / "zarr.json").is_file():
        raise StoreError(f"no zarr store at {path}")
    root_attrs = read_attrs(path)  # checked against its signature
    root = zarr.open_group(str(path), mode="r", zarr_format=3, use_consolidated=False)
    if group is not None:
        return _dataset(path, root, group)
    nodes = {"/": xr.Dataset(attrs=_public(root_attrs))}
    for name in _groups(root):
        nodes["/" + name] = _dataset(path, root, name)
    return xr.DataTree.from_dict(nodes)


def _groups(root, prefix: str = "") -> list[str]:
    """Every group below ``root`` that holds arrays (containers of groups only are walked through)."""
    out = []
    for name, g in sorted(root.groups()):
        full = prefix + name
        if any(True for _ in g.array_keys()):
            out.append(full)
        out += _groups(g, full + "/")
    return out


def _public(attrs: dict) -> dict:
    return {k: v for k, v in attrs.items() if k not in BOOKKEEPING}


def _unflagged(attrs: dict) -> dict:
    """A flag's attributes once it is a bool (no codes left to explain)."""
    return {k: v for k, v in attrs.items() if k not in ("flag_values", "flag_meanings")}


def _variable(arr, values, drop=("crc32",)):
    import xarray as xr

    dims = tuple(arr.metadata.dimension_names or (f"{arr.basename}_{k}" for k in range(arr.ndim)))
    return xr.Variable(dims, values, {k: v for k, v in arr.attrs.items() if k not in drop})


def _dataset(path: Path, root, name: str):
    import xarray as xr

    where = f"store {path}, group '{name}'"
    try:
        g = root[name]
    except KeyError:
        raise StoreError(f"{where}: not found; groups: {', '.join(_groups(root)) or 'none'}") from None
    attrs = dict(g.attrs)
    if "checksum_arrays" in attrs and "n_points" in attrs:
        return _branch(path, g, name, attrs)
    if "sweep" in attrs:
        return _sweep(path, g, name, attrs)
    if "n_written" in attrs or "columns" in attrs:
        arrays, attrs = read_group(path, name)  # checked
        data = {k: _variable(g[k], v) for k, v in arrays.items()}
        if "n_written" in attrs:  # a field group: the frames written
            n = int(attrs["n_written"])
            data = {k: (v[:n] if v.dims and v.dims[0] == "t" else v) for k, v in data.items()}
        return xr.Dataset(data, attrs=_public(attrs))
    check_attributes(where, attrs)
    raise StoreError(f"{where}: not a table, field, branch or sweep written by warpchain")


def _branch(path: Path, g, name: str, attrs: dict):
    import xarray as xr

    from continuation.branch_store import CHECKSUM, INT_FILL, load_branch

    load_branch(path, name)  # every point checked (raises StoreError naming array and point)
    n = int(attrs["n_points"])
    data = {k: _variable(arr, arr[:n]) for k, arr in sorted(g.arrays()) if k != CHECKSUM}
    code = data["stable"].values
    complete = data["floquet_complete"].values == 1
    data["stable"] = xr.Variable(
        ("point",),
        (code == 1) & complete,
        {
            **data["stable"].attrs,
            "long_name": "stable: a complete Floquet verdict of stability (False where unstable or not decided)",
        },
    )
    data["floquet_complete"] = xr.Variable(("point",), complete, _unflagged(data["floquet_complete"].attrs))
    data["stable"].attrs = _unflagged(data["stable"].attrs)
    ds = xr.Dataset(data, attrs=_public(attrs))
    for k, v in ds.data_vars.items():
        if v.dtype == np.int8:
            ds[k].attrs.setdefault("missing_value", INT_FILL)
    ds = ds.assign_coords(point=("point", np.arange(n), describe("point"))).set_coords(
        [c for c in ("K", "omega", "s") if c in ds]
    )
    varying = [c for c in ("K", "omega") if c in ds and n > 1 and np.ptp(ds[c].values) > 0]
    return ds.swap_dims(point=varying[0]) if varying else ds


def _sweep(path: Path, g, name: str, attrs: dict):
    import xarray as xr

    from sweep.store import CHECKSUM, COMPLETED, _crc  # deferred: the engine package does not depend on sweep

    where = f"store {path}, group '{name}'"
    check_attributes(where, attrs)
    arrays = dict(sorted(g.arrays()))
    if COMPLETED not in arrays or CHECKSUM not in arrays:
        raise StoreError(
            f"{where}: a sweep without its '{COMPLETED}' flags or checksums; rerun the scene that wrote it"
        )
    done = np.asarray(arrays[COMPLETED][...]) == 1
    sums = np.asarray(arrays[CHECKSUM][...])
    names = list(arrays[CHECKSUM].attrs.get("variables", []))
    values = {k: np.asarray(a[...]) for k, a in arrays.items() if k != CHECKSUM}
    for index in zip(*np.nonzero(done)):
        index = tuple(int(i) for i in index)
        for k, var in enumerate(names):
            if var not in values or _crc(values[var][index], index) != int(sums[index + (k,)]):
                raise StoreError(
                    f"{where}, array '{var}': task {index} does not match its checksum (a lost, altered or "
                    "misplaced chunk); rerun the scene that wrote it"
                )
    data = {k: _variable(arrays[k], v) for k, v in values.items()}
    data[COMPLETED] = xr.Variable(data[COMPLETED].dims, done, _unflagged(data[COMPLETED].attrs))
    return xr.Dataset(data, attrs=_public(attrs))
