"""pip's way in: builds the package adaptiso through the project's CMake build (pyproject.toml names
setuptools, which Debian packages, as the backend; nothing is fetched at build time).

    pip install --no-build-isolation .                  # in a venv made with --system-site-packages
    python3 -m build --no-isolation --wheel             # dist/adaptiso-VERSION-cp311-cp311-linux_x86_64.whl

The version is CMakeLists.txt's project(VERSION), the one place it is written. CMake builds the
target adaptiso_python in build/pip (configured once, then incremental); ADAPTISO_CMAKE_BUILD_DIR
names an existing build tree configured with -DADAPTISO_BUILD_PYTHON=ON for the same interpreter
instead (scripts/test.sh passes its Release tree, so pip compiles nothing again). The wheel links
the system's shared libraries (TBB, GDCM, teem, nifti, ...), as Debian's packages provide them: it
is for machines with scripts/deps.sh's packages, not a manylinux wheel.
"""
import os
import re
import shutil
import subprocess
import sys
import sysconfig

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = os.path.dirname(os.path.abspath(__file__))


def project_version():
    with open(os.path.join(ROOT, "CMakeLists.txt"), encoding="utf-8") as f:
        m = re.search(r"project\(\s*adaptiso\s+VERSION\s+([0-9][0-9.]*)", f.read())
    if not m:
        raise RuntimeError("CMakeLists.txt: no project(adaptiso VERSION x.y.z)")
    return m.group(1)


def cache_value(build_dir, name):
    try:
        with open(os.path.join(build_dir, "CMakeCache.txt"), encoding="utf-8") as f:
            for line in f:
                if line.startswith(name + ":"):
                    return line.split("=", 1)[1].strip()
    except FileNotFoundError:
        return None
    return None


class CMakeBuild(build_ext):
    """Builds adaptiso._core with CMake and copies it where setuptools packs the wheel."""

    def build_extension(self, ext):
        build_dir = os.environ.get("ADAPTISO_CMAKE_BUILD_DIR")
        if build_dir:
            build_dir = os.path.abspath(build_dir)
            # A tree configured by someone else is used as it is: configuring it again here could
            # change its options (tests, sanitizers) under its owner.
            if cache_value(build_dir, "ADAPTISO_BUILD_PYTHON") not in ("ON", "TRUE", "1"):
                raise RuntimeError(f"ADAPTISO_CMAKE_BUILD_DIR={build_dir}: not a CMake tree configured with -DADAPTISO_BUILD_PYTHON=ON")
            # Its module must be one this interpreter imports: the same ABI tag (cpython-311-x86_64-...).
            theirs = cache_value(build_dir, "PYTHON_MODULE_EXTENSION")
            if theirs != sysconfig.get_config_var("EXT_SUFFIX"):
                raise RuntimeError(f"ADAPTISO_CMAKE_BUILD_DIR={build_dir}: configured for another Python "
                                   f"({cache_value(build_dir, '_Python3_EXECUTABLE')}, modules {theirs}), not {sys.executable}")
        else:
            build_dir = os.path.join(ROOT, "build", "pip")
            # A unity build: a fresh tree compiles in about half the time.
            configure = ["cmake", "-S", ROOT, "-B", build_dir, "-DCMAKE_BUILD_TYPE=Release", "-DCMAKE_UNITY_BUILD=ON", "-DADAPTISO_BUILD_PYTHON=ON",
                         "-DADAPTISO_BUILD_TESTS=OFF", "-DADAPTISO_BUILD_APPS=OFF", "-DADAPTISO_BUILD_BENCH=OFF",
                         "-DADAPTISO_BUILD_PEERS=OFF", f"-DPython3_EXECUTABLE={sys.executable}"]
            if shutil.which("ninja") and not os.path.exists(os.path.join(build_dir, "CMakeCache.txt")):
                configure += ["-G", "Ninja"]
            subprocess.run(configure, check=True)
        jobs = os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL") or str(os.cpu_count() or 1)
        subprocess.run(["cmake", "--build", build_dir, "--target", "adaptiso_python", "-j", jobs], check=True)
        built = os.path.join(build_dir, "python", "adaptiso", "_core" + sysconfig.get_config_var("EXT_SUFFIX"))
        if not os.path.exists(built):
            raise RuntimeError(f"CMake built no {built}")
        target = self.get_ext_fullpath(ext.name)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copy2(built, target)


# setuptools' own scratch (build/lib..., the egg-info) under build/setuptools, which git ignores,
# rather than beside the sources.
SCRATCH = os.path.join("build", "setuptools")
os.makedirs(os.path.join(ROOT, SCRATCH), exist_ok=True)

setup(
    version=project_version(),
    options={"build": {"build_base": SCRATCH}, "egg_info": {"egg_base": SCRATCH}},
    package_dir={"": "python"},
    packages=["adaptiso"],
    package_data={"adaptiso": ["__init__.pyi", "py.typed"]},
    ext_modules=[Extension("adaptiso._core", sources=[])],
    cmdclass={"build_ext": CMakeBuild},
    zip_safe=False,
)
