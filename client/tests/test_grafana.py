"""ops/grafana/haptics.json: every metric its panels query exists in infer-server's /metrics,
and every panel's query is one ops/grafana/render.py evaluates (so the rendered panels cover
the whole dashboard)."""

import importlib.util
import json
import urllib.request
from typing import Any

from conftest import REPO

DASH = REPO / "ops" / "grafana" / "haptics.json"


def render_module():
    spec = importlib.util.spec_from_file_location("render", REPO / "ops" / "grafana" / "render.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def queries():
    dash = json.loads(DASH.read_text())
    return [(p["title"], t["expr"]) for p in dash["panels"] if p["type"] != "row"
            for t in p["targets"]]  # fmt: skip


def scrape_metrics(system: Any) -> Any:
    """GET /metrics with the system's token (infer-server needs it there too, unless started
    with --open-metrics)."""
    req = urllib.request.Request(f"{system.http}/metrics",
                                 headers={"Authorization": f"Bearer {system.token}"})  # fmt: skip
    return urllib.request.urlopen(req, timeout=5)


def test_every_metric_the_dashboard_queries_is_in_metrics(system, client):
    render = render_module()
    client.swap("soft_spring.onnx")  # an active model: haptics_active_model_info is written
    text = scrape_metrics(system).read().decode()
    scrape = render.parse(text)
    present = {name for name, _ in scrape}
    wanted = {m for _, e in queries() for m in render.metric_names(e)}
    assert len(wanted) >= 15, wanted
    assert sorted(wanted - present) == []
    # the ladder's four rungs and both upload refusal reasons are labelled series
    levels = {dict(lab).get("level") for name, lab in scrape if name == "haptics_steps_total"}
    assert levels == {"on_time", "late_one", "held", "fallback"}
    reasons = {dict(lab)["reason"] for name, lab in scrape
               if name == "haptics_model_uploads_refused_total"}  # fmt: skip
    assert reasons == {"too_large", "invalid"}


def test_every_panel_query_renders(system):
    render = render_module()
    scrapes = [render.parse(scrape_metrics(system)
                            .read().decode()) for _ in range(2)]  # fmt: skip
    for title, expr in queries():
        series = render.evaluate(expr, [0.0, 1.0], scrapes)
        assert series, (title, expr)


def test_a_refused_upload_is_counted(system, client, tmp_path):
    import pytest

    import haptics

    def refused():
        text = scrape_metrics(system).read().decode()
        return render_module().parse(text)[
            ("haptics_model_uploads_refused_total", (("reason", "invalid"),))]

    before = refused()
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00" * 64)
    with pytest.raises(haptics.BadModel):
        client.upload(bad)
    assert refused() == before + 1
