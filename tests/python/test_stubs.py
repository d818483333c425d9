"""The type stubs shipped beside the module (python/sfgs/_C.pyi) describe the module as built: every public name of
sfgs._C is in them and nothing else, and every function's and method's parameters have the module's names, order and
keyword-only marker (read from pybind11's signature line)."""
import ast
import os

import pytest

import sfgs
from sfgs import _C

STUB = os.path.join(os.path.dirname(sfgs.__file__), "_C.pyi")
CONSTANTS = ["LOW_PASS_VARIANCE_PX2", "MAX_ALPHA", "MIN_ALPHA", "MIN_TRANSMITTANCE", "TILE_SIZE"]
# Names the stub defines for its own annotations.
STUB_ALIASES = {"Tensor", "TensorLike", "CameraDict", "PoseDict"}


def stub_tree():
    assert os.path.isfile(STUB), f"{STUB}: the stubs must be shipped beside the module"
    with open(STUB) as f:
        return ast.parse(f.read())


def split_top_level(text):
    parts, depth, current = [], 0, ""
    for character in text:
        if character in "([{":
            depth += 1
        elif character in ")]}":
            depth -= 1
        if character == "," and depth == 0:
            parts.append(current.strip())
            current = ""
        else:
            current += character
    if current.strip():
        parts.append(current.strip())
    return parts


def module_parameters(function, method):
    """Parameter names of a pybind11 function from its signature line, '*' where keyword-only ones start."""
    line = function.__doc__.split("\n")[0]
    inside = line[line.index("(") + 1:line.rindex(") ->")]
    names = [part.split(":")[0].split("=")[0].strip() for part in split_top_level(inside)]
    return names[1:] if method else names


def stub_parameters(definition, method):
    arguments = definition.args
    names = [a.arg for a in arguments.posonlyargs + arguments.args]
    if arguments.kwonlyargs:
        names += ["*"] + [a.arg for a in arguments.kwonlyargs]
    return names[1:] if method else names


def is_property(definition):
    return any(isinstance(d, ast.Name) and d.id == "property" for d in definition.decorator_list)


def public(names):
    return {n for n in names if not n.startswith("_") or n in ("__init__", "__call__", "__len__")}


def test_the_stubs_name_every_public_name_of_the_module_and_no_other():
    tree = stub_tree()
    defined = {node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
    defined |= {node.target.id for node in tree.body if isinstance(node, ast.AnnAssign)}
    defined |= {t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets}
    module_names = {n for n in dir(_C) if not n.startswith("_")}
    assert defined - STUB_ALIASES == module_names
    assert set(sfgs.__all__) | set(CONSTANTS) <= defined


def test_functions_have_the_modules_parameters():
    for node in stub_tree().body:
        if isinstance(node, ast.FunctionDef):
            assert stub_parameters(node, False) == module_parameters(getattr(_C, node.name), False), node.name


@pytest.mark.parametrize("class_name", ["Avatar", "Dataset", "Smplx", "Mano"])
def test_classes_have_the_modules_methods_and_properties(class_name):
    (stub_class,) = [n for n in stub_tree().body if isinstance(n, ast.ClassDef) and n.name == class_name]
    members = {n.name: n for n in stub_class.body if isinstance(n, ast.FunctionDef)}
    module_class = getattr(_C, class_name)
    module_members = public(vars(module_class))
    if not (getattr(vars(module_class).get("__init__"), "__doc__", None) or "").startswith("__init__("):
        module_members.discard("__init__")  # no constructor of its own (sfgs.read_dataset makes a Dataset)
    assert set(members) == module_members, class_name
    for name, definition in members.items():
        member = vars(module_class)[name]
        if isinstance(member, property):
            assert is_property(definition), f"{class_name}.{name} is a property"
        else:
            assert not is_property(definition), f"{class_name}.{name} is a method"
            assert stub_parameters(definition, True) == module_parameters(member, True), f"{class_name}.{name}"
