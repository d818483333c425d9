"""Builds the Python module with CMake, for `pip install --no-build-isolation .` (pyproject.toml names this file).

Configures the project against the torch and pybind11 of the interpreter that runs pip, builds the module target
(sfgs_python) alone and packages python/sfgs with the built extension sfgs._C. Environment variables:

  SFGS_BUILD_DIR   the CMake build folder (default: build-pip/cmake in the source tree). A folder CMake has already
                   configured is reused as it is, so a machine's existing build is not compiled again; it must have
                   been configured for this interpreter (the build stops with a message otherwise).
  SFGS_CMAKE_ARGS  extra configure arguments, split as a shell would split them, e.g.
                   "-DSFGS_CUDA=ON -DSFGS_EXTRA_INCLUDE_DIRS=$PWD/.device/include"
  SFGS_BUILD_JOBS  parallel compile jobs (default: the number of CPUs)
"""
import os
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

SOURCE_DIR = Path(__file__).resolve().parent
# setuptools' own build folder: not build/, the CMake build folder the README's commands use.
SETUPTOOLS_BUILD_DIR = "build-pip"


def project_version():
    match = re.search(r"project\(sfgs VERSION ([0-9.]+)", (SOURCE_DIR / "CMakeLists.txt").read_text())
    if match is None:
        raise RuntimeError("CMakeLists.txt has no 'project(sfgs VERSION x.y.z' line to take the version from")
    return match.group(1)


def configure_arguments(build_dir):
    import torch  # the torch this module will be imported with; pip runs this file in that interpreter

    arguments = ["cmake", "-S", str(SOURCE_DIR), "-B", str(build_dir), "-DCMAKE_BUILD_TYPE=Release",
                 f"-DCMAKE_PREFIX_PATH={torch.utils.cmake_prefix_path}", f"-DPython_EXECUTABLE={sys.executable}",
                 "-DSFGS_BUILD_PYTHON=ON", "-DSFGS_BUILD_TESTS=OFF", "-DSFGS_BUILD_BENCH=OFF"]
    try:
        import pybind11
        arguments.append(f"-Dpybind11_DIR={pybind11.get_cmake_dir()}")
    except ImportError:
        pass  # CMake then looks for a system pybind11 (Debian: pybind11-dev)
    if shutil.which("ninja"):
        arguments += ["-G", "Ninja"]
    return arguments + shlex.split(os.environ.get("SFGS_CMAKE_ARGS", ""))


class CMakeExtension(Extension):
    """An extension CMake builds: setuptools compiles no sources of its own."""

    def __init__(self, name):
        super().__init__(name, sources=[])


class CMakeBuild(build_ext):
    def build_extension(self, ext):
        build_dir = Path(os.environ.get("SFGS_BUILD_DIR") or SOURCE_DIR / SETUPTOOLS_BUILD_DIR / "cmake").resolve()
        if (build_dir / "CMakeCache.txt").is_file():
            print(f"sfgs: reusing the configured CMake build folder {build_dir}", flush=True)
        else:
            subprocess.run(configure_arguments(build_dir), check=True)
        jobs = os.environ.get("SFGS_BUILD_JOBS") or str(os.cpu_count() or 1)
        subprocess.run(["cmake", "--build", str(build_dir), "--target", "sfgs_python", "--parallel", jobs], check=True)
        module_dir = build_dir / "python" / "sfgs"
        built = module_dir / ("_C" + sysconfig.get_config_var("EXT_SUFFIX"))
        if not built.is_file():
            found = ", ".join(sorted(p.name for p in module_dir.glob("_C*"))) or "nothing"
            raise RuntimeError(f"{build_dir} holds no module for this interpreter ({sys.executable}): expected "
                               f"{built.name}, found {found}; configure it with -DPython_EXECUTABLE={sys.executable} "
                               "or name a fresh SFGS_BUILD_DIR")
        destination = Path(self.get_ext_fullpath(ext.name))
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(built, destination)


setup(
    version=project_version(),
    packages=["sfgs"],
    package_dir={"": "python"},
    package_data={"sfgs": ["_C.pyi", "py.typed"]},
    ext_modules=[CMakeExtension("sfgs._C")],
    cmdclass={"build_ext": CMakeBuild},
    options={"build": {"build_base": SETUPTOOLS_BUILD_DIR}, "egg_info": {"egg_base": SETUPTOOLS_BUILD_DIR}},
)
