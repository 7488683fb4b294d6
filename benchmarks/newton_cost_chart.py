"""Chart: the cost per breather against N, dense against matrix-free, on each device: Newton (left), from the JSON
that ``benchmarks/newton_krylov.py --json`` writes, and its multipliers (right: dense Floquet, every multiplier,
against the window near +1 and -1, ``floquet(solver="window")``, the default above 1601 sites before 2026-11-27), from
``benchmarks/breather_scaling.py --json``;
either may also be a compact result set holding it (``benchmarks/results``).

Command: ``python benchmarks/newton_cost_chart.py --out newton-cost.png LABEL=FILE [LABEL=FILE ...]``, e.g.
``cpu=benchmarks/results/cpu-2core-2026-11-25c.json cpu=benchmarks/results/cpu-2core-2026-11-26.json``. Rows
with the same N in several files of one label keep the last, and the earlier value of a key the last lacks (a
dense timing where the later run stopped its dense runs at a smaller N).
"""

import argparse
import json
from pathlib import Path


def rows_of(path: Path) -> tuple[list, list]:
    """(Newton rows, Floquet rows) of a file: a benchmark's own JSON (its rows are one kind or the other) or a
    compact set's ``results["newton-krylov.json"]`` and ``results["scaling.json"]``."""
    data = json.loads(path.read_text())
    if "rows" in data:
        rows = data["rows"]
        return ([], rows) if rows and "krylov_floquet_seconds" in rows[0] else (rows, [])
    results = data["results"]
    return (
        results.get("newton-krylov.json", {}).get("rows", []),
        results.get("scaling.json", {}).get("rows", []),
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("sources", nargs="+", metavar="LABEL=FILE")
    ap.add_argument("--out", default="newton-cost.png")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    newton: dict = {}
    floq: dict = {}
    for source in args.sources:
        label, _, name = source.partition("=")
        n_rows, f_rows = rows_of(Path(name))
        for series, rows in ((newton, n_rows), (floq, f_rows)):
            for row in rows:  # a later row wins; a key it lacks (no dense run there) keeps the earlier value
                at = series.setdefault(label, {})
                at[row["N"]] = {**at.get(row["N"], {}), **row}
    labels = list(dict.fromkeys([*newton, *floq]))
    count = bool(newton) + bool(floq)
    fig, axes = plt.subplots(1, count, figsize=(6.5 * count, 4.5), layout="constrained", squeeze=False)
    panels = [
        (
            newton,
            (("dense_seconds", "dense", "s", "--"), ("krylov_seconds", "krylov", "o", "-")),
            "seconds per breather (Newton from the NLS seed)",
            "paper breather: dense against matrix-free Newton",
            "upper left",
        ),
        (
            floq,
            (
                ("dense_floquet_seconds", "dense Floquet (every multiplier)", "s", "--"),
                ("krylov_floquet_seconds", "window near +-1 (probe + shift-invert Arnoldi)", "o", "-"),
            ),
            "seconds per breather's multipliers",
            "its multipliers: dense Floquet against the window near +-1",
            "lower right",
        ),
    ]
    for ax, (series, curves, ylabel, title, where) in zip(axes[0], [p for p in panels if p[0]]):
        for label, rows in series.items():
            Ns = sorted(rows)
            for key, name, marker, style in curves:
                pts = [(n, rows[n][key]) for n in Ns if rows[n].get(key)]
                if pts:
                    x, y = zip(*pts)
                    ax.loglog(x, y, marker + style, color=f"C{labels.index(label)}", label=f"{label}: {name}")
        ax.set(xlabel="N (sites)", ylabel=ylabel)
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=8, loc=where)
    fig.savefig(args.out, dpi=130)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
