"""Compiled kernels: numba's ``njit`` with an on-disk cache that works on any install.

Each stage's arithmetic is one kernel (a numba-compiled function; every call into compiled
code costs a few microseconds, so a stage calls one kernel per scan, not many small ones).
Kernels are declared with :func:`kernel` and compiled once per machine: the machine code is
cached on disk, so a later process loads it instead of compiling.

Where the cache is (decided once, when the first kernel is declared):

* ``NUMBA_CACHE_DIR`` when the user set it;
* else numba's default, ``__pycache__`` beside the kernels' source, when the package folder
  is writable (a development checkout, a user install);
* else (a read-only install, e.g. from apt or in a container) the user's cache,
  ``$XDG_CACHE_HOME/laser_tracker/numba`` or ``~/.cache/laser_tracker/numba``, created when
  missing; said once in the log (INFO);
* else no cache: every process compiles its kernels again (a few seconds at start); said
  once in the log (WARNING).

A damaged cache file (an index or a kernel that cannot be read back: a disk error, a copy
cut short) is a cache miss: that kernel is compiled again and its file rewritten; said
once in the log (WARNING).

A kernel is compiled with the kernels it calls, which may live in other modules; numba
would take a cached kernel as fresh while its own module is unchanged, so a kernel of this
package is cached under the contents of its module and of every module of the package that
module imports, directly or not (:func:`sources_stamp`): a changed module compiles the
kernels that may call into it again, never runs an old one.

:func:`compiled` runs a stage's first kernel call (at the stage's construction, with a tiny
input) so that compiling happens at start, not in the middle of the first scans, and so
that a machine where numba cannot compile (an unusual CPU that LLVM does not know) fails at
start with one line naming the fix (:class:`CompileError`, a ``ConfigError``: exit status 2
from the nodes and the command-line tools).
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
import re
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from laser_tracker.config import ConfigError

log = logging.getLogger(__name__)

#: The folder whose ``__pycache__`` numba uses by default (every kernel lives in core/).
PACKAGE_CACHE = Path(__file__).resolve().parent / '__pycache__'

#: What to set when numba cannot compile for this CPU.
CPU_FIX = 'NUMBA_CPU_NAME=generic'


class CompileError(ConfigError):
    """numba cannot compile (or load) the kernels on this machine; the message names the
    fix. A start-up problem of the machine's configuration (its CPU, numba's install), so
    the nodes and the command-line tools report it as they report a bad parameter: one line,
    exit status 2."""


def user_cache_dir(environ) -> Path:
    """``$XDG_CACHE_HOME/laser_tracker/numba``, or ``~/.cache/laser_tracker/numba``."""
    home = environ.get('HOME') or os.path.expanduser('~')
    base = environ.get('XDG_CACHE_HOME') or os.path.join(home, '.cache')
    return Path(base) / 'laser_tracker' / 'numba'


def writable(folder: Path) -> bool:
    """``folder`` exists or can be created, and a file can be written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def choose_cache(package_cache: Path | None = None,
                 environ=None) -> tuple[str | None, bool, tuple[int, str] | None]:
    """``(cache_dir, enabled, note)``: the folder to give numba (None: its default, in
    ``package_cache``, default :data:`PACKAGE_CACHE`), whether to cache at all, and what to
    log once (level, text) or None."""
    package_cache = PACKAGE_CACHE if package_cache is None else package_cache
    environ = os.environ if environ is None else environ
    chosen = environ.get('NUMBA_CACHE_DIR')
    if chosen:
        if writable(Path(chosen)):
            return chosen, True, None
        return None, False, (logging.WARNING, f'compiled kernels are not cached: '
                             f'NUMBA_CACHE_DIR={chosen} cannot be written; every start '
                             f'compiles them again')
    if writable(package_cache):
        return None, True, None
    user = user_cache_dir(environ)
    if writable(user):
        return str(user), True, (logging.INFO, f'compiled kernels are cached in {user} (the '
                                 f'package folder {package_cache.parent} is read-only)')
    return None, False, (logging.WARNING, f'compiled kernels are not cached: neither '
                         f'{package_cache} nor {user} can be written (set XDG_CACHE_HOME or '
                         f'NUMBA_CACHE_DIR to a writable folder); every start compiles them '
                         f'again')


_state: dict = {}          # 'cache': bool, 'note': (level, text) or None, once decided


def _configure():
    """Decide the cache once (before the first kernel is declared); return numba or None."""
    try:
        import numba
    except Exception as exc:  # noqa: BLE001 - not installed, or its LLVM cannot load
        _state.setdefault('cache', False)
        _state.setdefault('missing', ' '.join(f'{type(exc).__name__}: {exc}'.split()))
        return None
    if 'cache' not in _state:
        cache_dir, enabled, note = choose_cache()
        if cache_dir is not None:
            numba.config.CACHE_DIR = cache_dir
        _state.update(cache=enabled, note=note)
        _tolerate_damaged_cache()
        _stamp_with_every_kernel_module()
    return numba


def sources_stamp(module: Path) -> str:
    """A hash of the contents of ``module`` (a file of this package's ``core``) and of every
    module of ``core`` it imports, directly or not; once per process and module."""
    stamps = _state.setdefault('sources', {})
    module = Path(module).resolve()
    if module not in stamps:
        digest = hashlib.sha256()
        for path in sorted(_imported_modules(module)):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
        stamps[module] = digest.hexdigest()
    return stamps[module]


_IMPORT = re.compile(r'^\s*from\s+laser_tracker\.core((?:\.\w+)*)\s+import\s+(\([^)]*\)|[^\n]*)'
                     r'|^\s*import\s+laser_tracker\.core((?:\.\w+)+)', re.MULTILINE)


def _imported_modules(module: Path) -> set[Path]:
    """``module`` and the modules of its folder's package it imports (``from
    laser_tracker.core... import ...``, anywhere in it), transitively."""
    root = module.parent
    while (root.parent / '__init__.py').exists() and root.name != 'core':
        root = root.parent
    found, todo = set(), [module]
    while todo:
        path = todo.pop()
        if path in found or not path.is_file():
            continue
        found.add(path)
        for match in _IMPORT.finditer(path.read_text(errors='replace')):
            dotted = (match.group(1) or match.group(3) or '').strip('.')
            base = root.joinpath(*dotted.split('.')) if dotted else root
            todo += [base.with_suffix('.py'), base / '__init__.py']
            for name in re.findall(r'\w+', (match.group(2) or '').split('#')[0]):
                todo += [base / f'{name}.py', base / name / '__init__.py']
    return found


def _stamp_with_every_kernel_module() -> None:
    """numba's cache locators, for functions of this package, stamped with
    :func:`sources_stamp` besides their own module's stamp."""
    try:
        from numba.core import caching
    except ImportError:                 # another numba: its own behaviour
        return
    impl = getattr(caching, 'CacheImpl', None) or getattr(caching, '_CacheImpl', None)
    if impl is None or getattr(impl, '_stamped_with_every_kernel_module', False):
        return
    folder = str(PACKAGE_CACHE.parent) + os.sep

    def stamped(locator):
        class Stamped(locator):
            def get_source_stamp(self):
                stamp = super().get_source_stamp()
                path = os.path.realpath(self._py_file)
                if path.startswith(folder):
                    return stamp, sources_stamp(Path(path))
                return stamp
        Stamped.__name__ = Stamped.__qualname__ = f'Stamped{locator.__name__}'
        return Stamped

    ours = []
    for name in ('UserProvidedCacheLocator', '_UserProvidedCacheLocator',
                 'InTreeCacheLocator', '_InTreeCacheLocator'):
        locator = getattr(caching, name, None)
        if locator is not None and locator in impl._locator_classes:
            ours.append(stamped(locator))
    impl._locator_classes = ours + list(impl._locator_classes)
    impl._stamped_with_every_kernel_module = True


def _tolerate_damaged_cache() -> None:
    """numba's cache files, read so that a damaged one is a miss (the kernel is compiled and
    the file rewritten) instead of an error that stops every start."""
    try:
        from numba.core.caching import IndexDataCacheFile
    except ImportError:                 # another numba: its own behaviour
        return
    load_index = getattr(IndexDataCacheFile, '_load_index', None)
    load_data = getattr(IndexDataCacheFile, '_load_data', None)
    if load_index is None or load_data is None or \
            getattr(IndexDataCacheFile, '_damage_tolerated', False):
        return

    def _load_index(self):
        try:
            return load_index(self)
        except Exception as exc:  # noqa: BLE001 - whatever unpickling a damaged file raises
            _damaged(self._index_path, exc)
            return {}

    def _load_data(self, name):
        try:
            return load_data(self, name)
        except OSError:
            raise
        except Exception as exc:  # noqa: BLE001 - as above
            _damaged(self._data_path(name), exc)
            raise OSError(str(exc)) from exc       # numba's load: a miss

    IndexDataCacheFile._load_index = _load_index
    IndexDataCacheFile._load_data = _load_data
    IndexDataCacheFile._damage_tolerated = True


def _damaged(path: str, exc: Exception) -> None:
    """Say once that a damaged cache file is ignored."""
    if not _state.get('damaged'):
        _state['damaged'] = True
        log.warning('a damaged file of the compiled kernels\' cache is ignored (%s: %s: %s); '
                    'its kernels are compiled again', path, type(exc).__name__,
                    ' '.join(str(exc).split())[:100])


# Ctrl-C while numba runs: defined before this module first loads numba (``inline`` below),
# so that a SIGINT handler can use them while it loads.

#: Set when a Ctrl-C arrived while numba's compiler was calling back into Python (see
#: :func:`defer_interrupt`).
_interrupt_pending = threading.Event()


def in_numba_callback(frame) -> bool:
    """Whether ``frame``, or a frame that called it, is Python code that C calls back while
    numba runs: llvmlite's (LLVM, while numba loads or compiles a kernel) or numba's unpickling
    of a kernel's constants (at a kernel's first call). A KeyboardInterrupt raised there does
    not reach the program: ctypes prints and drops it, numba's C code turns it into a
    SystemError with a traceback."""
    while frame is not None:
        code = frame.f_code
        path = code.co_filename.replace('\\', '/')
        if '/llvmlite/' in path or (path.endswith('/numba/core/serialize.py')
                                    and code.co_name == '_numba_unpickle'):
            return True
        frame = getattr(frame, 'f_back', None)
    return False


def defer_interrupt(frame) -> bool:
    """For a SIGINT handler: True (and the interrupt remembered) when the signal arrived in
    code that numba's C code called back (:func:`in_numba_callback`);
    :func:`raise_deferred_interrupt` raises it later, in plain Python."""
    if not in_numba_callback(frame):
        return False
    _interrupt_pending.set()
    return True


def interrupt_pending() -> bool:
    """A Ctrl-C that :func:`defer_interrupt` kept back has not been raised yet."""
    return _interrupt_pending.is_set()


def raise_deferred_interrupt() -> None:
    """Raise the KeyboardInterrupt :func:`defer_interrupt` kept back, if any."""
    if _interrupt_pending.is_set():
        _interrupt_pending.clear()
        raise KeyboardInterrupt


def kernel(function: Callable) -> Callable:
    """``function`` compiled by numba (``njit``, cached on disk where possible). Floating
    point division by zero gives inf or NaN as in numpy (``error_model='numpy'``), not
    Python's ZeroDivisionError: kernels replace numpy code and keep its arithmetic."""
    numba = _configure()
    if numba is None:
        def missing(*args, **kwargs):
            raise CompileError(f'numba cannot be imported ({_state["missing"]}): install it '
                               f'(pip install numba, or apt install python3-numba)')
        return missing
    return numba.njit(cache=_state['cache'], nogil=True, error_model='numpy')(function)


def inline(function: Callable) -> Callable:
    """A small helper of kernels, compiled into each kernel that calls it (numba's
    ``inline='always'``): a call that passes arrays to a separately compiled function costs
    a reference count update per array, which in a per-point loop is most of the time.

    Inlined, an array argument still has its reference counted once per call unless numba
    can pair the count with its release: when the helper uses the array last in one branch
    and not in another (an early return, a read only some cells need), it cannot, and a
    helper called per point then costs tens of nanoseconds per array (atomic counts): give
    such a helper one exit and end it with :func:`alive` of its arrays."""
    numba = _configure()
    if numba is None:
        return kernel(function)
    return numba.njit(cache=_state['cache'], nogil=True, error_model='numpy',
                      inline='always')(function)


def _alive(arrays) -> None:
    """Nothing: the last use of the arrays ``arrays`` (a tuple), at the one exit of an
    :func:`inline` helper that reads some of them only in some branches, so that numba
    pairs their reference counts within the call and drops them (see :func:`inline`)."""


alive = inline(_alive)


def compiled(what: str, call: Callable[[], object]) -> None:
    """Run ``call`` (a first kernel call with a small valid input), once per process and
    ``what``: compiles, or loads from the cache, before the first real input. Raises
    :class:`CompileError` (one line, naming the fix) when numba cannot compile here. A call
    for ``what`` made while ``call`` runs (it may build the stage that asked) returns at
    once."""
    done = _state.setdefault('compiled', set())
    if what in done:
        return
    note = _state.pop('note', None)
    if note is not None:
        log.log(*note)
    done.add(what)
    try:
        call()
        raise_deferred_interrupt()
    except Exception as exc:  # noqa: BLE001 - whatever numba or LLVM raised
        done.discard(what)
        if isinstance(exc, CompileError):
            raise
        first = (str(exc).strip().splitlines() or [''])[0][:200]
        raise CompileError(f'numba cannot compile the {what} on this machine '
                           f'({type(exc).__name__}: {first}); start with {CPU_FIX} in the '
                           f'environment (an unusual CPU), or reinstall numba and '
                           f'llvmlite') from exc


@kernel
def unique(values):
    """``np.unique`` of a 1-D array (sorted, each value once); numba compiles its own
    np.unique about ten times slower than a sort."""
    out = np.sort(values)
    n = 0
    for i in range(out.size):
        if i == 0 or out[i] != out[n - 1]:
            out[n] = out[i]
            n += 1
    return out[:n]


@inline
def compare_length(dx, dy, limit):
    """-1 when the length of ``(dx, dy)`` is below ``limit``, 1 when above, by its square
    (far cheaper than ``math.hypot`` or a square root); 0 when the square lies within a
    relative 1e-9 of the limit's (far above their rounding errors) or the numbers are too
    large or small to square: then the caller decides by the length as it is to be computed
    (``hypot``, ``sqrt``), whose result the squares give everywhere else."""
    if 1e-100 < limit < 1e100 and abs(dx) < 1e100 and abs(dy) < 1e100:   # no overflow,
        d2 = dx * dx + dy * dy                                  # nothing lost below
        l2 = limit * limit
        if d2 < l2 * (1.0 - 1e-9):
            return -1
        if d2 > l2 * (1.0 + 1e-9):
            return 1
    return 0


# ------------------------------------------------------------------ numpy's summation orders
#
# A kernel that replaces numpy code and must give the same numbers bit for bit (so that
# every figure measured with the numpy code stays exactly as it was) has to add in the
# order numpy and its BLAS add. These helpers do, for the operations the kernels replaced;
# each was checked against numpy on random inputs (test/test_jit.py). The BLAS orders are
# those of OpenBLAS's AVX-512 kernels (numpy's wheels on x86-64 machines with AVX-512);
# where numpy runs other kernels, the kernels' results stay the same and numpy's differ in
# the last bits.

def _fma_intrinsic():
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic
    from llvmlite import ir

    @intrinsic
    def fma(typingctx, a, b, c):
        """``a * b + c`` rounded once (the FMA instruction, or libm's fma without it)."""
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            double = ir.DoubleType()
            fn = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(double, [double] * 3), 'llvm.fma.f64')
            return builder.call(fn, args)
        return sig, codegen
    return fma


fma = _fma_intrinsic() if _configure() is not None else None


@inline
def python_hypot(x, y):
    """``math.hypot(x, y)`` as CPython computes it (its ``vector_norm``: scaled, squared
    and summed in doubled precision, with a differential correction of the square root),
    which libm's hypot is not, for finite ``x, y`` not both subnormal."""
    x, y = abs(x), abs(y)
    largest = max(x, y)
    if largest == 0.0:
        return largest
    scale = math.ldexp(1.0, -math.frexp(largest)[1])
    csum, frac1, frac2 = 1.0, 0.0, 0.0
    for v in (x * scale, y * scale):
        hi = v * v
        low = fma(v, v, -hi)
        total = csum + hi
        frac2 += (csum - total) + hi
        csum = total
        frac1 += low
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    hi = -h * h
    low = fma(-h, h, -hi)
    total = csum + hi
    frac2 += (csum - total) + hi
    csum = total
    frac1 += low
    h += (csum - 1.0 + (frac1 + frac2)) / (2.0 * h)
    return h / scale


@kernel
def _block_sum(a, start, n):
    """numpy's pairwise sum of at most 128 values (8 accumulators)."""
    if n < 8:
        total = 0.0
        for i in range(start, start + n):
            total += a[i]
        return total
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    i = 8
    while i < n - n % 8:
        k = start + i
        r0 += a[k]
        r1 += a[k + 1]
        r2 += a[k + 2]
        r3 += a[k + 3]
        r4 += a[k + 4]
        r5 += a[k + 5]
        r6 += a[k + 6]
        r7 += a[k + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += a[start + i]
        i += 1
    return total


@kernel
def pairwise_sum(a, start, n):
    """``a[start:start + n].sum()`` as numpy adds: blocks of at most 128, summed in halves
    (numpy's recursion, unrolled: numba cannot cache a recursive function)."""
    if n <= 128:
        return _block_sum(a, start, n)
    # frames: start, length, and the left half's sum once known (phase 1 -> 2)
    starts = np.empty(64, np.int64)
    lengths = np.empty(64, np.int64)
    lefts = np.empty(64)
    phases = np.zeros(64, np.int64)
    starts[0], lengths[0], phases[0] = start, n, 0
    top = 1
    value = 0.0
    while top:
        f = top - 1
        if phases[f] == 0 and lengths[f] <= 128:
            value = _block_sum(a, starts[f], lengths[f])
            top -= 1
        elif phases[f] == 0:                     # descend into the left half
            half = lengths[f] // 2
            half -= half % 8
            phases[f] = 1
            starts[top], lengths[top], phases[top] = starts[f], half, 0
            top += 1
            continue
        elif phases[f] == 1:                     # the left half is done: the right one
            half = lengths[f] // 2
            half -= half % 8
            lefts[f] = value
            phases[f] = 2
            starts[top], lengths[top], phases[top] = starts[f] + half, lengths[f] - half, 0
            top += 1
            continue
        else:                                    # both halves done
            value = lefts[f] + value
            top -= 1
    return value


@kernel
def blas_dot(x, y, n):
    """``x[:n] @ y[:n]`` as OpenBLAS's ddot adds (n <= 10,000; beyond, OpenBLAS splits
    the sum between threads)."""
    full = n & -16
    dot = 0.0
    if full:
        wide = np.zeros(32)                  # four 8-lane accumulators
        i = 0
        while i + 32 <= full:
            for j in range(32):
                wide[j] = fma(x[i + j], y[i + j], wide[j])
            i += 32
        acc = np.empty(16)                   # narrowed to four 4-lane accumulators
        for q in range(4):
            for lane in range(4):
                acc[4 * q + lane] = wide[8 * q + lane] + wide[8 * q + lane + 4]
        while i < full:
            for j in range(16):
                acc[j] = fma(x[i + j], y[i + j], acc[j])
            i += 16
        v0 = ((acc[0] + acc[4]) + acc[8]) + acc[12]
        v1 = ((acc[1] + acc[5]) + acc[9]) + acc[13]
        v2 = ((acc[2] + acc[6]) + acc[10]) + acc[14]
        v3 = ((acc[3] + acc[7]) + acc[11]) + acc[15]
        dot = (v0 + v2) + (v1 + v3)
    for i in range(full, n):
        dot = fma(y[i], x[i], dot)
    return dot


@kernel
def einsum_dot(x, y, n):
    """``np.einsum('i,i->', x[:n], y[:n])`` (so also ``'ij,ij->'`` of contiguous arrays,
    flattened) as numpy adds: per buffer of 8,192 values two lanes, in blocks of 8 taken
    from their end; the buffers' sums added in turn."""
    total = 0.0
    for first in range(0, n, 8192):
        end = min(first + 8192, n)
        lane0 = 0.0
        lane1 = 0.0
        i = first
        while end - i >= 8:
            for q in (6, 4, 2, 0):
                lane0 = x[i + q] * y[i + q] + lane0
                lane1 = x[i + q + 1] * y[i + q + 1] + lane1
            i += 8
        while i < end:
            lane0 = x[i] * y[i] + lane0
            if i + 1 < end:
                lane1 = x[i + 1] * y[i + 1] + lane1
            i += 2
        total = total + (lane0 + lane1)
    return total
