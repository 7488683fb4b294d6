import json

import numpy as np
import pytest
import zarr

from conftest import localized_state
from warpchain import Guard, Record
from warpchain import ChainParams, simulate
from warpchain.store import (
    SIGNATURE,
    FieldWriter,
    attributes_checksum,
    StoreError,
    open_store,
    provenance,
    read_attrs,
    read_group,
    write_fields,
    write_table,
)


def test_round_trip_and_xarray(tmp_path):
    xr = pytest.importorskip("xarray")
    p = ChainParams(3.0, 4.0, 11)
    path = tmp_path / "data.zarr"
    root = open_store(path, params=p.as_dict(), provenance_info=provenance("cpu"))
    t = np.arange(10) * 0.5
    u = np.random.default_rng(0).standard_normal((10, p.N))
    v = -u
    write_fields(root, path, "case", t, {"u": u, "v": v}, ("t", "site"), chunk_t=4, attrs={"note": "x"})
    arrays, attrs = read_group(path, "case")
    assert np.array_equal(arrays["u"], u) and np.array_equal(arrays["t"], t)
    assert attrs["complete"] is True and attrs["n_written"] == 10 and attrs["note"] == "x"
    arr = zarr.open_array(str(path / "case" / "u"), mode="r")
    assert arr.metadata.dimension_names == ("t", "site") and arr.chunks == (4, p.N)
    root_attrs = read_attrs(path)
    assert root_attrs["params"]["M"] == 3.0
    prov = root_attrs["provenance"]
    assert {"git_commit", "command_line", "device", "packages"} <= set(prov)
    assert prov["packages"]["numpy"]
    ds = xr.open_zarr(path, group="case")
    assert ds["u"].dims == ("t", "site")
    assert np.array_equal(ds["site"].values, np.arange(p.N))
    np.testing.assert_array_equal(ds["v"].values, v)
    json.dumps(root_attrs)  # attributes are plain JSON


def test_streamed_run_half_way_is_readable_and_says_how_far(tmp_path):
    xr = pytest.importorskip("xarray")
    p = ChainParams(3.0, 4.0, 11)
    x0 = localized_state(p.N, batch=2)
    path = tmp_path / "run.zarr"
    root = open_store(path, params=p.as_dict())
    writer = FieldWriter(root, path, "ensemble", {"u": (2, p.N), "v": (2, p.N)}, ("t", "lattice", "site"), chunk_t=5)

    class Stop(Exception):
        pass

    calls = []

    def on_chunk(t, u, v):
        writer.append(t, u=u, v=v)
        calls.append(len(t))
        if len(calls) == 3:
            raise Stop  # the run dies after its third chunk

    with pytest.raises(Stop):
        simulate(p, x0, 4.0, 0.1, device="cpu", record=Record(every=2, on_chunk=on_chunk), guard=Guard(chunks=4))
    frames_seen = sum(calls)
    arrays, attrs = read_group(path, "ensemble", require_complete=False)  # the default refuses a half-written group
    assert attrs["complete"] is False
    # only whole chunks were written; what is there is consistent and says how far it got
    assert attrs["n_written"] == (frames_seen // 5) * 5 == arrays["u"].shape[0] == arrays["t"].shape[0]
    assert attrs["t_written"] == pytest.approx(arrays["t"][-1])
    ds = xr.open_zarr(path, group="ensemble")
    assert ds["u"].dims == ("t", "lattice", "site")


def test_writer_rejects_bad_frames(tmp_path):
    root = open_store(tmp_path / "x.zarr")
    w = FieldWriter(root, tmp_path / "x.zarr", "g", {"u": (3,)}, ("t", "site"), chunk_t=2)
    with pytest.raises(ValueError, match="shape"):
        w.append([0.0], u=np.zeros((1, 4)))
    with pytest.raises(ValueError, match="fields"):
        w.append([0.0], v=np.zeros((1, 3)))


def _field_store(path):
    root = open_store(path, params={"N": 3})
    writer = FieldWriter(root, path, "case", {"u": (3,)}, ("t", "site"), chunk_t=2)
    writer.append(np.arange(6.0), u=np.ones((6, 3)))
    return writer


def test_a_missing_field_chunk_or_a_half_written_group_is_refused(tmp_path):
    from warpchain.store import StoreError

    path = tmp_path / "f.zarr"
    writer = _field_store(path)
    with pytest.raises(StoreError, match="half-written"):
        read_group(path, "case")  # not closed yet
    writer.close()
    arrays, _ = read_group(path, "case")
    assert np.all(arrays["u"] == 1.0)
    chunk = path / "case" / "u" / "c" / "1" / "0"
    assert chunk.exists()
    chunk.unlink()  # frames 2 and 3 lost: they read as NaN (the fill value), never as zeros
    with pytest.raises(StoreError, match=r"array 'u': frames 2 to 3 do not match their checksum"):
        read_group(path, "case")
    (path / "case" / "zarr.json").write_text("{broken")
    with pytest.raises(StoreError, match="f.zarr"):
        read_group(path, "case")


@pytest.mark.parametrize(
    "damage",
    [
        "lose method",
        "alter energy",
        "swap u",
        "lower n_written",
        "drop crc",
        "lose u metadata",
        "lose column",
        "edit columns",
        "drop signature",
        "drop flag",
        "swap columns",
    ],
)
def test_tables_and_fields_are_checked_array_by_array(tmp_path, damage):
    """The audit's cases: a lost chunk of an integer table column (read as 0 without a check), an altered
    value, two valid field chunks swapped, an edited frame count, an array stripped of its checksum."""
    path = tmp_path / "s.zarr"
    _field_store(path).close()
    root = open_store(path, mode="a")
    write_table(root, "points", {"method": np.array([4, 4, 4, 5, 5], dtype=np.int8), "energy": np.arange(5.0)})
    for group in ("points", "case"):
        read_group(path, group)  # intact
    if damage == "lose method":
        (path / "points" / "method" / "c" / "0").unlink()
        group, match = "points", "array 'method': does not match its checksum"
    elif damage == "alter energy":
        zarr.open_array(str(path / "points" / "energy"), mode="r+")[2] = 7.0
        group, match = "points", "array 'energy': does not match its checksum"
    elif damage == "swap u":
        u = zarr.open_array(str(path / "case" / "u"), mode="r+")
        u[0:2], u[2:4] = u[2:4] + 1.0, u[0:2]  # two chunks exchanged (and made to differ)
        group, match = "case", "array 'u': frames 0 to 1 do not match"
    elif damage == "lower n_written":
        meta = json.loads((path / "case" / "zarr.json").read_text())
        meta["attributes"]["n_written"] -= 1
        meta["attributes"][SIGNATURE] = attributes_checksum(meta["attributes"])  # signed again: the count is checked
        (path / "case" / "zarr.json").write_text(json.dumps(meta))
        group, match = "case", "but n_written says"
    elif damage in ("edit columns", "drop signature", "drop flag"):
        meta = json.loads((path / "points" / "zarr.json").read_text())
        attrs = meta["attributes"]
        if damage == "edit columns":
            attrs["columns"] = attrs["columns"][::-1]
            match = "attributes do not match their checksum"
        elif damage == "drop flag":
            del attrs["checksums"]
            match = "attributes do not match their checksum"
        else:
            del attrs[SIGNATURE]
            match = "attributes carry no checksum"
        (path / "points" / "zarr.json").write_text(json.dumps(meta))
        group = "points"
    elif damage == "swap columns":  # two columns exchanged with their own checksums
        a, b, tmp = path / "points" / "energy", path / "points" / "method", path / "points" / "tmp"
        a.rename(tmp), b.rename(a), tmp.rename(b)
        group, match = "points", "array '(energy|method)': does not match its checksum"
    elif damage == "lose u metadata":
        (path / "case" / "u" / "zarr.json").unlink()
        group, match = "case", "array 'u': missing"
    elif damage == "lose column":
        (path / "points" / "energy" / "zarr.json").unlink()
        group, match = "points", "array 'energy': missing"
    else:
        meta = json.loads((path / "points" / "method" / "zarr.json").read_text())
        del meta["attributes"]["crc32"]
        (path / "points" / "method" / "zarr.json").write_text(json.dumps(meta))
        group, match = "points", "array 'method': no checksum in a group that keeps them"
    with pytest.raises(StoreError, match=match):
        read_group(path, group)


def test_a_damaged_kernel_cache_gets_a_hint():
    from scenarios._common import failure_hint

    hint = failure_hint(Exception("Failed to load CPU module 'warpchain.kernels' (device='cpu', module_hash=c36b)"))
    assert "kernel cache" in hint and "warp.clear_kernel_cache()" in hint
    assert failure_hint(ValueError("N must be >= 3")) == ""


def test_a_group_of_zero_frames_reads_as_empty(tmp_path):
    path = tmp_path / "z.zarr"
    root = open_store(path, params={"N": 3})
    FieldWriter(root, path, "case", {"u": (3,)}, ("t", "site"), chunk_t=2).close()
    arrays, attrs = read_group(path, "case")
    assert arrays["u"].shape == (0, 3) and arrays["t"].shape == (0,) and attrs["n_written"] == 0


def test_a_group_metadata_commit_is_one_write(tmp_path, monkeypatch):
    """zarr's ``attrs.update`` rewrites zarr.json once per key, so a kill between the writes left a count without
    its walk state (issue #49): the stores commit several keys with ``update_attributes``, one atomic write (zarr's
    local store writes a temporary file and renames it)."""
    from zarr.storage import LocalStore

    from continuation.branch_store import BranchStore
    from warpchain import ChainParams

    branch = BranchStore(tmp_path / "b.zarr", "branch", ChainParams(30.0, 160.0, 21), {"omega": 1.01})
    writes = []
    plain = LocalStore.set

    async def counted(self, key, value, *args, **kwargs):
        writes.append(key)
        return await plain(self, key, value, *args, **kwargs)

    monkeypatch.setattr(LocalStore, "set", counted)
    branch.interrupted("a test")  # complete, stop_reason and message (three writes before), then consolidated
    assert [k for k in writes if k == "branch/zarr.json"] == ["branch/zarr.json"]
    assert dict(branch.group.attrs)["stop_reason"] == "interrupted"


def test_a_column_of_negative_nans_reads_back(tmp_path):
    """A chunk equal to the fill value is not written, and reads back as the canonical NaN: a column whose NaNs
    carry the sign bit (inf - inf) must still match its checksum (the fuzzing of issue #49 found dispersion and
    work-precision refusing their own stores at extreme parameters)."""
    path = tmp_path / "s.zarr"
    root = open_store(path, params={"N": 1})
    with np.errstate(invalid="ignore"):
        negative_nan = np.full(3, np.inf) - np.full(3, np.inf)
    assert np.signbit(negative_nan).all()
    write_table(root, "curves", {"q": np.arange(3.0), "optical": negative_nan}, dim="q")
    assert np.isnan(read_group(path, "curves")[0]["optical"]).all()
