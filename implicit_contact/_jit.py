"""How the compiled kernels are compiled: numba, cached per machine, plain Python on request.

Every kernel of the package is a plain Python function over numpy arrays and floats, decorated
with ``kernel`` (numba's ``njit`` with the options below). With the environment variable
``NUMBA_DISABLE_JIT=1`` numba leaves the functions as they are, so every kernel runs, slowly, as
ordinary Python that a debugger can step through; the results are the same up to round-off.

Options, and why:
* ``cache=True``: a machine compiles once; the machine code is written next to each module
  (``__pycache__/*.nbi, *.nbc``) and loaded by later processes in milliseconds.
* ``error_model="numpy"``: a division by zero gives inf or NaN instead of raising
  ZeroDivisionError inside a step; the solver reports a non-finite row (status NOT_FINITE) and
  the stepper treats it as a failed solve, so no arithmetic error escapes mid-step.
* no ``fastmath``: NaN and inf must propagate as IEEE says (the solver tests for them) and
  results must not depend on reassociation.
* ``lean_kernel``: the kernels that allocate nothing are compiled without numba's runtime, so
  their array views carry no atomic reference counts (see there).

Cache validity. numba keys a cached kernel to the modification time of the file that defines
it, not to the files of the kernels it calls, so editing one kernel module would leave the
cached callers of its kernels stale. ``_invalidate_stale_cache`` below runs once, before any
kernel module is imported: it hashes the source of every kernel module and, if the hash differs
from the one stored with the cache, deletes the package's cached kernels so that they are
compiled afresh. An installed release never meets this (installing rewrites every file), a
development checkout does.
"""
from __future__ import annotations

import glob
import hashlib
import os

import numba
import numpy as np

# The modules that define kernels (paths relative to the package). Keep this list complete:
# a kernel module missing here could be served from a stale cache after an edit.
KERNEL_MODULES = ("_jit.py", "shape_kernels.py", "rows/__init__.py", "rows/bodies.py", "rows/contact.py",
                  "rows/dynamics.py", "rows/support.py", "rows/velocity.py", "rows/assemble.py", "rows/tables.py", "rows/checks.py", "ncp.py", "sparse_lu.py", "block_elimination.py", "closest.py",
                  "step_solver.py", "step_kernels.py", "memory.py", "repeat_kernels.py", "patch.py", "landing.py", "rattle.py",
                  "bundles.py")   # the bundles' types are in the signatures of the kernels that take them

_PACKAGE = os.path.dirname(os.path.abspath(__file__))
_STAMP = "implicit_contact_kernels.sha256"


def _source_hash() -> str:
    digest = hashlib.sha256(numba.__version__.encode())
    for rel in KERNEL_MODULES:
        path = os.path.join(_PACKAGE, rel)
        if os.path.exists(path):
            with open(path, "rb") as fh:
                digest.update(rel.encode() + b"\0" + fh.read())
    return digest.hexdigest()


def _cache_subfolders() -> tuple:
    """The folders numba gives this package's two source folders inside a cache root such as
    NUMBA_CACHE_DIR: the folder's name and the SHA1 of its absolute path
    (numba.core.caching._CacheLocator.get_suitable_cache_subpath), so the rows' kernels are
    under rows_<sha1>, a name without the package's."""
    folders = (_PACKAGE, os.path.join(_PACKAGE, "rows"))
    return tuple(os.path.basename(f) + "_" + hashlib.sha1(f.encode()).hexdigest() for f in folders)


def _cache_files(folder: str) -> list:
    """This package's cached kernels in one cache folder: a __pycache__ beside the modules, or a
    cache root (NUMBA_CACHE_DIR) with this package's subfolders (_cache_subfolders). Before
    2026-12-07 only paths containing "implicit_contact" were taken, which missed the rows' folder:
    with NUMBA_CACHE_DIR set, an edit of a kernel module left the cached row assembly calling the
    old rows (measured: an edit of rows/contact.py had no effect on a step)."""
    if folder.startswith(_PACKAGE):
        return glob.glob(os.path.join(folder, "*.nb[ic]"))
    return [p for sub in _cache_subfolders() for p in glob.glob(os.path.join(folder, sub, "*.nb[ic]"))]


def _cache_dirs() -> list:
    """Where numba writes this package's kernel caches: NUMBA_CACHE_DIR if set, else the
    __pycache__ folders beside the modules."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    if root:
        return [root]
    return [os.path.join(_PACKAGE, "__pycache__"), os.path.join(_PACKAGE, "rows", "__pycache__")]


def _invalidate_stale_cache() -> None:
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return
    want = _source_hash()
    for folder in _cache_dirs():
        stamp = os.path.join(folder, _STAMP)
        try:
            with open(stamp) as fh:
                if fh.read().strip() == want:
                    continue
        except OSError:
            pass
        try:
            os.makedirs(folder, exist_ok=True)
            for path in _cache_files(folder):
                os.remove(path)
            with open(stamp, "w") as fh:
                fh.write(want)
        except OSError:
            # a read-only install: numba falls back to its user-wide cache, keyed the same way
            pass


_invalidate_stale_cache()


def kernel(fn):
    """A compiled kernel (see the module docstring)."""
    return numba.njit(cache=True, error_model="numpy", nogil=True)(fn)


def lean_kernel(fn):
    """A compiled kernel without numba's runtime (NRT): it allocates nothing and returns no array.

    numba counts the references of every array view it makes (a slice, a row ``A[i]``, a
    reshape) with an atomic increment and decrement. The row kernels make dozens of views per
    pair of a step (workspace slices, rows of the function tables), and those atomics were most
    of their time: a pair's F at a 27-superquadric landing state 2.4 us with them, 0.84 us
    without; F and J 6.6 against 4.2 us (the same numbers bit for bit). Without the runtime no
    count is kept. That is safe for a kernel whose views live only while it runs and which
    allocates nothing (numba refuses to compile an allocation here): its callers' arrays hold the
    memory throughout. Its rules, checked by tests/test_lean_kernels.py:
    * it returns no view, except to another lean kernel (a kernel with the runtime would release
      a reference it never took);
    * it calls only lean kernels: numba compiles a kernel called from a lean one without the
      runtime too, unless that kernel was compiled already, so an allocation or a StructRef read
      in the callee fails to compile, or not, by the order in which a process meets them
      (measured: ncp.dense_newton under a lean dense_request, step_kernels' bundles under a lean
      kinematics);
    * it reads no StructRef (bundles.py): their fields need the runtime.
    numba's own sorting and string helpers are compiled the same way (``_nrt=False``)."""
    return numba.njit(cache=True, error_model="numpy", nogil=True, _nrt=False)(fn)


def generator_kernel(fn):
    """A compiled generator, not cached by itself.

    numba 0.68 cannot compile a function that consumes a generator which was loaded from the
    cache (KeyError in the lowering of the generator type; reproduced with a two-module
    example). So a generator is never cached on its own: the cached kernels that iterate it
    compile it into themselves, and Python gets its generator objects from a cached factory
    kernel (``return the_generator(...)``), which works both ways round."""
    return numba.njit(cache=False, error_model="numpy", nogil=True)(fn)


JIT_DISABLED = bool(numba.config.DISABLE_JIT)

# Flags and small integers for the call sites of kernels inside kernels. numba compiles a kernel
# called with a bare literal (``assemble(..., False, False)``, ``evaluate(..., 1)``) once per
# literal value, typed Literal[bool](False) or Literal[int](1), besides the bool / int64 version
# that Python's calls use: the whole tree of a pair's rows was compiled three times (measured:
# ~45 s of a ~140 s cold start). These are typed values, not literals, so one compilation serves
# every call.
TRUE, FALSE = np.bool_(True), np.bool_(False)
ZERO, ONE, TWO = np.int64(0), np.int64(1), np.int64(2)
