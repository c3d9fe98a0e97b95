"""Does a background job keep a notebook responsive? Main-thread event latency while a search job runs.

A notebook kernel handles a widget click on its main thread's event loop, so the figure is the delay of that loop:
an asyncio loop on the main thread schedules a callback every ``--period-ms`` (20 ms) and records how late each
one runs (actual − due), and each callback pulls the queue's events as a widget would. Measured for ``--seconds``
(10) while a gradient search job (``imitate_keyframe_job`` on the bundled ``asl_v.jpeg``: the shipped self-model,
``CPU_SEARCH``'s batch and step size with iterations enough to outlast the window, no refinement, ``--threads``
torch threads (default 1), live shadow previews on) runs in a **thread** worker and in a **process** worker
(spawn), and the reference, the same loop with **no job** ("idle"), measured in the same run. The window starts at
the job's first search event, so start-up (the process's imports, the model load) is reported apart; the job is
then cancelled and the time to its final event recorded. ``--cores 2`` pins the run (children inherit it) to 2
CPUs where the machine has more.

Printed: one line per condition, then a JSON object last: per condition the latency p50/p99/max (ms) and ticks,
and for the workers the stage's steps/s, start-up s, cancel s, events received; the ratios of p99 to idle, the
target (p99 ≤ 100 ms), and the workers that meet it.

``--stage refine`` measures the refinement instead (a 20-step search, then one long hill climb: the numba renderer
and PyBullet, which hold the GIL in their calls); ``--stage sweep`` the block sweep (all 32 retrieved poses swept,
passes until none improves: batches of 1,024 renders and compiled losses, also GIL-holding calls).

    python benchmarks/bench_jobs.py [--seconds 10] [--period-ms 20] [--workers thread,process] [--stage refine|sweep]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import time
from dataclasses import replace

import numpy as np

TARGET_P99_MS = 100.0


def measure_loop(seconds: float, period: float, on_tick=None) -> np.ndarray:
    """Lateness (s) of callbacks scheduled every ``period`` s on a fresh asyncio loop for ``seconds`` s."""
    late: list[float] = []

    async def main() -> None:
        loop = asyncio.get_running_loop()
        done = loop.create_future()
        t_end = loop.time() + seconds
        due = loop.time() + period

        def tick(due_at: float) -> None:
            now = loop.time()
            late.append(now - due_at)
            if on_tick is not None:
                on_tick()
            if now >= t_end:
                done.set_result(None)
                return
            nxt = due_at + period
            while nxt <= now:  # a stall skips the slots it missed (as a UI would), no burst of catch-up calls
                nxt += period
            loop.call_at(nxt, tick, nxt)

        loop.call_at(due, tick, due)
        await done

    asyncio.run(main())
    return np.asarray(late)


def stats(late: np.ndarray) -> dict:
    ms = late * 1000
    return {
        "p50_ms": round(float(np.percentile(ms, 50)), 2),
        "p99_ms": round(float(np.percentile(ms, 99)), 2),
        "max_ms": round(float(ms.max()), 2),
        "ticks": int(len(ms)),
    }


def run_worker(worker: str, args) -> dict:
    from studio.assets import asset

    from studio.imitate.config import CPU_SEARCH, RefineConfig
    from studio.jobs import JobQueue, JobState, imitate_keyframe_job

    target = asset("targets/asl_v.jpeg")
    if args.stage == "search":
        search = replace(CPU_SEARCH, iterations=1_000_000)
        job = imitate_keyframe_job(target, None, search=search, refine_enabled=False)
    elif args.stage == "sweep":  # every retrieved pose swept until a pass finds nothing: outlasts the window
        from studio.imitate.config import SweepConfig

        sweep = SweepConfig(starts=CPU_SEARCH.batch, passes=1_000)
        job = imitate_keyframe_job(target, None, search=replace(CPU_SEARCH, iterations=20), sweep=sweep,
                                   refine_enabled=False)  # fmt: skip
    else:  # a short search, then one long refinement (numba renderer + PyBullet: the GIL-heavy stage)
        search = replace(CPU_SEARCH, iterations=20)
        job = imitate_keyframe_job(target, None, search=search, refine=RefineConfig(steps=1_000_000), candidates=1)
    counts = {"events": 0}
    first: list[float] = []
    steps: list[tuple[float, int]] = []

    def on_event(e) -> None:  # what a widget subscriber does: note the newest state, cheaply
        counts["events"] += 1
        if e.stage == args.stage:
            steps.append((time.perf_counter(), e.step))
            if not first:
                first.append(time.perf_counter())

    with JobQueue(worker, threads=args.threads) as queue:
        queue.subscribe(on_event)
        t0 = time.perf_counter()
        queue.submit(job)
        while not first and not job.finished and time.perf_counter() - t0 < 300:
            time.sleep(0.01)
        if not first:
            raise RuntimeError(f"the {worker} job never reached its {args.stage} stage: {job.state.value} {job.error}")
        pulled = {"n": 0}
        late = measure_loop(
            args.seconds, args.period_ms / 1000, lambda: pulled.__setitem__("n", pulled["n"] + len(queue.events()))
        )
        t_cancel = time.perf_counter()
        job.cancel()
        state = job.wait(5.0)
        cancel_s = time.perf_counter() - t_cancel
    window = [(t, s) for t, s in steps if t <= t_cancel]
    rate = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0]) if len(window) > 1 else float("nan")
    out = stats(late) | {
        "steps_per_s": round(rate, 1),
        "startup_s": round(first[0] - t0, 2),
        "cancel_s": round(cancel_s, 3),
        "cancelled": state == JobState.CANCELLED,
        "events": counts["events"],
        "events_pulled": pulled["n"],
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0, help="measurement window per condition (default 10)")
    ap.add_argument("--period-ms", type=float, default=20.0, help="main-thread callback period (default 20)")
    ap.add_argument("--workers", default="thread,process", help="comma-separated: thread, process")
    ap.add_argument("--switch-ms", type=float, default=None, help="sys.setswitchinterval in ms (default: Python's)")
    ap.add_argument("--stage", choices=("search", "refine", "sweep"), default="search", help="the job's stage measured")
    ap.add_argument("--cores", type=int, default=2, help="pin to this many CPUs where there are more (0: no pin)")
    ap.add_argument("--threads", type=int, default=1, help="the job's torch CPU threads (default 1)")
    args = ap.parse_args()
    if args.threads < 1:
        ap.error(f"--threads must be at least 1, not {args.threads}")
    if args.cores and hasattr(os, "sched_setaffinity") and len(os.sched_getaffinity(0)) > args.cores:
        os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[: args.cores])
    if args.switch_ms is not None:
        sys.setswitchinterval(args.switch_ms / 1000)
    from studio.learn.threads import set_torch_threads

    set_torch_threads(args.threads)  # the thread worker shares this process's setting
    results: dict[str, dict] = {"idle": stats(measure_loop(args.seconds, args.period_ms / 1000))}
    print(f"idle      p50 {results['idle']['p50_ms']:6.2f} ms  p99 {results['idle']['p99_ms']:6.2f} ms", flush=True)
    for worker in args.workers.split(","):
        r = run_worker(worker.strip(), args)
        results[worker] = r
        print(
            f"{worker:9s} p50 {r['p50_ms']:6.2f} ms  p99 {r['p99_ms']:6.2f} ms  max {r['max_ms']:6.1f} ms  "
            f"{args.stage} {r['steps_per_s']:.1f} steps/s  start-up {r['startup_s']:.1f} s  "
            f"cancel {r['cancel_s']:.2f} s",
            flush=True,
        )
    idle99 = max(results["idle"]["p99_ms"], 1e-3)
    summary = {
        "conditions": results,
        "p99_over_idle": {w: round(results[w]["p99_ms"] / idle99, 2) for w in results if w != "idle"},
        "target_p99_ms": TARGET_P99_MS,
        "meets_target": [w for w in results if w != "idle" and results[w]["p99_ms"] <= TARGET_P99_MS],
        "stage": args.stage,
        "seconds": args.seconds,
        "period_ms": args.period_ms,
        "switch_interval_ms": round(sys.getswitchinterval() * 1000, 3),
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "cores": args.cores,
        "threads": args.threads,
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
