"""Compiled kernels (core/jit.py): where the cache goes on any install, one clear line when
numba cannot compile, and the summation orders that keep results bit for bit those of numpy.
"""
from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from laser_tracker.core import jit

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable


# ------------------------------------------------------------------------ cache folder


def _unwritable(tmp_path: Path) -> Path:
    """A folder that can neither be created nor written, whoever runs the test (root
    included): it would sit below a regular file."""
    blocker = tmp_path / 'a-file'
    blocker.write_text('')
    return blocker / 'cache'


def test_a_writable_package_folder_keeps_numbas_own_cache(tmp_path):
    cache = tmp_path / 'pkg' / '__pycache__'
    assert jit.choose_cache(cache, {'HOME': str(tmp_path)}) == (None, True, None)
    assert cache.is_dir()                # a missing __pycache__ is created


def test_a_read_only_package_falls_back_to_the_users_cache_and_says_so(tmp_path):
    env = {'XDG_CACHE_HOME': str(tmp_path / 'xdg'), 'HOME': str(tmp_path / 'home')}
    folder, enabled, (level, text) = jit.choose_cache(_unwritable(tmp_path), env)
    assert enabled and folder == str(tmp_path / 'xdg' / 'laser_tracker' / 'numba')
    assert Path(folder).is_dir()         # created when missing
    assert level == logging.INFO and 'read-only' in text and folder in text
    # without XDG_CACHE_HOME: ~/.cache
    folder, _, _ = jit.choose_cache(_unwritable(tmp_path), {'HOME': str(tmp_path / 'home')})
    assert folder == str(tmp_path / 'home' / '.cache' / 'laser_tracker' / 'numba')


def test_no_writable_cache_anywhere_runs_without_cache_and_says_so(tmp_path):
    env = {'XDG_CACHE_HOME': str(_unwritable(tmp_path)), 'HOME': str(tmp_path)}
    folder, enabled, (level, text) = jit.choose_cache(_unwritable(tmp_path), env)
    assert (folder, enabled, level) == (None, False, logging.WARNING)
    assert 'not cached' in text and 'XDG_CACHE_HOME' in text


def test_the_users_numba_cache_dir_is_honoured_or_refused(tmp_path):
    mine = tmp_path / 'mine'
    assert jit.choose_cache(_unwritable(tmp_path), {'NUMBA_CACHE_DIR': str(mine)}) == \
        (str(mine), True, None)
    bad = _unwritable(tmp_path)
    folder, enabled, (level, text) = jit.choose_cache(tmp_path / 'pkg',
                                                      {'NUMBA_CACHE_DIR': str(bad)})
    assert (folder, enabled, level) == (None, False, logging.WARNING) and str(bad) in text


KERNEL_MODULE = '''
from laser_tracker.core import jit

@jit.kernel
def twice(x):
    return 2.0 * x
'''

READ_ONLY_RUN = '''
import logging, sys
logging.basicConfig(level=logging.INFO, format='%(levelname)s %(message)s')
sys.path.insert(0, sys.argv[1])
from laser_tracker.core import jit
import kernels
for _ in range(3):                      # said once, however many stages start
    jit.compiled('test kernel', lambda: kernels.twice(1.0))
assert kernels.twice(3.0) == 6.0
print('cache hits', sum(kernels.twice.stats.cache_hits.values()))
'''


@pytest.mark.skipif(not hasattr(os, 'geteuid') or os.geteuid() != 0
                    or shutil.which('setpriv') is None,
                    reason='a read-only install is simulated by running as another user '
                    '(needs root and setpriv)')
def test_a_read_only_install_caches_in_the_users_folder_across_processes():
    """The package folder belongs to root; as 'nobody' it is read-only: kernels are cached
    in the user's cache (created when missing) and the next process loads them."""
    base = Path(tempfile.mkdtemp(prefix='laser-tracker-jit-'))   # pytest's are private
    try:
        _read_only_install(base)
    finally:
        shutil.rmtree(base, ignore_errors=True)


def _read_only_install(tmp_path: Path) -> None:
    code = tmp_path / 'code'
    code.mkdir()
    (code / 'kernels.py').write_text(KERNEL_MODULE)
    (code / 'run.py').write_text(READ_ONLY_RUN)
    home = tmp_path / 'home'
    home.mkdir()
    os.chown(home, 65534, 65534)
    for p in (tmp_path, code, code / 'kernels.py', code / 'run.py'):
        os.chmod(p, 0o755)
    env = {k: v for k, v in os.environ.items()       # the venv's ROS bootstrap included
           if k not in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME')}
    env.update(HOME=str(home), PYTHONPATH=str(ROOT),
               XDG_CACHE_HOME=str(home / 'missing' / 'cache'))
    cmd = ['setpriv', '--reuid=65534', '--regid=65534', '--clear-groups', PYTHON,
           str(code / 'run.py'), str(code)]
    outputs = [subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
               for _ in range(2)]
    for out in outputs:
        assert out.returncode == 0, out.stderr
        assert out.stderr.count('read-only') == 1, out.stderr
    cache = home / 'missing' / 'cache' / 'laser_tracker' / 'numba'
    assert list(cache.rglob('kernels.twice-*.nbi')), list(cache.rglob('*'))
    assert 'cache hits 0' in outputs[0].stdout and 'cache hits 1' in outputs[1].stdout


DAMAGED_RUN = '''
import logging, sys
logging.basicConfig(level=logging.WARNING, format='%(levelname)s %(message)s')
sys.path.insert(0, sys.argv[1])
from laser_tracker.core import jit
import kernels
jit.compiled('test kernel', lambda: kernels.twice(1.0))
assert kernels.twice(3.0) == 6.0
print('cache hits', sum(kernels.twice.stats.cache_hits.values()))
'''


@pytest.mark.parametrize('damaged', ['nbi', 'nbc'])
def test_a_damaged_cache_file_is_compiled_again_and_rewritten(tmp_path, damaged):
    """A cache index or kernel that cannot be read back (a disk error, a copy cut short) is
    a miss, said once: the kernel is compiled again and the next start loads it."""
    (tmp_path / 'kernels.py').write_text(KERNEL_MODULE)
    (tmp_path / 'run.py').write_text(DAMAGED_RUN)
    env = {k: v for k, v in os.environ.items() if k not in ('NUMBA_CACHE_DIR',)}
    env.update(PYTHONPATH=str(ROOT))

    def start() -> subprocess.CompletedProcess:
        return subprocess.run([PYTHON, str(tmp_path / 'run.py'), str(tmp_path)], env=env,
                              capture_output=True, text=True, timeout=300)

    assert 'cache hits 0' in start().stdout
    for path in (tmp_path / '__pycache__').glob(f'kernels.twice-*.{damaged}'):
        path.write_bytes(path.read_bytes()[:20])
    out = start()
    assert out.returncode == 0 and 'cache hits 0' in out.stdout, out.stderr
    warnings = [ln for ln in out.stderr.splitlines() if 'damaged' in ln]
    assert len(warnings) == 1 and damaged in warnings[0], out.stderr
    out = start()
    assert 'cache hits 1' in out.stdout and 'damaged' not in out.stderr, out.stderr


def test_a_kernel_is_cached_under_the_modules_it_may_call_into(tmp_path):
    """A kernel is compiled with the kernels it calls in other modules: editing one of them
    must not leave its cached code in use, so a kernel's stamp covers its module and the
    package's modules it imports, directly or not (and no others)."""
    core = tmp_path / 'core'
    (core / 'sub').mkdir(parents=True)
    (core / 'a.py').write_text('from laser_tracker.core import b, jit\n')
    (core / 'b.py').write_text('def f():\n    from laser_tracker.core.sub.c import (x,\n'
                               '                                         y)\n')
    (core / 'sub' / 'c.py').write_text('x = y = 1\n')
    (core / 'jit.py').write_text('')
    (core / 'other.py').write_text('z = 2\n')
    assert {p.name for p in jit._imported_modules(core / 'a.py')} == \
        {'a.py', 'b.py', 'c.py', 'jit.py'}
    first = jit.sources_stamp(core / 'a.py')
    assert jit.sources_stamp(core / 'a.py') == first      # once per process and module
    (core / 'other.py').write_text('z = 3\n')
    jit._state['sources'].clear()
    assert jit.sources_stamp(core / 'a.py') == first      # not imported: no matter
    (core / 'sub' / 'c.py').write_text('x = y = 2\n')
    jit._state['sources'].clear()
    assert jit.sources_stamp(core / 'a.py') != first
    jit.unique(np.array([2, 1]))                          # the package's kernels carry it
    assert jit.unique._cache._cache_file._source_stamp[1] == \
        jit.sources_stamp(Path(jit.__file__))


# ----------------------------------------------------------------------- compile errors


def test_a_kernel_that_does_not_compile_is_one_line_naming_the_fix(monkeypatch):
    def broken():
        raise RuntimeError('LLVM ERROR: Cannot select: intrinsic %llvm.x86.foo\nmore\nlines')
    monkeypatch.setitem(jit._state, 'compiled', set())
    with pytest.raises(jit.CompileError) as err:
        jit.compiled('test kernels', broken)
    text = str(err.value)
    assert '\n' not in text and jit.CPU_FIX in text and 'Cannot select' in text
    assert 'test kernels' not in jit._state['compiled']   # tried again at the next start
    jit.compiled('test kernels', lambda: None)
    assert 'test kernels' in jit._state['compiled']


FAILING_COMPILE = '''
import sys
import numba.core.dispatcher as dispatcher

def fail(self, sig):
    raise RuntimeError('LLVM ERROR: 64-bit code requested on a subtarget that does not '
                       'support it\\n(details)')

dispatcher.Dispatcher.compile = fail
'''


def _run_with_failing_compile(tmp_path, main: str) -> subprocess.CompletedProcess:
    script = tmp_path / 'run.py'
    script.write_text(FAILING_COMPILE + textwrap.dedent(main))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([PYTHON, str(script)], env=env, capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)


def test_the_cli_exits_2_with_one_line_when_numba_cannot_compile(tmp_path):
    out = _run_with_failing_compile(tmp_path, f'''
        from laser_tracker.tools.cli import main
        sys.exit(main(['replay', {str(ROOT / 'bags' / 'exp1_stationary_single_walker')!r},
                       '--out', 'out', '--no-progress']))
        ''')
    assert out.returncode == 2, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if 'error' in ln]
    assert len(lines) == 1 and 'Traceback' not in out.stderr, out.stderr
    assert lines[0].startswith('laser-tracker replay: error: numba cannot compile')
    assert jit.CPU_FIX in lines[0]


def test_a_node_exits_2_with_one_line_when_numba_cannot_compile(tmp_path):
    from ros_env import isolate_ros_env
    isolate_ros_env()
    out = _run_with_failing_compile(tmp_path, '''
        from laser_tracker.nodes.launch import ego_motion
        sys.argv = ['ego_motion']
        ego_motion()
        ''')
    assert out.returncode == 2, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if 'numba' in ln]
    assert len(lines) == 1 and 'Traceback' not in out.stderr, out.stderr
    assert lines[0].startswith('ego_motion: numba cannot compile') and jit.CPU_FIX in lines[0]


# --------------------------------------------------------------- numpy's summation orders


@njit
def _fma(a, b, c):
    return jit.fma(a, b, c)


def test_fma_rounds_once():
    a = 1.0 + 2.0 ** -30
    # a * a = 1 + 2^-29 + 2^-60: the last term survives only in a fused operation
    assert _fma(a, a, -1.0) == 2.0 ** -29 + 2.0 ** -60
    assert a * a - 1.0 == 2.0 ** -29


def test_pairwise_sum_adds_as_numpy_sums():
    rng = np.random.default_rng(1)
    for n in list(range(0, 300)) + [1000, 4097, 100_000]:
        a = rng.normal(size=n) * 10.0 ** rng.integers(-3, 4, size=n)
        assert jit.pairwise_sum(a, 0, n) == a.sum(), n
    a = rng.normal(size=500)
    assert jit.pairwise_sum(a, 7, 300) == a[7:307].sum()


def test_einsum_dot_adds_as_numpy_einsum():
    rng = np.random.default_rng(2)
    for n in list(range(0, 200)) + [1001, 4096, 4097, 5000, 20_000]:
        p = rng.normal(size=(n, 2)) * 3.0
        flat = p.ravel()
        assert jit.einsum_dot(flat, flat, 2 * n) == np.einsum('ij,ij->', p, p), n


def _numpy_blas_in_avx512_order() -> bool:
    """True when numpy's BLAS adds as OpenBLAS's AVX-512 kernels do (sums of 999 random
    terms: equal in every bit only when added in the same order)."""
    rng = np.random.default_rng(0)
    pairs = [(rng.normal(size=999), rng.normal(size=999)) for _ in range(3)]
    return all(jit.blas_dot(x, y, x.size) == x @ y for x, y in pairs)


AVX512_ORDER = pytest.mark.skipif(
    not _numpy_blas_in_avx512_order(),
    reason="numpy's BLAS on this machine does not add in OpenBLAS's AVX-512 order (the "
    "kernels give the same numbers on every machine; numpy differs in the last bits)")


@AVX512_ORDER
def test_blas_dot_adds_as_numpys_blas():
    rng = np.random.default_rng(3)
    for n in list(range(0, 300)) + [1000, 4001, 10_000]:
        w = rng.random(n)
        r = rng.normal(size=n)
        assert jit.blas_dot(w, r * r, n) == w @ (r * r), n


@AVX512_ORDER
def test_icp_sums_add_as_the_numpy_formulation():
    """Residuals ``A [c, s, x, y, -1]`` and ``T^T (A w)^T A T`` (the Gauss-Newton normal
    equations) as numpy and its BLAS compute them."""
    from laser_tracker.core import icp

    rng = np.random.default_rng(4)
    for n in (3, 5, 16, 157, 361, 1000):
        a = rng.normal(size=(n, 5))
        th, x, y = rng.normal(size=3)
        c, s = np.cos(th), np.sin(th)
        r, w = np.empty(n), np.empty(n)
        icp._residuals(a, n, c, s, x, y, 4.0, r, w)
        r_np = a @ np.array([c, s, x, y, -1.0])
        assert np.array_equal(r, r_np)
        assert np.array_equal(w, 1.0 / (1.0 + (r_np * r_np) * 4.0))
        t = np.array([[0.0, 0.0, -s, c], [0.0, 0.0, c, s], [c, -s, 0.0, x],
                      [s, c, 0.0, y], [0.0, 0.0, 0.0, -1.0]])
        m = t.T @ ((a * w[:, None]).T @ a) @ t
        h, g0, g1, g2 = icp._normal_equations(a, n, w, c, s, x, y)
        assert np.array_equal(h, m[:3, :3]) and (g0, g1, g2) == tuple(m[:3, 3])


def test_a_ctrl_c_inside_numbas_callbacks_is_raised_after_the_warm_up(monkeypatch):
    """SIGINT while LLVM calls back into llvmlite's Python code (numba loading a kernel) would
    be printed and dropped by ctypes: the CLI's handler keeps it back, and it is raised when
    the warm-up returns; anywhere else it is raised at once. (The timed retry, which uses
    SIGALRM as pytest-timeout does, is left out here: tested in a process of its own.)"""
    from types import SimpleNamespace

    from laser_tracker.tools import cli
    from laser_tracker.tools.cli import _interrupt

    monkeypatch.setattr(cli, '_retry_interrupt', lambda: None)

    def frame(path):
        return SimpleNamespace(f_code=SimpleNamespace(co_filename=path, co_name='f'),
                               f_back=None)

    callback = frame('/venv/lib/python3.11/site-packages/llvmlite/binding/executionengine.py')
    _interrupt(2, callback)                                  # kept back, nothing raised
    with pytest.raises(KeyboardInterrupt):
        jit.compiled('a warm-up during which Ctrl-C came', lambda: None)
    jit.raise_deferred_interrupt()                           # raised once only
    with pytest.raises(KeyboardInterrupt):
        _interrupt(2, frame('laser_tracker/tools/replay.py'))
    with pytest.raises(KeyboardInterrupt):
        _interrupt(2, None)


def _caller_is_a_numba_callback() -> bool:
    return jit.in_numba_callback(sys._getframe())


class _ProbeOnUnpickling:
    """Unpickled, it reports whether its reconstruction runs inside a numba callback."""

    def __reduce__(self):
        return (_caller_is_a_numba_callback, ())


def test_numbas_unpickling_of_a_kernels_constants_is_a_callback():
    """At a kernel's first call numba's C code calls back into Python to unpickle the
    kernel's constants; a KeyboardInterrupt raised there becomes a SystemError with a
    traceback (a Ctrl-C in the first second of a replay did that), so it is kept back too."""
    import pickle

    from numba.core.serialize import _numba_unpickle

    data = pickle.dumps(_ProbeOnUnpickling())
    assert _numba_unpickle(0, data, b'laser_tracker test probe') is True
    assert not jit.in_numba_callback(sys._getframe())
    assert not jit.in_numba_callback(None)


def test_a_ctrl_c_kept_back_where_nothing_asks_for_it_is_raised_a_moment_later():
    """Kept back in a numba callback, a Ctrl-C is raised within the CLI's retry time even
    where the work never asks for it (a command without a scan loop); raised where it was
    asked for first, the retry raises nothing more. (A process of its own: the retry uses
    SIGALRM, as pytest-timeout does.)"""
    script = textwrap.dedent('''
        import time
        from types import SimpleNamespace
        from laser_tracker.core import jit
        from laser_tracker.tools import cli
        callback = SimpleNamespace(f_code=SimpleNamespace(
            co_filename='/venv/lib/python3.11/site-packages/llvmlite/binding/ffi.py',
            co_name='f'), f_back=None)
        cli._interrupt(2, callback)
        start = time.monotonic()
        try:
            time.sleep(2.0)
            print('not raised')
        except KeyboardInterrupt:
            print('raised after', round(time.monotonic() - start, 2), jit.interrupt_pending())
        cli._interrupt(2, callback)
        try:
            jit.raise_deferred_interrupt()
        except KeyboardInterrupt:
            pass
        time.sleep(3 * cli.INTERRUPT_RETRY)
        print('then nothing more')
    ''')
    out = subprocess.run([PYTHON, '-c', script], capture_output=True, text=True, timeout=120,
                         cwd=ROOT)
    lines = out.stdout.split('\n')
    assert out.returncode == 0 and lines[0].startswith('raised after'), out
    assert float(lines[0].split()[2]) < 1.0 and lines[0].endswith('False'), out
    assert lines[1] == 'then nothing more', out
