"""What a study's table says: sensitivities of each response to each input, and figures.

Sensitivity of response y to input x_j, from the successful samples:

* ``src``: standardized regression coefficient, the least-squares fit
  (y - mean y)/std y = sum_j b_j (x_j - mean x_j)/std x_j; b_j^2 is x_j's share of the
  variance of y where the inputs are independent and y nearly linear in them (the fit's
  ``r2`` says how nearly);
* ``correlation``: Pearson's correlation of x_j and y;
* ``gradient``: where the table has exact gradients, mean over samples of
  |dy/dx_j| std x_j / std y (the local sensitivity in the same standardized units).

The ranking orders the inputs by |gradient| where there are gradients, else by |src|
(rank 0 for each input of a response that does not vary).
Figures are matplotlib Figure objects saved to files (no global backend, no display).
Imports no JAX.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from jaxform.study.engine import as_arrays, read_table
from jaxform.study.spec import Study


def standardized_regression(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """(SRC of each column of x (n, d), r2 of the fit) for responses y (n,)."""
    sx, sy = x.std(axis=0), y.std()
    if sy == 0.0 or len(y) <= x.shape[1]:
        return np.full(x.shape[1], np.nan), np.nan
    zx = (x - x.mean(axis=0)) / np.where(sx > 0, sx, 1.0)
    zy = (y - y.mean()) / sy
    b, *_ = np.linalg.lstsq(zx, zy, rcond=None)
    r2 = 1.0 - np.sum((zy - zx @ b) ** 2) / np.sum(zy**2)
    return b, float(r2)


def correlations(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    sx, sy = x.std(axis=0), y.std()
    if sy == 0.0:
        return np.full(x.shape[1], np.nan)
    cov = ((x - x.mean(axis=0)) * (y - y.mean())[:, None]).mean(axis=0)
    return np.where(sx > 0, cov / np.where(sx > 0, sx, 1.0) / sy, 0.0)


def sensitivities(study: Study, rows: list[dict]) -> list[dict]:
    """One record per (response, input): src, r2, correlation, gradient index, rank."""
    keys = [i.key for i in study.inputs]
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return []
    x = np.stack([as_arrays(ok, keys)[k] for k in keys], axis=1)
    out = []
    for resp in study.responses:
        y = as_arrays(ok, [resp.name])[resp.name]
        src, r2 = standardized_regression(x, y)
        corr = correlations(x, y)
        grad = np.full(len(keys), np.nan)
        if study.gradients and y.std() > 0:
            names = [f"d_{resp.name}/d_{k}" for k in keys]
            g = np.stack([as_arrays(ok, [n])[n] for n in names], axis=1)
            grad = np.nanmean(np.abs(g), axis=0) * x.std(axis=0) / y.std()
        score = np.abs(grad) if study.gradients else np.abs(src)
        order = np.argsort(-np.nan_to_num(score, nan=-1.0), kind="stable")
        rank = np.zeros(len(keys), int)  # 0: no ranking (a constant response)
        if y.std() > 0:
            rank[order] = np.arange(1, len(keys) + 1)
        for j, k in enumerate(keys):
            out.append(dict(response=resp.name, input=k, src=float(src[j]), r2=r2,
                            correlation=float(corr[j]), gradient=float(grad[j]),
                            rank=int(rank[j])))  # fmt: skip
    return out


def write_sensitivities(records: list[dict], path) -> None:
    cols = ["response", "input", "rank", "src", "r2", "correlation", "gradient"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in records:
            w.writerow([repr(v) if isinstance(v, float) else v for v in (r[c] for c in cols)])


def main_effects(x: np.ndarray, y: np.ndarray, bins: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """(bin centres, mean response per bin) of one input: its distinct values where there
    are at most ``bins`` of them (levels), else quantile bins."""
    values = np.unique(x)
    if len(values) <= bins:
        return values, np.array([y[x == v].mean() for v in values])
    edges = np.quantile(x, np.linspace(0.0, 1.0, bins + 1))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    keep = [b for b in range(bins) if np.any(idx == b)]
    return (np.array([x[idx == b].mean() for b in keep]),
            np.array([y[idx == b].mean() for b in keep]))  # fmt: skip


def _figure(w: float, h: float, layout: str | None = "constrained"):
    """A Figure (grids of many small axes take ``layout=None`` and fixed margins: the
    constrained layout costs seconds there)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), layout=layout)
    if layout is None:
        fig.subplots_adjust(left=0.08, right=0.98, bottom=0.08, top=0.93, wspace=0.45, hspace=0.45)
    return fig


def write_figures(study: Study, out_dir, records: list[dict]) -> list[Path]:
    """scatter_matrix.png, main_effects.png and ranking.png of the successful samples."""
    out = Path(out_dir)
    rows = [r for r in read_table(out / "results.csv") if r["status"] == "ok"]
    if len(rows) < 2:
        return []
    keys = [i.key for i in study.inputs]
    names = [r.name for r in study.responses]
    data = as_arrays(rows, keys + names)
    paths = [out / "scatter_matrix.png", out / "main_effects.png", out / "ranking.png"]
    _scatter_matrix(data, keys + names, paths[0])
    _main_effects(data, keys, names, paths[1])
    _ranking(records, names, paths[2])
    return paths


def _scatter_matrix(data: dict, cols: list[str], path: Path) -> None:
    n = len(cols)
    fig = _figure(2.0 * n + 1, 2.0 * n + 1, layout=None)
    axes = fig.subplots(n, n, squeeze=False)
    for a, ca in enumerate(cols):
        for b, cb in enumerate(cols):
            ax = axes[a, b]
            if a == b:
                ax.hist(data[ca], bins=min(20, max(5, len(data[ca]) // 4)), color="0.6")
            else:
                ax.plot(data[cb], data[ca], ".", ms=3)
            if a == n - 1:
                ax.set_xlabel(cb, fontsize=7)
            if b == 0:
                ax.set_ylabel(ca, fontsize=7)
            ax.tick_params(labelsize=6)
    fig.suptitle("study samples: inputs and responses")
    fig.savefig(path, dpi=90)


def _main_effects(data: dict, keys: list[str], names: list[str], path: Path) -> None:
    fig = _figure(2.6 * len(keys) + 1, 2.3 * len(names) + 1, layout=None)
    axes = fig.subplots(len(names), len(keys), squeeze=False)
    for a, name in enumerate(names):
        for b, k in enumerate(keys):
            ax = axes[a, b]
            cx, my = main_effects(data[k], data[name])
            ax.plot(data[k], data[name], ".", ms=2, color="0.75")
            ax.plot(cx, my, "o-")
            ax.set_xlabel(k, fontsize=7)
            ax.set_ylabel(name, fontsize=7)
            ax.tick_params(labelsize=6)
    fig.suptitle("main effects: mean response per level or quantile bin of each input")
    fig.savefig(path, dpi=90)


def _ranking(records: list[dict], names: list[str], path: Path) -> None:
    fig = _figure(5.0, 1.8 * len(names) + 1)
    axes = fig.subplots(len(names), 1, squeeze=False)[:, 0]
    for ax, name in zip(axes, names):
        recs = sorted((r for r in records if r["response"] == name), key=lambda r: r["rank"])
        use_grad = any(np.isfinite(r["gradient"]) for r in recs)
        vals = [abs(r["gradient"] if use_grad else r["src"]) for r in recs]
        ax.barh([r["input"] for r in recs][::-1], vals[::-1])
        what = "mean |dy/dx| std x / std y" if use_grad else "|standardized regression coef.|"
        ax.set_title(f"{name}: {what}", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.savefig(path, dpi=90)
