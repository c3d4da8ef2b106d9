"""Files other people share are read as data: crafted pickles in a dataset's ``annots.npy``, its
per-frame ``smpl_params/<n>.npy`` and an SMPL model ``.pkl`` are refused before they can run code,
truncated / random / empty files give errors that name the file, and the dataset folder is left
untouched. Positive controls: legitimate files load to exactly what ``np.load(allow_pickle=True)``
(on files this test wrote itself) gives."""

from __future__ import annotations

import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

import smpl_synth as S
from reconstruct.body import smpl_backend as B
from reconstruct.data.load import load_scene
from reconstruct.data.loaders import LoaderError
from reconstruct.safe_pickle import (RefusedGlobalError, RestrictedUnpickler, SafeLoadError, load_npy,
                                     load_npy_object, restricted_loads)


# ----------------------------------------------------------------------------- hostile payloads
class OpenMarker:
    """Unpickling this creates ``marker`` (``builtins.open(marker, 'w')``, pickled as ``io.open``)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


class SystemMarker:
    """Unpickling this runs a shell command that creates ``marker`` (``posix.system``)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch '{self.marker}'",))


def npy_bytes_of_pickle(payload: bytes, shape=()) -> bytes:
    """A .npy file (format 1.0) declaring an object array of ``shape``, followed by ``payload``."""
    import numpy.lib.format as fmt
    import io

    buf = io.BytesIO()
    fmt.write_array_header_1_0(buf, {"descr": "|O", "fortran_order": False, "shape": shape})
    return buf.getvalue() + payload


def hostile_npy(path: Path, marker: Path, kind: str) -> None:
    """Write a crafted .npy at ``path`` whose unpickling would create ``marker``."""
    if kind == "open_in_dict":  # as np.save writes a dict holding the payload
        np.save(path, {"cams": OpenMarker(marker), "ims": []}, allow_pickle=True)
    elif kind == "system_in_array":  # an object array with the payload as an element
        arr = np.empty(2, object)
        arr[0], arr[1] = {"poses": np.zeros((1, 72))}, SystemMarker(marker)
        np.save(path, arr, allow_pickle=True)
    elif kind == "bare_payload":  # the pickle after the header is the payload itself, no array around it
        path.write_bytes(npy_bytes_of_pickle(pickle.dumps(OpenMarker(marker), protocol=2)))
    else:
        raise ValueError(kind)


def damage(path: Path, kind: str) -> None:
    """Replace ``path`` with a damaged version of itself."""
    data = path.read_bytes()
    rng = np.random.default_rng(7)
    if kind == "truncated_payload":  # header intact, pickle cut in the middle
        path.write_bytes(data[: len(data) * 2 // 3])
    elif kind == "truncated_header":
        path.write_bytes(data[:40])
    elif kind == "random":
        path.write_bytes(rng.integers(0, 256, len(data), dtype=np.uint8).tobytes())
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "wrong_magic":
        path.write_bytes(b"\x93NUMPZ" + data[6:])
    else:
        raise ValueError(kind)


DAMAGE_MESSAGES = {
    "truncated_payload": r"found a truncated pickle stream",
    "truncated_header": r"found a truncated or malformed one \(EOF",
    "random": r"expected a \.npy file \(starting with b'\\x93NUMPY'\), found it starts with",
    "empty": r"expected a \.npy file, found an empty file",
    "wrong_magic": r"expected a \.npy file \(starting with b'\\x93NUMPY'\), found it starts with b'\\x93NUMPZ",
}


def listing(folder: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder below ``folder`` with its size and mtime (ns)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st = p.stat()
        out[str(p.relative_to(folder))] = (st.st_size if p.is_file() else -1, st.st_mtime_ns)
    return out


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A tiny ZJU-MoCap folder (2 frames) and a folder with the SMPL model as a .pkl."""
    root = tmp_path_factory.mktemp("safe")
    smpl = S.write_model(root / "smpl", fmt="pkl").parent
    S.write_annots_dataset(root / "my_377", S.build_model()[0], "zju", T=2)
    return root / "my_377", smpl


@pytest.fixture()
def copy(dataset, tmp_path):
    """A fresh copy of the dataset and the SMPL folder, and a marker path outside both."""
    folder, smpl = dataset
    mine = tmp_path / "data" / "my_377"
    shutil.copytree(folder, mine)
    mine_smpl = tmp_path / "smpl"
    shutil.copytree(smpl, mine_smpl)
    return mine, mine_smpl, tmp_path / "pwned"


def spec(folder: Path, smpl: Path) -> str:
    return f"zju:{folder},smpl_dir={smpl},frames=0:2"


# ----------------------------------------------------------------------------- positive controls
def test_legitimate_files_load_like_np_load(dataset):
    folder, smpl = dataset
    for rel in ("annots.npy", "smpl_params/0.npy", "smpl_params/1.npy"):
        got = load_npy_object(folder / rel)
        ref = np.load(folder / rel, allow_pickle=True).item()  # the reference: files this test wrote
        assert_same(got, ref)
    scene = load_scene(spec(folder, smpl))
    assert len(scene.frames) == 2 and scene.body_model().num_joints == 24


def assert_same(a, b) -> None:
    assert type(a) is type(b), (type(a), type(b))
    if isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            assert_same(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same(x, y)
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    else:
        assert a == b


def test_plain_data_of_every_admitted_kind_round_trips(tmp_path):
    from collections import OrderedDict

    value = {"i": 3, "f": 2.5, "c": 1 + 2j, "s": "ü", "b": b"\x00\xff", "n": None, "t": True, "set": {1, 2},
             "fs": frozenset({3}), "ba": bytearray(b"ab"), "tuple": (1, [2, {"x": np.float32(1.5)}]),
             "od": OrderedDict(a=1), "scalars": [np.int64(7), np.bool_(True), np.datetime64("2020-01-02")],
             "arrays": [np.arange(6, dtype=np.int16).reshape(2, 3), np.zeros((2, 2), np.float32, order="F"),
                        np.array(["ab", "c"]), np.zeros(2, [("a", "<f4"), ("b", "<i2", (2,))]),
                        np.array([{"k": 1}, None], object)]}
    path = tmp_path / "all.npy"
    np.save(path, value, allow_pickle=True)
    assert_same(load_npy_object(path), np.load(path, allow_pickle=True).item())
    for protocol in (2, 3, 4, 5):  # every pickle protocol, including numpy's _frombuffer (5) and _codecs (2)
        assert_same(restricted_loads(pickle.dumps(value, protocol=protocol)), value)
    # arrays without objects go through np.load(allow_pickle=False); a 0-d plain array stays an array
    np.save(tmp_path / "plain.npy", np.arange(5.0))
    assert np.array_equal(load_npy(tmp_path / "plain.npy"), np.arange(5.0))
    np.save(tmp_path / "zero_d.npy", np.float64(4.0))
    assert isinstance(load_npy_object(tmp_path / "zero_d.npy"), np.ndarray)


def test_numpy1_spelling_of_array_pickles_loads(tmp_path):
    """Files written by numpy 1 name ``numpy.core.multiarray._reconstruct``: still admitted."""
    data = pickle.dumps({"poses": np.arange(72.0).reshape(1, 72), "x": np.float32(2)}, protocol=2)
    data1 = data.replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    assert data1 != data
    path = tmp_path / "old.npy"
    path.write_bytes(npy_bytes_of_pickle(data1))
    with pytest.raises(SafeLoadError, match="found a pickled dict"):  # np.save always pickles an array
        load_npy(path)
    got = restricted_loads(data1)
    assert np.array_equal(got["poses"], np.arange(72.0).reshape(1, 72)) and got["x"] == np.float32(2)


@pytest.mark.parametrize("name", ["os.system", "posix.system", "builtins.eval", "builtins.getattr", "builtins.open",
                                  "io.open", "subprocess.Popen", "numpy.load", "numpy.testing.run_module_suite",
                                  "numpy._core.multiarray.frombuffer", "copyreg._reconstructor", "builtins.object",
                                  "pickle.loads", "__builtin__.eval", "scipy.sparse.linalg.spsolve"])
def test_globals_outside_the_allow_list_are_refused(name):
    module, attr = name.rsplit(".", 1)
    data = b"c" + module.encode() + b"\n" + attr.encode() + b"\n."  # GLOBAL, STOP: find_class is asked
    with pytest.raises(RefusedGlobalError, match=rf"x.npy: refusing to load {name.replace('.', '[.]')}") as e:
        restricted_loads(data, source="x.npy")
    assert e.value.global_name == name and e.value.path == "x.npy"
    if module.startswith("scipy") or name in ("builtins.eval", "numpy.load", "posix.system"):  # nor for SMPL files
        with pytest.raises(RefusedGlobalError, match=rf"refusing to load {name.replace('.', '[.]')}"):
            restricted_loads(data, source="m.pkl", unpickler=B._ModelUnpickler)


def test_smpl_unpickler_extends_the_shared_one():
    assert issubclass(B._ModelUnpickler, RestrictedUnpickler)
    import scipy.sparse

    for module in ("scipy.sparse.csc", "scipy.sparse._csc", "scipy.sparse"):
        data = b"c" + module.encode() + b"\ncsc_matrix\n."
        assert restricted_loads(data, unpickler=B._ModelUnpickler) is scipy.sparse.csc_matrix
        with pytest.raises(RefusedGlobalError):  # not plain data for the dataset reader
            restricted_loads(data)
    assert restricted_loads(b"cchumpy.ch\nCh\n.", unpickler=B._ModelUnpickler) is B._ChumpyStandIn


# ----------------------------------------------------------------------------- hostile dataset files
@pytest.mark.parametrize("rel", ["annots.npy", "smpl_params/0.npy"])
@pytest.mark.parametrize("kind", ["open_in_dict", "system_in_array", "bare_payload"])
def test_crafted_npy_is_refused_and_runs_nothing(copy, rel, kind):
    folder, smpl, marker = copy
    target = folder / rel
    hostile_npy(target, marker, kind)
    before = listing(folder.parent)
    with pytest.raises(LoaderError) as e:
        load_scene(spec(folder, smpl))
    msg = str(e.value)
    assert f"{target}: refusing to load " in msg, msg
    assert ("io.open" in msg) if kind != "system_in_array" else ("posix.system" in msg or "nt.system" in msg)
    with pytest.raises(RefusedGlobalError):
        load_npy_object(target)
    assert not marker.exists()
    assert listing(folder.parent) == before


@pytest.mark.parametrize("rel", ["annots.npy", "smpl_params/0.npy"])
@pytest.mark.parametrize("kind", sorted(DAMAGE_MESSAGES))
def test_damaged_npy_gives_a_clear_error_and_leaves_the_folder(copy, rel, kind):
    folder, smpl, _ = copy
    target = folder / rel
    damage(target, kind)
    before = listing(folder.parent)
    with pytest.raises(LoaderError) as e:
        load_scene(spec(folder, smpl))
    msg = str(e.value)
    assert msg.startswith(f"{target}: ") and "\n" not in msg, msg
    import re

    assert re.search(DAMAGE_MESSAGES[kind], msg), msg
    assert ("camera parameters" in msg) if rel == "annots.npy" else ("SMPL parameters" in msg)
    assert listing(folder.parent) == before


def test_truncated_plain_array_npy_names_the_sizes(tmp_path):
    path = tmp_path / "a.npy"
    np.save(path, np.arange(10.0))
    path.write_bytes(path.read_bytes()[:-12])
    with pytest.raises(SafeLoadError, match=r"a.npy: expected 80 bytes of float64 data for shape \(10,\) after the "
                                            r"header, found 68: the file is truncated"):
        load_npy(path)


# ----------------------------------------------------------------------------- hostile SMPL model files
@pytest.mark.parametrize("payload", ["open", "system"])
def test_crafted_smpl_pkl_is_refused_and_runs_nothing(copy, payload):
    folder, smpl, marker = copy
    evil = OpenMarker(marker) if payload == "open" else SystemMarker(marker)
    pkl = smpl / "SMPL_NEUTRAL.pkl"
    pkl.write_bytes(pickle.dumps({"v_template": evil, "f": np.zeros((1, 3))}, protocol=2))
    before = listing(smpl)
    name = r"io\.open" if payload == "open" else r"(posix|nt)\.system"
    with pytest.raises(B.SMPLFilesError, match=rf"^{pkl}: refusing to load {name}"):
        B.load_model_arrays(pkl)
    scene = load_scene(spec(folder, smpl))  # the body is built on first use
    with pytest.raises(B.SMPLFilesError, match=rf"SMPL_NEUTRAL.pkl: refusing to load {name}"):
        scene.body_model()
    assert not marker.exists()
    assert listing(smpl) == before


@pytest.mark.parametrize("kind", ["truncated", "random", "empty"])
def test_damaged_smpl_pkl_gives_a_clear_error(copy, kind):
    _, smpl, _ = copy
    pkl = smpl / "SMPL_NEUTRAL.pkl"
    data = pkl.read_bytes()
    pkl.write_bytes({"truncated": data[: len(data) // 2], "empty": b"",
                     "random": np.random.default_rng(3).integers(0, 256, 4000, dtype=np.uint8).tobytes()}[kind])
    before = listing(smpl)
    expect = {"truncated": "found a truncated pickle stream", "empty": "found an empty file",
              "random": "found bytes that are not a valid pickle of it"}[kind]
    with pytest.raises(B.SMPLFilesError) as e:
        B.load_model_arrays(pkl)
    msg = str(e.value)
    assert msg.startswith(f"{pkl}: expected a pickled SMPL model (a dict of arrays), {expect}"), msg
    assert listing(smpl) == before
