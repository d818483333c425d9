"""The module lives beside any torch without a preload: C++ exceptions reach Python as exceptions, and the built
module links no C++ library beyond torch's and the C++ runtime and exports nothing but its init function.

A shared yaml-cpp built by another compiler, loaded as the module's dependency into a pip-torch interpreter, once
crashed it on the first C++ exception; CMakeLists.txt builds yaml-cpp (third_party/) into the module and hides
the module's symbols.
The exceptions are raised in a child interpreter, so that a crash fails one test with its signal instead of ending
the whole pytest run."""
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap

import pytest

import sfgs

# Each case raises a C++ exception that must arrive as RuntimeError: thrown by the core (a bad shape), thrown by
# yaml-cpp and caught and re-thrown by the core (a checkpoint whose stored config is not YAML: the first checkpoint
# format, without a version entry, is still read), and thrown by libtorch's archive reader (a damaged checkpoint).
RAISING_CHILD = textwrap.dedent(r"""
    import os, sys
    import torch
    import sfgs

    def expect_runtime_error(what, call, pattern):
        try:
            call()
        except RuntimeError as error:
            if pattern not in str(error):
                sys.exit(f"{what}: RuntimeError without '{pattern}': {error}")
            print(f"{what}: raised RuntimeError", flush=True)
            return
        sys.exit(f"{what}: no exception raised")

    def render_with_two_coordinates():
        zeros = torch.zeros
        sfgs.render(zeros(4, 2), zeros(4), zeros(4, 3), zeros(3), torch.eye(4), 10.0, 10.0, 4.0, 4.0, 8, 8,
                    scales=zeros(4, 3), rotations=zeros(4, 4))

    def run_with_checkpoint(folder, entries):
        os.makedirs(folder)
        archive = torch.nn.Module()  # the format of torch::serialize::OutputArchive: a TorchScript module's tensors
        for name, tensor in entries.items():
            archive.register_buffer(name, tensor)
        torch.jit.save(torch.jit.script(archive), os.path.join(folder, "checkpoint.pt"))
        return folder

    def text(value):
        return torch.tensor(list(value.encode()), dtype=torch.uint8)

    scratch = sys.argv[1]
    expect_runtime_error("render with means of shape (4, 2)", render_with_two_coordinates, "means must have shape")
    bad_config = run_with_checkpoint(os.path.join(scratch, "bad_config"), dict(
        iteration=torch.tensor([1]), rng=text(""), dataset=text("nowhere"), betas=torch.zeros(10),
        config=text("avatar: [unclosed")))
    expect_runtime_error("load_avatar with a stored config that is not YAML", lambda: sfgs.load_avatar(bad_config),
                         "is not valid YAML")
    damaged = os.path.join(scratch, "damaged")
    os.makedirs(damaged)
    with open(os.path.join(damaged, "checkpoint.pt"), "wb") as file:
        file.write(b"not a checkpoint")
    expect_runtime_error("load_avatar with a damaged checkpoint", lambda: sfgs.load_avatar(damaged),
                         "is not a readable sfgs checkpoint")
""")


def test_cpp_exceptions_arrive_as_python_exceptions(tmp_path):
    environment = dict(os.environ)
    # The child imports the very module under test, wherever it was installed.
    package_parent = os.path.dirname(os.path.dirname(os.path.abspath(sfgs.__file__)))
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [package_parent, environment.get("PYTHONPATH")]))
    child = subprocess.run([sys.executable, "-c", RAISING_CHILD, str(tmp_path)], cwd=tmp_path, env=environment,
                           capture_output=True, text=True, timeout=300)
    report = f"stdout:\n{child.stdout}\nstderr (end):\n{child.stderr[-4000:]}"
    if child.returncode < 0:
        pytest.fail(f"the interpreter died of {signal.Signals(-child.returncode).name} while raising C++ exceptions "
                    f"through the module ({sfgs._C.__file__}):\n{report}")
    assert child.returncode == 0, report
    assert child.stdout.count("raised RuntimeError") == 3, report


# The module's ELF file: its dynamic section and dynamic symbols (Linux, binutils' readelf).
needs_readelf = pytest.mark.skipif(not sys.platform.startswith("linux") or shutil.which("readelf") is None,
                                   reason="needs Linux and readelf (binutils)")


def readelf(*arguments):
    return subprocess.run(["readelf", "-W", *arguments], check=True, capture_output=True, text=True).stdout


def dynamic_section(path):
    """The libraries an ELF file needs, and the names it is needed by (its file name and soname)."""
    section = readelf("--dynamic", path)
    needed = re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", section)
    names = {os.path.basename(path), *re.findall(r"\(SONAME\)\s+Library soname: \[([^\]]+)\]", section)}
    return needed, names


def loaded_torch_libraries():
    """Paths of the libtorch and c10 libraries this process loaded with `import torch`."""
    with open("/proc/self/maps") as maps:
        paths = {line.split()[-1] for line in maps if "/lib" in line}
    return sorted(p for p in paths if re.match(r"lib(torch|c10)\w*\.so", os.path.basename(p)))


# The C and C++ runtimes (GCC's, shared with every C++ library of the process, torch's included), the CUDA driver,
# and the C libraries libzip and zlib: nothing in them can take the place of the module's C++ code.
RUNTIME_LIBRARY = re.compile(r"(libc|libm|libdl|librt|libpthread|libstdc\+\+|libgcc_s|ld-linux[\w-]*|libcuda"
                             r"|libzip|libz)\.so(\.[\d.]+)?")


@needs_readelf
def test_module_links_no_cpp_library_beyond_torch_and_the_runtime():
    needed, _ = dynamic_section(sfgs._C.__file__)
    assert any(name.startswith("libc10") for name in needed), f"readelf found no libc10 among {needed}"
    torch_libraries = loaded_torch_libraries()
    assert torch_libraries, "found no libtorch or libc10 in /proc/self/maps after `import torch`"
    torch_own = set()  # torch's libraries and their own dependencies (CUDA's; on Debian also protobuf, glog, OpenCV)
    for path in torch_libraries:
        torch_needs, torch_names = dynamic_section(path)
        torch_own.update(torch_needs, torch_names)
    foreign = [name for name in needed if name not in torch_own and not RUNTIME_LIBRARY.fullmatch(name)]
    # Debian's libtorch itself links OpenCV: named here, the project's own C++ dependencies fail on every stack.
    shared_dependencies = [name for name in needed if re.match(r"lib(yaml-cpp|opencv_)", name)]
    assert not shared_dependencies, f"the module links the shared C++ libraries {shared_dependencies}"
    assert not foreign, (f"{sfgs._C.__file__} links {foreign}, beyond torch's libraries and the C/C++ runtime "
                         f"(all it needs: {needed})")


@needs_readelf
def test_module_exports_only_its_init_function():
    exported = []
    for line in readelf("--dyn-syms", sfgs._C.__file__).splitlines():
        fields = line.split()
        # Num: Value Size Type Bind Vis Ndx Name: a symbol the module defines and others can bind to.
        if len(fields) >= 8 and fields[0].endswith(":") and fields[6] != "UND" and fields[4] in ("GLOBAL", "WEAK",
                                                                                                   "UNIQUE"):
            exported.append(fields[7])
    assert exported == ["PyInit__C"], f"{sfgs._C.__file__} exports {len(exported)} symbols: {exported[:20]}"
