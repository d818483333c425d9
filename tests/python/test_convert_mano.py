"""python/tools/convert_mano_pkl.py on pickles laid out like the official Python 2 MANO files: chumpy arrays, a
scipy.sparse J_regressor and numpy arrays whose raw data are Python 2 byte strings, written without chumpy or
scipy installed (stand-in classes under their module names, removed again before converting)."""
import pickle
import struct
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

TOOL = Path(__file__).resolve().parents[2] / "python" / "tools" / "convert_mano_pkl.py"


class Python2Pickler(pickle._Pickler):
    """Writes bytes and str the way Python 2 wrote its str (BINSTRING opcodes), as in the official files."""

    def write_string(self, data):
        if len(data) < 256:
            self.write(pickle.SHORT_BINSTRING + bytes([len(data)]) + data)
        else:
            self.write(pickle.BINSTRING + struct.pack("<i", len(data)) + data)

    def save_bytes(self, obj):
        self.write_string(obj)
        self.memoize(obj)

    def save_str(self, obj):
        self.write_string(obj.encode("latin1"))
        self.memoize(obj)

    dispatch = dict(pickle._Pickler.dispatch)
    dispatch[bytes] = save_bytes
    dispatch[str] = save_str


def fake_module(name, **classes):
    module = types.ModuleType(name)
    for class_name, cls in classes.items():
        cls.__module__ = name
        cls.__qualname__ = cls.__name__ = class_name
        setattr(module, class_name, cls)
    return module


class Ch:
    """chumpy.ch.Ch as pickled: its attribute dictionary, the array in 'x'."""

    def __init__(self, x):
        self.__dict__.update(x=x, _dirty_vars=set(), _itr=None, _depends_on_deps={}, _make_dense=False,
                             _make_sparse=False)


class Select(Ch):
    """A derived chumpy expression: no stored array."""

    def __init__(self, a):
        self.__dict__.update(a=a, idxs=np.arange(3), _dirty_vars=set())


class csc_matrix:
    """scipy.sparse.csc.csc_matrix as pickled by scipy 0.x."""

    def __init__(self, dense):
        self.__dict__.update(_shape=dense.shape, maxprint=50, format="csc")
        columns = [np.nonzero(dense[:, c])[0] for c in range(dense.shape[1])]
        self.indices = np.concatenate(columns).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum([len(c) for c in columns])]).astype(np.int32)
        self.data = np.concatenate([dense[c_rows, c] for c, c_rows in enumerate(columns)])


def write_official_style(path, content):
    modules = {"chumpy": fake_module("chumpy"), "chumpy.ch": fake_module("chumpy.ch", Ch=Ch, Select=Select),
               "scipy": fake_module("scipy"), "scipy.sparse": fake_module("scipy.sparse"),
               "scipy.sparse.csc": fake_module("scipy.sparse.csc", csc_matrix=csc_matrix)}
    saved = {name: sys.modules.get(name) for name in modules}
    sys.modules.update(modules)
    try:
        with open(path, "wb") as f:
            Python2Pickler(f, protocol=2).dump(content)
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module


def run_tool(*args):
    return subprocess.run([sys.executable, str(TOOL), *map(str, args)], capture_output=True, text=True)


@pytest.fixture
def mano(tmp_path):
    rng = np.random.default_rng(0)
    regressor = np.where(rng.random((16, 12)) < 0.3, rng.random((16, 12)), 0.0)
    content = {
        "v_template": rng.standard_normal((12, 3)),
        "f": rng.integers(0, 12, (20, 3)).astype(np.uint32),
        "weights": rng.random((12, 16)),
        "kintree_table": np.array([[4294967295, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14], list(range(16))],
                                  dtype=np.int64),
        "J": rng.standard_normal((16, 3)),
        "shapedirs": Ch(rng.standard_normal((12, 3, 10))),
        "posedirs": rng.standard_normal((12, 3, 135)),
        "J_regressor": csc_matrix(regressor),
        "hands_components": rng.standard_normal((45, 45)),
        "hands_mean": rng.standard_normal(45),
        "hands_coeffs": rng.standard_normal((1554, 45)),
        "bs_style": "lbs",
        "bs_type": "lrotmin",
    }
    path = tmp_path / "MANO_RIGHT.pkl"
    write_official_style(path, content)
    return path, content, regressor


def test_the_fake_files_really_need_chumpy_and_scipy(mano):
    path, _, _ = mano
    with pytest.raises((ModuleNotFoundError, AttributeError)):
        pickle.loads(path.read_bytes(), encoding="latin1")


def test_converts_chumpy_sparse_and_python2_arrays(mano):
    path, content, regressor = mano
    result = run_tool(path)
    assert result.returncode == 0, result.stderr
    with np.load(path.with_suffix(".npz"), allow_pickle=False) as npz:
        assert set(npz.files) == set(content) - {"bs_style", "bs_type"}
        np.testing.assert_array_equal(npz["shapedirs"], content["shapedirs"].x)
        np.testing.assert_array_equal(npz["J_regressor"], regressor)
        for key in ("v_template", "f", "weights", "kintree_table", "posedirs", "hands_components", "hands_mean"):
            np.testing.assert_array_equal(npz[key], content[key])
            assert npz[key].dtype == content[key].dtype
    assert "left out bs_style (str)" in result.stdout


def test_vertex_id_files_convert_too(tmp_path):
    path = tmp_path / "MANO_SMPLX_vertex_ids.pkl"
    ids = {"left_hand": np.arange(778, dtype=np.int64) * 3, "right_hand": np.arange(778, dtype=np.int64) * 5}
    write_official_style(path, ids)
    out = tmp_path / "ids.npz"
    assert run_tool(path, "--output", out).returncode == 0
    with np.load(out, allow_pickle=False) as npz:
        np.testing.assert_array_equal(npz["left_hand"], ids["left_hand"])
        np.testing.assert_array_equal(npz["right_hand"], ids["right_hand"])


def test_refuses_existing_outputs_unless_forced(mano):
    path, _, _ = mano
    assert run_tool(path).returncode == 0
    again = run_tool(path)
    assert again.returncode == 1 and "pass --force" in again.stderr
    assert run_tool(path, "--force").returncode == 0


def test_pickles_that_would_run_code_are_refused(tmp_path):
    marker = tmp_path / "executed"

    class Exploit:
        def __reduce__(self):
            return (subprocess.call, (["touch", str(marker)],))

    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"v_template": Exploit()}, protocol=2))
    result = run_tool(path)
    assert result.returncode == 1
    assert "refusing to load" in result.stderr and ".call" in result.stderr
    assert not marker.exists()


@pytest.mark.parametrize("content, message", [
    ({"x": Select(np.zeros(3))}, "chumpy expression"),
    ([np.zeros(3)], "not the dictionary of arrays"),
    ({"note": "no arrays"}, "holds no numeric arrays"),
])
def test_unconvertible_content_is_a_clear_error(tmp_path, content, message):
    path = tmp_path / "model.pkl"
    write_official_style(path, content)
    result = run_tool(path)
    assert result.returncode == 1
    assert f"cannot convert '{path}'" in result.stderr and message in result.stderr


def test_files_that_are_not_pickles_are_clear_errors(tmp_path):
    path = tmp_path / "model.pkl"
    path.write_bytes(b"PK\x03\x04 this is a zip, not a pickle")
    result = run_tool(path, tmp_path / "absent.pkl")
    assert result.returncode == 1
    assert "not a readable pickle" in result.stderr
    assert "absent.pkl': the file does not exist" in result.stderr
