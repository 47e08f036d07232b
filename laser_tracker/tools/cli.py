"""``laser-tracker``: the offline commands (simulate, import, replay, evaluate, bench, ...).

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and
``run(args) -> int``; modules are imported only when their command runs, so a command never
pays for another's dependencies.
"""
from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from laser_tracker.errors import LaserTrackerError

#: Exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED = 130
#: A Ctrl-C kept back while numba's C code called back into Python is raised at most this
#: many seconds later (s).
INTERRUPT_RETRY = 0.05

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    'simulate': ('laser_tracker.tools.simulate', 'generate a scenario recording (rosbag2)'),
    'summarize': ('laser_tracker.tools.summarize', 'print what a recording holds'),
    'import-carmen': ('laser_tracker.tools.import_carmen',
                      'convert a CARMEN log to a rosbag2 recording'),
    'import-bag': ('laser_tracker.tools.import_bag',
                   'convert a ROS 1 bag (LaserScan, Odometry) to rosbag2'),
    'replay': ('laser_tracker.tools.replay', 'run ego-motion, detection and tracking on a bag'),
    'evaluate': ('laser_tracker.tools.evaluate', 'score a replay against ground truth'),
    'play': ('laser_tracker.tools.play', 'publish a recording into ROS 2 (as ros2 bag play)'),
    'demo': ('laser_tracker.tools.demo', 'replay and evaluate a bundled recording'),
    'animate': ('laser_tracker.tools.animate',
                'a GIF or MP4 of the scans with the tracks of a replay'),
    'bench': ('laser_tracker.tools.bench', 'benchmarks that print figures'),
    'train-detector': ('laser_tracker.tools.train_detector', 'train the person detector'),
    'sick-sim': ('laser_tracker.tools.sick_sim', 'a SICK LMS2xx device on a pseudo-terminal'),
    'config': ('laser_tracker.tools.config_file', 'write or check config/laser_tracker.yaml'),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='laser-tracker', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, (module, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, description=help_text).set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    top = build_parser()
    # Parse only the command name first; the command's own parser is built by its module.
    if not argv or argv[0] in ('-h', '--help') or argv[0] not in COMMANDS:
        top.parse_args(argv)  # prints help or a clear error and exits
    name = argv[0]
    module_name, help_text = COMMANDS[name]
    signal.signal(signal.SIGINT, _interrupt)
    try:
        module = importlib.import_module(module_name)
        parser = argparse.ArgumentParser(prog=f'laser-tracker {name}', description=help_text)
        module.add_arguments(parser)
        args = parser.parse_args(argv[1:])
        return int(module.run(args) or 0)
    except LaserTrackerError as exc:
        print(f'laser-tracker {name}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    except OSError as exc:   # an output that cannot be written, a disk that is full, ...
        where = f'{exc.filename}: ' if getattr(exc, 'filename', None) else ''
        print(f'laser-tracker {name}: error: {where}{exc.strerror or exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'laser-tracker {name}: interrupted', file=sys.stderr)
        return INTERRUPTED


def _jit():
    """``laser_tracker.core.jit`` once a command has imported it, else None. The command line
    does not import it itself: it loads numba, which takes a second, and a Ctrl-C then must
    find this module's handler installed and its ``try`` around the import."""
    return sys.modules.get('laser_tracker.core.jit')


def _interrupt(signum, frame) -> None:
    """Ctrl-C: KeyboardInterrupt, unless numba's C code is calling back into Python (it
    would not reach the program from there: ``jit.defer_interrupt``, defined before the
    module loads numba); then where the work next asks for it
    (``jit.raise_deferred_interrupt``), or :data:`INTERRUPT_RETRY` seconds later, whichever
    comes first."""
    defer = getattr(_jit(), 'defer_interrupt', None)
    if defer is None or not defer(frame):
        raise KeyboardInterrupt
    _retry_interrupt()


def _retry_interrupt() -> None:
    if hasattr(signal, 'setitimer'):
        signal.signal(signal.SIGALRM, _interrupt_later)
        signal.setitimer(signal.ITIMER_REAL, INTERRUPT_RETRY)


def _interrupt_later(signum, frame) -> None:
    """The retry of a Ctrl-C kept back: raised now, unless it has been raised already or the
    program is still inside numba's callback (then a moment later again)."""
    jit = _jit()
    if not jit.interrupt_pending():
        return
    if jit.in_numba_callback(frame):
        _retry_interrupt()
        return
    jit.raise_deferred_interrupt()


def console() -> int:
    """The ``laser-tracker`` executable: :func:`main`, and then nothing is left to stop. Python
    takes a few tenths of a second to shut down (its modules and the compiled kernels unload)
    after restoring the default SIGINT action, so a Ctrl-C then would kill the process by the
    signal, silently, after its work was done and said; it is ignored instead. An interrupted
    command ends here with status 130: a KeyboardInterrupt that passed through code run by
    ``exec`` (dataclasses make their methods so) marks it unhandled inside CPython even when
    caught, and Python would then end by killing itself with SIGINT at exit."""
    code = main()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, 'setitimer'):     # a retry of a Ctrl-C kept back (_interrupt)
        signal.setitimer(signal.ITIMER_REAL, 0.0)
    if code == INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


if __name__ == '__main__':
    sys.exit(console())
