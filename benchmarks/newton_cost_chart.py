"""Chart: Newton's cost per breather against N, dense against matrix-free, on each device, from the JSON that
``benchmarks/newton_krylov.py --json`` writes (or a compact result set holding it, ``benchmarks/results``).

Command: ``python benchmarks/newton_cost_chart.py --out newton-cost.png LABEL=FILE [LABEL=FILE ...]``, e.g.
``cpu=benchmarks/results/cpu-2core-2026-11-25c.json h100=newton-krylov.json``. Rows with the same N in
several files of one label keep the last.
"""

import argparse
import json
from pathlib import Path


def rows_of(path: Path) -> list:
    """The benchmark's rows, from its own JSON or from a compact set's ``results["newton-krylov.json"]``."""
    data = json.loads(path.read_text())
    if "rows" not in data:
        data = data["results"]["newton-krylov.json"]
    return data["rows"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("sources", nargs="+", metavar="LABEL=FILE")
    ap.add_argument("--out", default="newton-cost.png")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series: dict = {}
    for source in args.sources:
        label, _, name = source.partition("=")
        for row in rows_of(Path(name)):
            series.setdefault(label, {})[row["N"]] = row
    fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
    for i, (label, rows) in enumerate(series.items()):
        Ns = sorted(rows)
        for path, marker, style in (("dense", "s", "--"), ("krylov", "o", "-")):
            pts = [(n, rows[n].get(f"{path}_seconds")) for n in Ns if rows[n].get(f"{path}_seconds")]
            if pts:
                x, y = zip(*pts)
                ax.loglog(x, y, marker + style, color=f"C{i}", label=f"{label}: {path}")
    ax.set(xlabel="N (sites)", ylabel="seconds per breather (Newton from the NLS seed)")
    ax.set_title("paper breather: dense against matrix-free Newton", fontsize=10)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=8, loc="upper left")
    fig.savefig(args.out, dpi=130)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
