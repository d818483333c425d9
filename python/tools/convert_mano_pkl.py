#!/usr/bin/env python3
"""Convert the official MANO pickles (and MANO_SMPLX_vertex_ids.pkl) to .npz archives, with numpy only.

MANO_RIGHT.pkl and MANO_LEFT.pkl are Python 2 pickles holding chumpy arrays and a scipy.sparse J_regressor, so
loading them normally needs chumpy and scipy installed. This tool unpickles them with minimal stand-ins for those
classes, refuses every other class (a pickle is a program: a downloaded one must not run code), densifies the
arrays and writes them with numpy.savez_compressed under the same keys. sfgs reads the result
(csrc/body/mano.h, csrc/body/parts.h), and so does numpy.load(path, allow_pickle=False). Other SMPL-family
pickles of plain arrays (SMPLX_*.pkl) convert the same way.

    python3 python/tools/convert_mano_pkl.py MANO_RIGHT.pkl MANO_LEFT.pkl MANO_SMPLX_vertex_ids.pkl
    python3 python/tools/convert_mano_pkl.py MANO_RIGHT.pkl --output models/mano_right.npz --force

Non-array entries (MANO's 'bs_style' and 'bs_type' strings) are listed and left out. The left model's known
shapedirs bug (vchoutas/smplx#48) is repaired when sfgs loads both hands, not here: the converted file keeps the
official numbers.
"""
import argparse
import io
import pickle
import sys
from pathlib import Path

import numpy as np


class ConversionError(Exception):
    """A file that is not a body-model pickle this tool can convert; the message says why."""


class ChumpyStandIn:
    """Takes the place of chumpy.ch.Ch (and its subclasses): keeps the pickled attribute dictionary."""

    chumpy_class = "Ch"

    def __setstate__(self, state):
        self.state = state

    def to_array(self, key):
        state = getattr(self, "state", {})
        if "x" not in state:
            raise ConversionError(
                f"'{key}' is a chumpy expression ({self.chumpy_class}), not a stored array; only plain chumpy "
                "arrays (chumpy.ch.Ch) can be converted without chumpy")
        return np.asarray(state["x"])


class SparseStandIn:
    """Takes the place of a scipy.sparse CSC, CSR or COO matrix: keeps its pickled arrays and densifies them."""

    sparse_format = "csc"

    def __setstate__(self, state):
        self.state = state

    def to_array(self, key):
        s = getattr(self, "state", {})
        shape = tuple(int(n) for n in s.get("_shape", s.get("shape", ())))
        if len(shape) != 2:
            raise ConversionError(f"'{key}' is a scipy.sparse matrix without a 2-D shape")
        dense = np.zeros(shape, dtype=np.asarray(s["data"]).dtype)
        data = np.asarray(s["data"])
        if self.sparse_format == "coo":
            np.add.at(dense, (np.asarray(s["row"]), np.asarray(s["col"])), data)
            return dense
        indices, indptr = np.asarray(s["indices"]), np.asarray(s["indptr"])
        # CSC: indptr runs over columns and indices are rows; CSR the other way round.
        major = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        rows, cols = (indices, major) if self.sparse_format == "csc" else (major, indices)
        np.add.at(dense, (rows, cols), data)
        return dense


_SPARSE_FORMATS = {"csc_matrix": "csc", "csr_matrix": "csr", "coo_matrix": "coo",
                   "csc_array": "csc", "csr_array": "csr", "coo_array": "coo"}

# What a body-model pickle may reference besides chumpy and scipy.sparse: numpy's array and dtype reconstruction
# and object creation, under their Python 2 names (the official files) and Python 3 names.
_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("copy_reg", "_reconstructor"), ("copyreg", "_reconstructor"),
    ("__builtin__", "object"), ("__builtin__", "set"), ("__builtin__", "frozenset"),
    ("builtins", "object"), ("builtins", "set"), ("builtins", "frozenset"),
}


class _RestrictedUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module == "chumpy" or module.startswith("chumpy."):
            return type(name, (ChumpyStandIn,), {"chumpy_class": f"{module}.{name}"})
        if module.startswith("scipy.sparse"):
            if name not in _SPARSE_FORMATS:
                raise ConversionError(f"unsupported scipy.sparse class {module}.{name}")
            return type(name, (SparseStandIn,), {"sparse_format": _SPARSE_FORMATS[name]})
        if (module, name) in _ALLOWED:
            return super().find_class(module, name)
        raise ConversionError(f"refusing to load {module}.{name}: a body-model pickle holds only arrays "
                              "(numpy, chumpy, scipy.sparse)")


def load_pickle(path):
    """The top-level dictionary of a (Python 2 or 3) body-model pickle, with stand-ins for chumpy and scipy."""
    data = Path(path).read_bytes()
    try:
        # latin1 turns Python 2 byte strings (numpy's raw array data) back into the bytes they were.
        content = _RestrictedUnpickler(io.BytesIO(data), encoding="latin1").load()
    except ConversionError:
        raise
    except Exception as error:  # any malformed pickle: truncated, not a pickle at all, ...
        raise ConversionError(f"not a readable pickle ({type(error).__name__}: {error})") from error
    if not isinstance(content, dict):
        raise ConversionError(f"holds a {type(content).__name__}, not the dictionary of arrays of a model file")
    return content


def to_arrays(content):
    """Numeric arrays by key, and the keys left out (with the reason)."""
    arrays, skipped = {}, {}
    for key, value in content.items():
        key = key.decode("latin1") if isinstance(key, bytes) else str(key)
        if isinstance(value, (ChumpyStandIn, SparseStandIn)):
            value = value.to_array(key)
        if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
            arrays[key] = np.ascontiguousarray(value)
        elif isinstance(value, np.ndarray):
            skipped[key] = f"array of dtype {value.dtype}"
        else:
            skipped[key] = type(value).__name__
    if not arrays:
        raise ConversionError("holds no numeric arrays")
    return arrays, skipped


def convert(source, target, force=False):
    """Converts one pickle; returns the arrays written and the keys left out."""
    source, target = Path(source), Path(target)
    if not source.is_file():
        raise ConversionError("the file does not exist")
    if target.exists() and not force:
        raise ConversionError(f"'{target}' exists (pass --force to replace it)")
    arrays, skipped = to_arrays(load_pickle(source))
    temporary = target.with_name(target.name + ".partial.npz")
    np.savez_compressed(temporary, **arrays)
    temporary.replace(target)
    return arrays, skipped


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("inputs", nargs="+", type=Path, help="official .pkl files")
    parser.add_argument("-o", "--output", type=Path,
                        help="output .npz (one input only; default: the input's name with .npz)")
    parser.add_argument("--force", action="store_true", help="replace existing outputs")
    args = parser.parse_args(argv)
    if args.output is not None and len(args.inputs) != 1:
        parser.error("--output needs exactly one input")
    failed = False
    for source in args.inputs:
        target = args.output if args.output is not None else source.with_suffix(".npz")
        try:
            arrays, skipped = convert(source, target, args.force)
        except ConversionError as error:
            print(f"cannot convert '{source}': {error}", file=sys.stderr)
            failed = True
            continue
        print(f"{source} -> {target}")
        for key, array in arrays.items():
            print(f"  {key}: {array.dtype} {array.shape}")
        for key, why in skipped.items():
            print(f"  left out {key} ({why})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
