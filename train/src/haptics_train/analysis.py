"""Statistical analysis of a dataset as the thesis did it (chapter 3.3 / 6.2): item statistics
(Table 3.2), Pearson and Spearman correlations, f_regression, mutual information, PCA."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402
from sklearn.decomposition import PCA  # noqa: E402
from sklearn.feature_selection import f_regression, mutual_info_regression  # noqa: E402

from .data import Dataset, Recording, row_stride  # noqa: E402
from .features import NINE, TARGET_DEFAULT  # noqa: E402

DPI = 80


def fmt(v: float) -> str:
    if isinstance(v, int):
        return str(v)
    if not np.isfinite(v):
        return str(v)
    a = abs(v)
    if a != 0 and (a >= 1e5 or a < 1e-3):
        return f"{v:.3e}"
    return f"{v:.4g}"


def md_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def item_statistics(x: np.ndarray, names: list[str]) -> list[dict]:
    """Table 3.2: count, mean, std, min, quartiles, max per item."""
    rows = []
    for j, n in enumerate(names):
        c = x[:, j]
        q = np.percentile(c, [25, 50, 75])
        rows.append({
            "item": n, "count": int(len(c)), "mean": c.mean(), "std": c.std(ddof=1),
            "min": c.min(), "25%": q[0], "50%": q[1], "75%": q[2], "max": c.max(),
        })  # fmt: skip
    return rows


def _heatmap(
    m: np.ndarray, names: list[str], title: str, path: Path, cols: list[str] | None = None
) -> None:
    cols = cols or names
    fig, ax = plt.subplots(figsize=(1.0 + 0.6 * len(cols), 1.0 + 0.5 * len(names)))
    im = ax.imshow(m, cmap="RdBu_r", vmin=-1, vmax=1, aspect="auto")
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            ax.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, fraction=0.04)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _bars(
    values: np.ndarray, names: list[str], title: str, ylabel: str, path: Path, log: bool = False
) -> None:
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(range(len(names)), values, color="tab:blue")
    ax.set_xticks(range(len(names)), names, rotation=45, ha="right", fontsize=8)
    if log:
        ax.set_yscale("log")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _loops(recs: list[Recording], path: Path, stride: int) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for r in recs:
        k = max(1, min(stride, len(r) // 2000))  # every row of a short (low-rate) recording
        ax.plot(1e3 * r.column("position_x")[::k], r.target()[::k], lw=0.6,
                label=f"{r.name}")  # fmt: skip
    ax.set_xlabel("compression x [mm]")
    ax.set_ylabel("F_res (RFOB) [N]")
    ax.set_title("Force-displacement loops of the recordings")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def analyze(
    dataset: Dataset,
    out: Path,
    decimate: int | None = None,
    mi_rows: int = 20_000,
    seed: int = 0,
    target_rate_hz: float = 500.0,
) -> Path:
    """Writes `analysis.md` and its PNGs into `out`; returns the Markdown path."""
    out.mkdir(parents=True, exist_ok=True)
    names = list(NINE)
    recs = dataset.train
    strides = [row_stride(r, decimate, target_rate_hz) for r in recs]
    x = np.concatenate([r.matrix(NINE, k) for r, k in zip(recs, strides, strict=True)])
    y = np.concatenate([r.target(TARGET_DEFAULT, k) for r, k in zip(recs, strides, strict=True)])
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y)
    x, y = x[ok], y[ok]
    allx = np.column_stack([x, y])
    alln = [*names, "F_res"]
    md = ["# Dataset analysis", ""]
    md.append(
        f"Training recordings ({', '.join(r.name for r in recs)}), every "
        f"{'/'.join(str(k) for k in sorted(set(strides)))}th row: {len(y)} rows. "
        f"Target F_res = `{TARGET_DEFAULT}` (the RFOB estimate). "
        "Held-out test recordings are not analysed here (they stay unseen)."
    )
    md += ["", "## Recordings", ""]
    md.append(md_table(
        ["split", "name", "rows", "rate [Hz]", "control steps per row", "duration [s]",
         "ramp rate [N/s]", "source", "sha256"],
        [[d["split"], d["name"], str(d["rows"]), f"{d['sample_rate_hz']:.4g}", str(d["row_step"]),
          f"{d['duration_s']:.1f}", str(d["ramp_rate"]), d["source"] or "-", d["sha256"]]
         for d in dataset.describe()],
    ))  # fmt: skip
    _loops(recs + dataset.validation + dataset.test, out / "loops.png", 20)
    md += ["", "![force-displacement loops](loops.png)", ""]

    md += ["## Item statistics (thesis Table 3.2)", ""]
    st = item_statistics(allx, alln)
    cols = ["count", "mean", "std", "min", "25%", "50%", "75%", "max"]
    md.append(md_table(["item", *cols], [[s["item"], *[fmt(s[c]) for c in cols]] for s in st]))
    md += [
        "",
        "The ratio features F_res(t-1)/x, /v, /a explode where the divisor crosses zero (the "
        "thesis saw +-1.4e7); tree models do not mind, the networks here see them through "
        "asinh scaling inside the graph, and the feature set `xva_f` uses F_res(t-1) itself.",
        "",
    ]

    pear = np.corrcoef(allx, rowvar=False)
    spear = stats.spearmanr(allx).statistic
    pear = np.nan_to_num(pear)
    spear = np.nan_to_num(np.asarray(spear))
    _heatmap(pear, alln, "Pearson correlation", out / "pearson.png")
    _heatmap(spear, alln, "Spearman rank correlation", out / "spearman.png")
    md += ["## Correlations", "", "![Pearson](pearson.png) ![Spearman](spearman.png)", ""]
    md.append(md_table(
        ["feature", "Pearson r with F_res", "Spearman rho with F_res"],
        [[n, f"{pear[j, -1]:.3f}", f"{spear[j, -1]:.3f}"] for j, n in enumerate(names)],
    ))  # fmt: skip

    fval, pval = f_regression(x, y)
    fval = np.nan_to_num(fval)
    rng = np.random.default_rng(seed)
    sub = rng.choice(len(y), min(mi_rows, len(y)), replace=False)
    mi = mutual_info_regression(x[sub], y[sub], random_state=seed)
    _bars(fval, names, "f_regression F score", "F", out / "f_regression.png", log=True)
    _bars(
        mi,
        names,
        f"mutual information (k-NN, {len(sub)} rows)",
        "MI [nats]",
        out / "mutual_info.png",
    )
    md += ["", "## Univariate scores", "", "![f_regression](f_regression.png) "
           "![mutual information](mutual_info.png)", ""]  # fmt: skip
    order = np.argsort(-mi)
    md.append(md_table(
        ["feature", "f_regression F", "p-value", "mutual information", "MI rank"],
        [[names[j], fmt(fval[j]), fmt(pval[j]), f"{mi[j]:.3f}",
          str(int(np.where(order == j)[0][0]) + 1)] for j in range(len(names))],
    ))  # fmt: skip

    z = (x - x.mean(axis=0)) / np.where(x.std(axis=0) > 0, x.std(axis=0), 1.0)
    pca = PCA().fit(z)
    evr = pca.explained_variance_ratio_
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(range(1, len(evr) + 1), evr, label="per component")
    ax.plot(range(1, len(evr) + 1), np.cumsum(evr), "o-", color="tab:red", label="cumulative")
    ax.set_xlabel("principal component")
    ax.set_ylabel("explained variance ratio")
    ax.legend(fontsize=8)
    ax.set_title("PCA on the standardised nine features", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "pca_variance.png", dpi=DPI)
    plt.close(fig)
    pcs = [f"PC{i + 1}" for i in range(len(evr))]
    _heatmap(pca.components_.T, names, "PCA loadings", out / "pca_loadings.png", cols=pcs)
    md += ["", "## Principal components", "", "![PCA variance](pca_variance.png) "
           "![PCA loadings](pca_loadings.png)", ""]  # fmt: skip
    md.append(md_table(
        ["component", "explained variance", "cumulative", "largest loadings"],
        [[pcs[i], f"{evr[i]:.3f}", f"{np.cumsum(evr)[i]:.3f}",
          ", ".join(f"{names[j]} {pca.components_[i, j]:+.2f}"
                    for j in np.argsort(-np.abs(pca.components_[i]))[:3])]
         for i in range(len(evr))],
    ))  # fmt: skip
    md.append("")
    path = out / "analysis.md"
    path.write_text("\n".join(md))
    return path
