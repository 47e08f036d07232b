"""``laser-tracker bench sick``: the SICK driver against the simulator under injected faults.

Three phases over a real pseudo-terminal:

1. streaming with random corruption of telegrams (flipped bits, dropped and inserted bytes)
   plus bursts of garbage and NAKs on re-initialisation;
2. unplug / replug at the same path, alternately with a power cycle (the device comes back
   at 9600 baud, idle) and without (an adapter replugged while the laser keeps streaming);
3. the device going silent long enough for the driver to re-initialise it.

Figures: telegrams sent and corrupted, what the driver rejected, corrupted scans delivered
(must be 0), intact scans lost, scans recovered (intact telegrams right after a corrupted one
that were delivered), and the time from replug / end of silence to the next scan.
"""
from __future__ import annotations

import argparse
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from laser_tracker.sick.driver import SickLmsConfig, SickLmsDriver, SickScan
from laser_tracker.tools.sick_device import Lms2xxSimulator


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--baud', type=int, default=500000, choices=(9600, 19200, 38400, 500000),
                        help='line rate the driver runs at (default 500000)')
    parser.add_argument('--resolution', type=float, default=1.0, choices=(1.0, 0.5, 0.25))
    parser.add_argument('--stream-seconds', type=float, default=15.0,
                        help='length of the corruption phase')
    parser.add_argument('--fault-rate', type=float, default=0.05,
                        help='probability that a streamed telegram is corrupted')
    parser.add_argument('--unplugs', type=int, default=4, help='unplug/replug cycles')
    parser.add_argument('--speedup', type=float, default=1.0,
                        help='simulator speed-up (device clock and line rate)')
    parser.add_argument('--seed', type=int, default=0)


@dataclass
class Recorder:
    scans: list[SickScan] = field(default_factory=list)
    events: list[tuple[float, str, str]] = field(default_factory=list)
    arrived: threading.Event = field(default_factory=threading.Event)

    def on_scan(self, scan: SickScan) -> None:
        self.scans.append(scan)
        self.arrived.set()

    def on_event(self, state: str, message: str) -> None:
        self.events.append((time.monotonic(), state, message))

    def wait_scan(self, after: int, timeout: float) -> float | None:
        """Seconds until a scan beyond the first ``after`` ones arrives, or None."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if len(self.scans) > after:
                return time.monotonic() - t0
            self.arrived.clear()
            self.arrived.wait(0.01)
        return None


@dataclass
class BenchResult:
    telegrams_sent: int
    telegrams_corrupted: int
    crc_errors: int
    length_errors: int
    naks_injected: int
    garbage_bytes: int
    scans_delivered: int
    corrupted_delivered: int
    unknown_delivered: int
    intact_lost_streaming: int
    intact_not_delivered_total: int
    recovered_after_corruption: int
    followers_of_corruption: int
    reconnects: int
    replug_recovery_s: list[tuple[str, float | None]]
    silence_recovery_s: float | None
    duration_s: float


def run_benchmark(baud: int = 500000, resolution: float = 1.0, stream_seconds: float = 15.0,
                  fault_rate: float = 0.05, unplugs: int = 4, speedup: float = 1.0,
                  seed: int = 0) -> BenchResult:
    t_start = time.monotonic()
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(prefix='bench-sick-') as tmp:
        link = Path(tmp) / 'ttyLMS'
        sim = Lms2xxSimulator(link, baud=9600, speedup=speedup, seed=seed,
                              resolution_cdeg=int(round(resolution * 100)),
                              fault_kinds=('flip', 'drop', 'insert'))
        sim.start()
        rec = Recorder()
        cfg = SickLmsConfig(port=str(link), baud=baud, resolution=resolution, units='mm',
                            reply_timeout=0.3, silence_timeout=0.5, reconnect_period=0.2)
        driver = SickLmsDriver(cfg, rec.on_scan, on_event=rec.on_event, clock=time.monotonic)
        driver.start()
        garbage = 0
        naks = 0
        replug_times: list[tuple[str, float | None]] = []
        silence_time = None
        try:
            if rec.wait_scan(0, 20.0) is None:
                raise RuntimeError(f'driver did not start streaming: {rec.events[-3:]}')
            # phase 1: random corruption and garbage bursts while streaming
            streaming_from = len(sim.sent)
            sim.fault_rate = fault_rate
            t_end = time.monotonic() + stream_seconds
            while time.monotonic() < t_end:
                time.sleep(0.5)
                burst = rng.integers(0, 256, int(rng.integers(50, 500)), dtype=np.uint8)
                sim.inject_bytes(burst.tobytes())
                garbage += burst.size
            sim.fault_rate = 0.0
            time.sleep(0.3)
            streaming_until = len(sim.sent)
            # phase 2: unplug / replug; NAKs on the first commands after each replug
            for k in range(unplugs):
                power_cycle = k % 2 == 0
                sim.unplug()
                time.sleep(0.3)
                before = len(rec.scans)
                sim.replug(power_cycle=power_cycle)
                sim.nak_next(2)
                naks += 2
                replug_times.append(('power cycle' if power_cycle else 'adapter replug',
                                     rec.wait_scan(before, 15.0)))
                time.sleep(0.5)
            # phase 3: silence longer than the driver's watchdog
            sim.silence(1.0)
            time.sleep(1.0)
            before = len(rec.scans)
            silence_time = rec.wait_scan(before, 15.0)
            time.sleep(0.3)
        finally:
            driver.stop()
            sim.stop()
        stats = driver.stats()

    sent = list(sim.sent)
    delivered = {s.values.tobytes() for s in rec.scans}
    clean = {s.values.tobytes() for s in sent if s.corruption is None}
    damaged = {s.values.tobytes() for s in sent if s.corruption is not None}
    phase1 = sent[streaming_from:streaming_until]
    lost_streaming = sum(1 for s in phase1[:-3]
                         if s.corruption is None and s.values.tobytes() not in delivered)
    followers = [b for a, b in zip(phase1, phase1[1:]) if a.corruption and not b.corruption]
    return BenchResult(
        telegrams_sent=len(sent),
        telegrams_corrupted=sum(1 for s in sent if s.corruption),
        crc_errors=stats.crc_errors, length_errors=stats.length_errors,
        naks_injected=naks, garbage_bytes=garbage,
        scans_delivered=len(rec.scans),
        corrupted_delivered=sum(1 for s in rec.scans if s.values.tobytes() in damaged),
        unknown_delivered=sum(1 for s in rec.scans if s.values.tobytes() not in clean | damaged),
        intact_lost_streaming=lost_streaming,
        intact_not_delivered_total=len(clean - delivered),
        recovered_after_corruption=sum(1 for s in followers if s.values.tobytes() in delivered),
        followers_of_corruption=len(followers),
        reconnects=stats.reconnects, replug_recovery_s=replug_times,
        silence_recovery_s=silence_time, duration_s=time.monotonic() - t_start)


def _fmt(t: float | None) -> str:
    return 'never' if t is None else f'{t:.2f} s'


def run(args: argparse.Namespace) -> int:
    print(f'SICK LMS2xx driver vs simulator: {args.baud} baud, {args.resolution:g} deg, '
          f'fault rate {args.fault_rate:g}, {args.stream_seconds:g} s streaming, '
          f'{args.unplugs} unplugs, speed-up {args.speedup:g}', flush=True)
    r = run_benchmark(args.baud, args.resolution, args.stream_seconds, args.fault_rate,
                      args.unplugs, args.speedup, args.seed)
    print(f'telegrams sent                 {r.telegrams_sent}')
    print(f'telegrams corrupted (injected) {r.telegrams_corrupted}')
    print(f'garbage bytes injected         {r.garbage_bytes}')
    print(f'NAKs injected                  {r.naks_injected}')
    print(f'frames rejected by the driver  {r.crc_errors} CRC, {r.length_errors} length')
    print(f'scans delivered                {r.scans_delivered}')
    print(f'corrupted scans delivered      {r.corrupted_delivered}')
    print(f'unknown scans delivered        {r.unknown_delivered}')
    print(f'intact scans lost (streaming)  {r.intact_lost_streaming}')
    print(f'scans lost (all causes)        {r.telegrams_sent - r.scans_delivered} '
          f'({r.telegrams_corrupted} corrupted, {r.intact_not_delivered_total} intact '
          f'sent while unplugged, re-initialising or stopping)')
    print(f'scans recovered                {r.recovered_after_corruption} of '
          f'{r.followers_of_corruption} intact telegrams right after a corrupted one')
    print(f'reconnects                     {r.reconnects}')
    for kind, t in r.replug_recovery_s:
        print(f'recovery after {kind:<15} {_fmt(t)} (replug to first scan)')
    print(f'recovery after silence         {_fmt(r.silence_recovery_s)} (end of silence '
          f'to first scan)')
    print(f'benchmark time                 {r.duration_s:.1f} s', flush=True)
    return 0
