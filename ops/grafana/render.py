"""Renders the panels of ops/grafana/haptics.json from infer-server's /metrics without a Grafana
server (none is packaged for this machine): scrapes /metrics every `--interval` seconds while
the system runs, evaluates each panel's PromQL the way Prometheus would for the forms the
dashboard uses (a series, `rate(m[$__rate_interval])`, `sum by (l) (rate(...))`), and draws every
panel into one PNG with matplotlib.

    .venv/bin/python ops/grafana/render.py --url http://127.0.0.1:8080 --seconds 60 \\
        --out docs/figures/grafana-panels.png [--save-scrapes scrapes.jsonl]
    .venv/bin/python ops/grafana/render.py --from-scrapes scrapes.jsonl --out panels.png
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
import urllib.request
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
DASHBOARD = HERE / "haptics.json"

_SAMPLE = re.compile(r"^([a-zA-Z_:][a-zA-Z0-9_:]*)(?:\{(.*)\})?\s+(\S+)$")
_LABEL = re.compile(r'(\w+)="((?:[^"\\]|\\.)*)"')
_RATE = re.compile(r"^rate\((\w+)\[\$__rate_interval\]\)$")
_SUM_BY = re.compile(r"^sum by \((\w+)\) \((.*)\)$")
_PLAIN = re.compile(r"^(\w+)$")

#: one scrape: (metric name, sorted label pairs) -> value
Scrape = dict[tuple[str, tuple[tuple[str, str], ...]], float]
#: a series: its labels -> values over time (NaN where absent)
Series = dict[tuple[tuple[str, str], ...], list[float]]


def parse(text: str) -> Scrape:
    """Prometheus text format 0.0.4 samples."""
    out: Scrape = {}
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        m = _SAMPLE.match(line.strip())
        if not m:
            continue
        labels = tuple(sorted(_LABEL.findall(m.group(2) or "")))
        out[(m.group(1), labels)] = float(m.group(3))
    return out


def metric_names(expr: str) -> set[str]:
    """The metric names a dashboard expression reads."""
    return set(re.findall(r"\bhaptics_\w+", expr))


def evaluate(expr: str, times: list[float], scrapes: list[Scrape]) -> Series:
    """The expression's series over the scrapes, for the three forms the dashboard uses.
    ValueError for any other form (so a new panel cannot be skipped silently)."""
    m = _SUM_BY.match(expr)
    if m:
        inner = evaluate(m.group(2), times, scrapes)
        grouped: Series = defaultdict(lambda: [0.0] * len(times))
        for labels, values in inner.items():
            key = tuple((k, v) for k, v in labels if k == m.group(1))
            pairs = zip(grouped[key], values, strict=True)
            grouped[key] = [a + (0.0 if math.isnan(b) else b) for a, b in pairs]
        return dict(grouped)
    m = _RATE.match(expr)
    if m:
        raw = evaluate(m.group(1), times, scrapes)
        out: Series = {}
        for labels, values in raw.items():
            r = [math.nan]
            for i in range(1, len(values)):
                dt = times[i] - times[i - 1]
                dv = values[i] - values[i - 1]
                # a counter reset (a new run) counts from zero, as Prometheus does
                r.append((values[i] if dv < 0 else dv) / dt if dt > 0 else math.nan)
            out[labels] = r
        return out
    m = _PLAIN.match(expr)
    if m:
        keys = sorted({k[1] for s in scrapes for k in s if k[0] == m.group(1)})
        return {lab: [s.get((m.group(1), lab), math.nan) for s in scrapes] for lab in keys}
    raise ValueError(f"render.py does not evaluate {expr!r}")


def legend(fmt: str, labels: tuple[tuple[str, str], ...]) -> str:
    d = dict(labels)
    return re.sub(r"\{\{(\w+)\}\}", lambda m: d.get(m.group(1), ""), fmt) or fmt


def scrape(url: str, seconds: float, interval: float) -> tuple[list[float], list[Scrape]]:
    times: list[float] = []
    scrapes: list[Scrape] = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        # /metrics needs infer-server's token unless it runs with --open-metrics.
        token = os.environ.get("HAPTICS_TOKEN")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        req = urllib.request.Request(f"{url.rstrip('/')}/metrics", headers=headers)
        with urllib.request.urlopen(req, timeout=5) as r:
            scrapes.append(parse(r.read().decode()))
        times.append(time.monotonic() - t0)
        time.sleep(max(0.0, interval - (time.monotonic() - t0 - times[-1])))
    return times, scrapes


def render(times: list[float], scrapes: list[Scrape], out: Path) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dash = json.loads(DASHBOARD.read_text())
    panels = [p for p in dash["panels"] if p["type"] != "row"]
    cols = 3
    rows = math.ceil(len(panels) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(15, 2.6 * rows))
    for ax, p in zip(axes.flat, panels, strict=False):
        ax.set_title(p["title"], fontsize=10, loc="left")
        unit = p["fieldConfig"]["defaults"].get("unit", "")
        if p["type"] == "stat":
            text = []
            for t in p["targets"]:
                for labels, values in evaluate(t["expr"], times, scrapes).items():
                    last = values[-1]
                    if math.isnan(last):  # a series gone by the last scrape (a model swapped out)
                        continue
                    name = legend(t["legendFormat"], labels)
                    text.append(name if p["options"].get("textMode") == "name"
                                else f"{name}: {last:g}")  # fmt: skip
            ax.text(0.5, 0.5, "\n".join(text) or "no value", ha="center", va="center",
                    fontsize=12 if len(text) < 3 else 9, transform=ax.transAxes)  # fmt: skip
            ax.set_axis_off()
            continue
        for t in p["targets"]:
            for labels, values in evaluate(t["expr"], times, scrapes).items():
                ax.plot(times, values, lw=1, label=legend(t["legendFormat"], labels))
        ax.set_xlabel("s", fontsize=8)
        ax.set_ylabel("µs" if unit == "µs" else {"ops": "per s", "hertz": "Hz"}.get(unit, unit),
                      fontsize=8)  # fmt: skip
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(panels):]:
        ax.set_axis_off()
    fig.suptitle(f"{dash['title']}: the dashboard's panels over {times[-1]:.0f} s of /metrics "
                 "(rendered by ops/grafana/render.py, not Grafana)", fontsize=11)  # fmt: skip
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    return len(panels)


def main(argv: list[str] | None = None) -> int:
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("--url", default="http://127.0.0.1:8080", help="infer-server's HTTP address")
    a.add_argument("--seconds", type=float, default=60.0)
    a.add_argument("--interval", type=float, default=1.0)
    a.add_argument("--out", type=Path, required=True)
    a.add_argument("--save-scrapes", type=Path, help="keep the scrapes (JSON lines)")
    a.add_argument("--from-scrapes", type=Path, help="render scrapes saved earlier")
    args = a.parse_args(argv)
    if args.from_scrapes:
        lines = [json.loads(x) for x in args.from_scrapes.read_text().splitlines()]
        times = [x["t"] for x in lines]
        scrapes = [{(s[0], tuple(map(tuple, s[1]))): s[2] for s in x["samples"]} for x in lines]
    else:
        times, scrapes = scrape(args.url, args.seconds, args.interval)
    if args.save_scrapes:
        with args.save_scrapes.open("w") as fh:
            for t, s in zip(times, scrapes, strict=True):
                fh.write(json.dumps({"t": t, "samples": [[k[0], k[1], v] for k, v in s.items()]}))
                fh.write("\n")
    n = render(times, scrapes, args.out)
    print(f"render.py: {n} panels from {len(scrapes)} scrapes -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
