"""Play a 30 s show to the servo emulator through real pyserial and measure the clock and tracking.

The emulator runs in its own process (`shadow-studio emulate`), as it would beside a real adapter, so the
player's timing is not disturbed by the emulator's thread. Target (issue 6): 40 Hz ± 0.5 %, p99 jitter ≤ 3 ms.
Reference in the same run: bare wake-ups on the same tick grid (no bus), the floor that the OS sets right now.
Last line: {"rate_hz", "jitter_p50_ms", "jitter_p99_ms", "commands", "max_tracking_error_rad", ...}.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hardware.calibration import load_calibration
from hardware.player import Player, _sleep_until
from hardware.serial_bus import BusConfig
from hardware.session import ServoSession
from studio.motion.show import Show, load_show, save_show
from studio.sim.hand import load_hand


def make_show(hand, seconds: float, cal) -> Show:
    """Every joint swings smoothly inside its soft range (peak speed ≈ 1.5 rad/s), starting at rest."""
    t = np.arange(0.0, seconds + 1e-9, 1 / 40)
    lo, hi = cal.lower + 0.05, cal.upper - 0.05
    rest = np.clip(hand.rest_pose(), lo, hi)
    amp = np.minimum(0.6, (hi - lo) / 2)
    mid = np.clip(rest, lo + amp, hi - amp)
    phase = np.arange(hand.dof) * 0.7
    freq = 0.25 + 0.02 * np.arange(hand.dof)
    wave = mid + amp * np.sin(2 * np.pi * freq * t[:, None] + phase)
    fade = np.clip(t / 2.0, 0, 1)[:, None]  # ease in from rest over 2 s
    q = rest + fade * (wave - rest)
    return Show.from_samples(hand, t, np.clip(q, hand.lower, hand.upper), title=f"bench {seconds:.0f} s")


def sleep_only_jitter_ms(seconds: float = 3.0, period: float = 1 / 40) -> np.ndarray:
    """Reference measured in the same run: lateness (ms) of bare wake-ups on the player's tick grid, no bus.
    It is the floor that the OS scheduler sets on this machine at this moment."""
    t0 = time.perf_counter() + 0.002
    late = []
    for k in range(int(seconds / period)):
        _sleep_until(t0 + k * period)
        late.append(time.perf_counter() - t0 - k * period)
    return np.abs(np.array(late)) * 1000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=30.0, help="show length (default 30)")
    args = ap.parse_args()
    hand = load_hand()
    cal = load_calibration(None, hand)
    ref = sleep_only_jitter_ms()
    proc = subprocess.Popen(
        [sys.executable, "-m", "studio.cli.main", "emulate"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        port = proc.stdout.readline().strip()
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "bench.json"
            save_show(make_show(hand, args.seconds, cal), path)
            show = load_show(path, hand)
        samples = []
        # the emulator runs in its own process (its timing apart from the player's); the port is opened, read back
        # and closed fail-safe as every face opens servos
        with ServoSession(port, calibration=cal, config=BusConfig(port, timeout_s=0.01, retries=0)) as session:
            bus = session.bus
            player = Player(bus, cal, on_sample=lambda t, c, m: samples.append((t, c, m)))
            r = player.play(show.times, show.positions, show.joint_names)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
    n = len(r.lateness_s)
    starts = r.t + r.lateness_s  # actual tick starts
    late_ms = np.abs(r.lateness_s) * 1000
    # raw error: each read-back against the command sent in the same tick (no allowance for servo lag)
    row = np.clip(np.searchsorted(r.t, r.measured_t, side="right") - 1, 0, n - 1)
    raw = np.abs(r.measured_rad - r.sent[row, r.measured_joint])
    print(f"{r.reason.value}: {r.message}; torque {r.torque}; bus stats {bus.stats}")
    print(
        json.dumps(
            {
                # clock rate: ticks of the schedule per second of wall time (skipped ticks reported below)
                "rate_hz": round((r.t[-1] - r.t[0]) * player.cfg.rate_hz / (starts[-1] - starts[0]), 4),
                "jitter_p50_ms": round(float(np.percentile(late_ms, 50)), 3),
                "jitter_p99_ms": round(float(np.percentile(late_ms, 99)), 3),
                "jitter_max_ms": round(float(late_ms.max()), 3),
                "sleep_only_p50_ms": round(float(np.percentile(ref, 50)), 3),
                "sleep_only_p99_ms": round(float(np.percentile(ref, 99)), 3),
                "jitter_p99_vs_sleep_only": round(float(np.percentile(late_ms, 99) / np.percentile(ref, 99)), 3),
                "commands": r.commands,
                "ticks": n,
                "skipped_ticks": r.skipped_ticks,
                "readbacks": len(r.measured_t),
                "max_tracking_error_rad": round(r.max_tracking_error_rad, 4),
                "max_raw_error_rad": round(float(raw.max()), 4),
                "completed": r.ok,
            }
        )
    )


if __name__ == "__main__":
    main()
