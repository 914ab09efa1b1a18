"""Model size against the number of training instances, with and without pruning (Fig. 4).

Trains one category model on EPFL cars 1..N (the EPFL protocols' settings;
the Eq. 4 weights are per instance, so the model of the first n cars is
the n-car subset of it), then prunes the first n cars' model with each
preset and records the features kept, the clustering time and its peak
memory (tracemalloc, which sees NumPy's allocations), and the process's
peak resident memory.

Usage::

    python benchmarks/pruning.py [--data ../shared/data] [--cars 1-10]
        [--max-train-features 150] [--markdown docs/results/pruning.md]
        [--plot docs/results/pruning_fig4.png]
"""

from __future__ import annotations

import argparse
import json
import resource
import shlex
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from posevote import PoseEstimator
from posevote.data import read_epfl
from posevote.model.kernels import ORIENTATION_KAPPA
from posevote.model.pruning import PRESETS, prune_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--cars", default="1-10")
    parser.add_argument("--max-train-features", type=int,
                        default=PoseEstimator.from_preset("category").edges.max_train_features)
    parser.add_argument("--markdown", type=Path)
    parser.add_argument("--plot", type=Path)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    lo, hi = (int(x) for x in args.cars.split("-"))
    cars = list(range(lo, hi + 1))
    folder = Path(args.data) / "epfl-gims08" / "tripod-seq"
    ts = read_epfl(folder, cars=cars)
    # The category preset's training, with the 3-pixel kernel this study chose
    # the pruning presets at (docs/results/pruning.md).
    est = PoseEstimator.from_preset("category", appearance=None, kernel__position_sigma=3.0,
                                    edges__max_train_features=args.max_train_features)
    start = time.perf_counter()
    est.fit(ts.images, ts.poses, boxes=ts.boxes, instances=list(ts.instances), category="car")
    train_s = time.perf_counter() - start
    full = est.full_model_
    rows = []
    for n in range(1, len(cars) + 1):
        sub = full.select_instances(list(range(n)))
        row = {"instances": n, "features": sub.n_features}
        for name, preset in PRESETS.items():
            tracemalloc.start()
            t0 = time.perf_counter()
            pruned = prune_model(sub, preset, position_sigma=est.kernel.position_sigma,
                                 orientation_kappa=ORIENTATION_KAPPA)
            row[f"{name}_seconds"] = time.perf_counter() - t0
            row[f"{name}_peak_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            row[name] = pruned.n_features
            row[f"{name}_percent"] = 100.0 * pruned.n_features / max(sub.n_features, 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result = {"command": "python " + " ".join(shlex.quote(a) for a in sys.argv),
              "cars": cars, "params": repr(est), "train_seconds": train_s,
              "peak_rss_mb": peak_rss, "presets": {k: vars(v) for k, v in PRESETS.items()},
              "rows": rows}
    lines = [f"Command: `{result['command']}`", "",
             f"EPFL cars {cars[0]}-{cars[-1]}, {args.max_train_features} features per training "
             f"view; training (features, Eq. 4 weights, verification descriptors) {train_s:.1f} s; "
             f"peak resident memory "
             f"of the whole process {peak_rss:.0f} MB.", "",
             "Presets (maximum within-cluster standard deviation): " + "; ".join(
                 f"{k}: {v.pose_std_deg:g}° in viewpoint, {v.appearance_std:g} kernel widths in "
                 "appearance" for k, v in PRESETS.items()), "",
             "| cars | features | moderate | kept % | s | peak MB | aggressive | kept % | s "
             "| peak MB |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['instances']} | {r['features']} | {r['moderate']} "
                     f"| {r['moderate_percent']:.1f} | {r['moderate_seconds']:.1f} "
                     f"| {r['moderate_peak_mb']:.0f} | {r['aggressive']} "
                     f"| {r['aggressive_percent']:.1f} | {r['aggressive_seconds']:.1f} "
                     f"| {r['aggressive_peak_mb']:.0f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(text)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        n = [r["instances"] for r in rows]
        fig, ax = plt.subplots(figsize=(5, 3.4))
        ax.plot(n, [r["features"] for r in rows], "o-", color="0.6", label="no pruning")
        ax.plot(n, [r["moderate"] for r in rows], "s-", color="0.3", label="moderate pruning")
        ax.plot(n, [r["aggressive"] for r in rows], "^-", color="0.0", label="aggressive pruning")
        ax.set_xlabel("training instances (EPFL cars)")
        ax.set_ylabel("features in the model")
        ax.set_xticks(n)
        ax.legend(fontsize=8)
        ax.set_title("Model size vs. number of instances (Fig. 4)", fontsize=9)
        fig.savefig(args.plot, dpi=100, bbox_inches="tight")
    growth = np.diff([r["moderate"] for r in rows])
    if len(growth) > 1:
        print(f"moderate: features added per extra car, first {growth[0]}, last {growth[-1]}")


if __name__ == "__main__":
    main()
