"""``laser-tracker sick-sim``: a SICK LMS2xx on a pseudo-terminal, for the driver node.

Prints the pty's slave path and the symlink to open (``port`` parameter of the node); the
link survives simulated unplugs, so a driver can reopen the same path.
"""
from __future__ import annotations

import argparse
import time

from laser_tracker.sick import protocol as P
from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.sick_device import (DEFAULT_LINK, DEFAULT_TYPE, Corruption,
                                          Lms2xxSimulator, RecordingSource, ScenarioSource)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--link', default=DEFAULT_LINK,
                        help=f'symlink to the pty that the driver opens (default {DEFAULT_LINK})')
    parser.add_argument('--baud', type=int, default=P.DEFAULT_BAUD,
                        help='rate the device starts at (default 9600, the power-on rate; '
                             'another value simulates a device at an unknown rate)')
    parser.add_argument('--speedup', type=float, default=1.0,
                        help='run the device clock (line rate, mirror) this many times faster')
    parser.add_argument('--scan-angle', type=int, choices=P.SCAN_ANGLES, default=180)
    parser.add_argument('--resolution', type=float, choices=(1.0, 0.5, 0.25), default=1.0,
                        help='initial variant resolution in degrees (the driver sets its own)')
    parser.add_argument('--units', choices=('mm', 'cm'), default='cm')
    parser.add_argument('--measuring-mode', type=lambda s: int(s, 0), default=0,
                        help='configuration byte 5 (0x00..0x06, 0x0F)')
    parser.add_argument('--type', default=DEFAULT_TYPE, dest='device_type',
                        help='type string answered to 0x3A')
    parser.add_argument('--recording', metavar='PATH',
                        help='replay ranges from a rosbag2 folder (/scan), .npy or .csv '
                             'instead of the built-in synthetic room')
    parser.add_argument('--topic', default='/scan', help='scan topic of --recording bags')
    parser.add_argument('--scenario', metavar='NAME',
                        help='take ranges from a scenario of the scenario simulator '
                             '(laser_tracker.tools.sim), e.g. exp1_stationary_single_walker')
    parser.add_argument('--fault-rate', type=float, default=0.0,
                        help='probability that a streamed telegram is corrupted')
    parser.add_argument('--faults', default='flip,drop,insert',
                        help='corruptions to draw from (flip, drop, insert)')
    parser.add_argument('--unplug-every', type=float, default=0.0, metavar='S',
                        help='disappear every S seconds (0: never)')
    parser.add_argument('--unplug-for', type=float, default=2.0, metavar='S',
                        help='stay away this long before reappearing at the same link')
    parser.add_argument('--keep-power', action='store_true',
                        help='on replug keep rate and streaming (adapter replugged) instead '
                             'of a power cycle (back to 9600, idle)')
    parser.add_argument('--boot-time', type=float, default=0.0,
                        help='seconds a power-cycled device ignores the host')
    parser.add_argument('--duration', type=float, default=0.0,
                        help='stop after this many seconds (0: until Ctrl-C)')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--quiet', action='store_true', help='no periodic status line')


def run(args: argparse.Namespace) -> int:
    if args.recording and args.scenario:
        raise SystemExit('laser-tracker sick-sim: give --recording or --scenario, not both')
    check_output(args.link, overwrite=True)       # the link is replaced when it exists
    ranges = None
    if args.recording:
        ranges = RecordingSource(args.recording, args.topic)
    elif args.scenario:
        try:
            ranges = ScenarioSource(args.scenario, args.seed or None)
        except ValueError as exc:
            raise SystemExit(f'laser-tracker sick-sim: {exc}') from None
    sim = Lms2xxSimulator(
        args.link, ranges, baud=args.baud, speedup=args.speedup, scan_angle=args.scan_angle,
        resolution_cdeg=int(round(args.resolution * 100)), units=args.units,
        measuring_mode=args.measuring_mode, device_type=args.device_type, seed=args.seed,
        boot_time=args.boot_time, fault_rate=args.fault_rate,
        fault_kinds=[Corruption(k.strip()) for k in args.faults.split(',') if k.strip()],
        record=False)
    link = sim.start()
    print(f'sick-sim: LMS2xx ({args.device_type}) on {sim.slave_name}, open {link} '
          f'(device at {args.baud} baud)', flush=True)
    t0 = last_report = next_unplug = time.monotonic()
    next_unplug += args.unplug_every if args.unplug_every > 0 else float('inf')
    try:
        while args.duration <= 0 or time.monotonic() - t0 < args.duration:
            time.sleep(0.1)
            now = time.monotonic()
            if now >= next_unplug:
                sim.unplug()
                print('sick-sim: unplugged', flush=True)
                time.sleep(args.unplug_for)
                sim.replug(power_cycle=not args.keep_power)
                print(f'sick-sim: back on {sim.slave_name} via {link}', flush=True)
                next_unplug = time.monotonic() + args.unplug_every
            if not args.quiet and now - last_report >= 5.0:
                last_report = now
                c = sim.counters
                state = 'streaming' if sim.device.streaming else 'idle'
                print(f'sick-sim: {state} at {sim.baud} baud, {c.scans_sent} scans sent, '
                      f'{c.scans_corrupted} corrupted, {c.requests} requests', flush=True)
    finally:
        sim.stop()
    return 0
