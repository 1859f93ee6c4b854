"""Builds line_odom (ament_python) and its C++17 engine (pybind11 + Eigen): line_odom_core._core, the module the node
imports, and line_odom_core._testing, the hooks of the tests and benchmarks."""
import glob
import os
import sys

from pybind11.setup_helpers import ParallelCompile, Pybind11Extension, build_ext
from setuptools import find_packages, setup

PACKAGE = "line_odom"
VERSION = "0.1.0"
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from build_support import HeaderAwareRecompile  # noqa: E402

engine_headers = sorted(glob.glob("line_odom_core/cpp/**/*.hpp", recursive=True))
ParallelCompile("LINE_ODOM_BUILD_JOBS", default=2, needs_recompile=HeaderAwareRecompile(engine_headers)).install()


class AtomicInplaceBuildExt(build_ext):
    """--inplace copies the extension over the old one; write a temporary file and rename it instead, so a
    process that has the old module loaded keeps a valid mapping."""

    def copy_file(self, infile, outfile, *args, **kwargs):
        if not self.inplace or not outfile.endswith((".so", ".pyd")):
            return super().copy_file(infile, outfile, *args, **kwargs)
        tmp = outfile + ".tmp"
        result = super().copy_file(infile, tmp, *args, **kwargs)
        os.replace(tmp, outfile)
        return result


def eigen_include_dir():
    candidates = [os.environ.get("EIGEN3_INCLUDE_DIR", ""), "/usr/include/eigen3", "/usr/local/include/eigen3",
                  os.path.join(os.environ.get("CONDA_PREFIX", "/nonexistent"), "include", "eigen3")]
    for path in candidates:
        if path and os.path.isfile(os.path.join(path, "Eigen", "Core")):
            return path
    raise RuntimeError("Eigen3 headers not found: install libeigen3-dev (apt) or set EIGEN3_INCLUDE_DIR "
                       "to the directory that contains Eigen/Core")


# The engine's sources (every folder but bindings/ and testing/) go into both modules; `_core` adds the bindings the
# node uses, `_testing` the hooks of the tests and benchmarks (testing/), so that the production module carries none.
CPP = "line_odom_core/cpp"
all_sources = sorted(glob.glob(f"{CPP}/**/*.cpp", recursive=True))
engine_sources = [s for s in all_sources if not s.startswith((f"{CPP}/bindings/", f"{CPP}/testing/"))]
binding_sources = sorted(glob.glob(f"{CPP}/bindings/*.cpp"))
testing_sources = sorted(glob.glob(f"{CPP}/testing/*.cpp"))
shared_binding_sources = [f"{CPP}/bindings/types.cpp", f"{CPP}/bindings/settings.cpp"]
# -fno-math-errno: the engine never reads errno, and with it GCC keeps a libm call and a branch beside every inlined
# sqrt (so no sqrt loop vectorizes). The square roots themselves are the same IEEE operation either way.
compile_flags = ["-O3", "-DNDEBUG", "-fvisibility=hidden", "-fno-math-errno"]


def engine_extension(name: str, sources: list[str]) -> Pybind11Extension:
    # the same flags and macros for both modules: an object file compiled for one is valid for the other
    return Pybind11Extension(
        name,
        sources,
        include_dirs=[eigen_include_dir(), CPP],
        depends=engine_headers,  # a header-only change rebuilds the extension too
        cxx_std=17,
        extra_compile_args=compile_flags,
        define_macros=[("LINE_ODOM_VERSION", f'"{VERSION}"'),
                       ("LINE_ODOM_COMPILE_FLAGS", '"' + " ".join(compile_flags) + '"')],
    )


core = engine_extension("line_odom_core._core", engine_sources + binding_sources)
testing = engine_extension("line_odom_core._testing", engine_sources + shared_binding_sources + testing_sources)

setup(
    name=PACKAGE,
    version=VERSION,
    packages=find_packages(include=["line_odom", "line_odom.*", "line_odom_core", "line_odom_core.*"]),
    package_data={"line_odom_core": ["py.typed", "*.pyi"], "line_odom": ["py.typed"]},
    ext_modules=[core, testing],
    cmdclass={"build_ext": AtomicInplaceBuildExt},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", sorted(glob.glob("config/*"))),
        ("share/" + PACKAGE + "/launch", sorted(glob.glob("launch/*.py"))),
        ("share/" + PACKAGE + "/rviz", sorted(glob.glob("rviz/*.rviz"))),
    ],
    install_requires=["setuptools", "numpy", "scipy", "pyyaml"],
    # `line_odom batch` only (the node never imports it); pinned in requirements/dev.txt, which make setup installs
    extras_require={"batch": ["dask", "distributed"]},
    zip_safe=False,
    maintainer="line_odom maintainers",
    maintainer_email="maintainers@line-odom.dev",
    description="Sparse-scan LiDAR and depth odometry from line-intersection constraints",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "node = line_odom.node:main",
            "lifecycle_node = line_odom.lifecycle_node:main",
            "line_odom = line_odom.cli:main",
        ],
    },
)
