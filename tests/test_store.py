import json

import numpy as np
import pytest
import zarr

from conftest import localized_state
from warpchain import ChainParams, simulate
from warpchain.store import FieldWriter, open_store, provenance, read_attrs, read_group, write_fields


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
    assert np.array_equal(ds["site"].values, np.arange(1, p.N + 1))
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
        simulate(p, x0, 4.0, 0.1, device="cpu", save_every=2, chunks=4, on_chunk=on_chunk)
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
    with pytest.raises(StoreError, match=r"array 'u': frame 2"):
        read_group(path, "case")
    (path / "case" / "zarr.json").write_text("{broken")
    with pytest.raises(StoreError, match="f.zarr"):
        read_group(path, "case")
