"""Does live telemetry through the Python client keep up with the loop, and does a client reading
it make the loop late? Against a running system (scripts/up.sh, or any `Client()` finds):

    .venv/bin/python client/bench_telemetry.py --runs 3 [--decimation 10] [--model NAME]

Each run is one reproduction experiment (the simulated hand's programme, about 13 s) served by
the active model, alternately with a client reading the telemetry stream at `--decimation` loop
steps per bucket (the page's 10 by default) and without one. Per run: the loop's steps not on
time (the ladder's late_one + held + fallback), its overruns, and, with the client, the buckets
and steps received against those the run produced. Prints a table and one JSON line of medians.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
from typing import Any

import haptics


def one_run(c: haptics.Client, read: bool, decimation: int) -> dict[str, Any]:
    got: list[haptics.pb.TelemetrySample] = []
    stop = threading.Event()

    def reader() -> None:
        # its own connection: the reading client is a separate program in practice
        with haptics.Client(c.address, c.info.token) as rc:
            for s in rc.telemetry_rows(decimation, seconds=40):
                got.append(s)
                if stop.is_set():
                    break

    t = threading.Thread(target=reader, daemon=True)
    if read:
        t.start()
        time.sleep(0.5)
    c.start_experiment("reproduction")
    s = c.wait_experiment(timeout=60, poll_s=0.5)
    stop.set()
    if read:
        t.join(45)
    run_steps = s.on_time + s.late_one + s.held + s.fallback
    row: dict[str, Any] = {
        "client_reading": read,
        "run_steps": run_steps,
        "not_on_time": s.late_one + s.held + s.fallback,
        "late_one": s.late_one,
        "held": s.held,
        "fallback": s.fallback,
        "overruns": s.overruns,  # per run, like the ladder's counts
        "round_trip_p99_us": round(s.round_trip_latency.p99_us, 1),
    }
    if read:
        # the run's buckets: from the first whose step is 0 (a bucket never spans two runs)
        first = next((i for i, x in enumerate(got) if x.step == 0), None)
        mine = got[first:] if first is not None else []
        end = next((i for i in range(1, len(mine)) if mine[i].step <= mine[i - 1].step), None)
        mine = mine[:end] if end else mine
        received = sum(x.steps for x in mine)
        row.update(buckets_received=len(mine),
                   buckets_produced=-(-run_steps // decimation),
                   steps_received=received,
                   keep_up=round(received / run_steps, 5) if run_steps else 0.0)  # fmt: skip
    return row


def main() -> int:
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("--runs", type=int, default=3, help="runs with and runs without the reader")
    a.add_argument("--decimation", type=int, default=haptics.PAGE_DECIMATION)
    a.add_argument("--model", help="swap to this model first (default: the active one)")
    args = a.parse_args()
    with haptics.Client() as c:
        c.wait_experiment(timeout=120)
        if args.model:
            c.swap(args.model)
        model = c.active_model()
        print(f"{c}: model {model.name if model else '(fallback)'}, "
              f"decimation {args.decimation}")  # fmt: skip
        rows = []
        for i in range(2 * args.runs):
            r = one_run(c, read=i % 2 == 0, decimation=args.decimation)
            rows.append(r)
            print(json.dumps(r))
    out: dict[str, Any] = {"decimation": args.decimation, "runs_each": args.runs}
    for read in (True, False):
        rs = [r for r in rows if r["client_reading"] == read]
        key = "with_client" if read else "without_client"
        out[key] = {k: statistics.median(r[k] for r in rs)
                    for k in ("not_on_time", "late_one", "held", "fallback", "overruns",
                              "round_trip_p99_us", "run_steps")}  # fmt: skip
        if read:
            out[key]["keep_up_min"] = min(r["keep_up"] for r in rs)
            out[key]["buckets_received_median"] = statistics.median(
                r["buckets_received"] for r in rs
            )
            out[key]["buckets_produced_median"] = statistics.median(
                r["buckets_produced"] for r in rs
            )
    print("| | steps not on time (median) | late_one | held | fallback | overruns "
          "| round trip p99 µs |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for key in ("with_client", "without_client"):
        m = out[key]
        print(f"| {key.replace('_', ' ')} | {m['not_on_time']:g} of {m['run_steps']:g} | "
              f"{m['late_one']:g} | {m['held']:g} | {m['fallback']:g} | {m['overruns']:g} | "
              f"{m['round_trip_p99_us']:g} |")  # fmt: skip
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
