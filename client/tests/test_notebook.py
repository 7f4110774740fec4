"""docs/notebook.ipynb, executed top to bottom against the real system (nbclient), so the
example cannot go stale. It finds the system through HAPTICS_ADDR / HAPTICS_TOKEN here (the
test's server has its own port and token); its figures go to a temp folder."""

import time

from conftest import REPO, missing

NOTEBOOK = REPO / "docs" / "notebook.ipynb"


def test_notebook_runs_against_the_system(system, tmp_path, monkeypatch):
    try:
        import nbformat
        from nbclient import NotebookClient
    except ImportError as e:
        missing(f"nbclient/nbformat missing ({e}): scripts/setup.sh installs client[notebook]")
    monkeypatch.setenv("HAPTICS_ADDR", system.address)
    monkeypatch.setenv("HAPTICS_TOKEN", system.token)
    monkeypatch.setenv("HAPTICS_NOTEBOOK_FIGURES", str(tmp_path / "figures"))
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend
    nb = nbformat.read(NOTEBOOK, as_version=4)
    t0 = time.monotonic()
    NotebookClient(nb, timeout=240, kernel_name="python3",
                   resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()  # fmt: skip
    took = time.monotonic() - t0
    figs = sorted(p.name for p in (tmp_path / "figures").glob("*.png"))
    assert figs == ["notebook-abstraction.png", "notebook-swap.png"]
    images = sum("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code"
                 for o in c.outputs)  # fmt: skip
    assert images >= 4, images  # the live plots and the final figures
    print(f"notebook ran in {took:.1f} s, {images} images")
