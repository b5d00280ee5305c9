"""The compiled kernel (issue 28 item 1): droid._kernel, a CPython C extension built by pip at
install (``pip install -e .``; the project's metadata is in pyproject.toml).  It needs a C
compiler and Python's headers (Debian: build-essential python3-dev; scripts/venv.sh checks).

-O2 without fast-math and with -ffp-contract=off (no fused multiply-add): every floating-point
operation as the Python reference does it, so the kernel gives the same bits (droid/kernel.py).
"""
from setuptools import Extension, setup

FLAGS = ["-O2", "-fno-fast-math", "-ffp-contract=off", "-fno-strict-aliasing"]

# droid._guard: the collision guard's distance pass (issue 41; droid/guard/kernel.py), a file of its own
setup(ext_modules=[Extension("droid._kernel", ["droid/_kernel.c"], libraries=["m"], extra_compile_args=FLAGS),
                   Extension("droid._guard", ["droid/guard/_guard.c"], libraries=["m"], extra_compile_args=FLAGS)])
