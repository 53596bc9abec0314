"""Build of the native MPM engine (``mpm._native``, C++ in mpm/native/) during ``pip install``.

The extension is optional: without a C++ compiler the project still installs and simulates on Taichi's CPU path
(mpm/runtime.py says so in one line at the first simulation). The C++ is portable (GCC, Clang, MSVC; x86 and
ARM); on x86 one build carries an AVX-512, an AVX2 and a generic path, chosen at run time from the CPU's features.
Everything else about the package is in pyproject.toml.
"""
import sys

from setuptools import Extension, setup

if sys.platform == "win32":
    FLAGS = ["/O2", "/std:c++17"]
else:
    FLAGS = ["-O3", "-std=c++17", "-fno-math-errno", "-fno-trapping-math", "-Wno-psabi"]

setup(ext_modules=[Extension(
    "mpm._native",
    sources=["mpm/native/engine.cpp"],
    depends=["mpm/native/kernel.h", "mpm/native/simd.h", "mpm/native/transfer.h", "mpm/native/types.h"],
    extra_compile_args=FLAGS,
    language="c++",
    optional=True,
)])
