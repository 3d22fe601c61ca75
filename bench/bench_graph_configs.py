"""CPU per process of `changing-slam graph` runs of this tree, alternating between config files (prints only).

    .venv/bin/python bench/bench_graph_configs.py BAG CONFIG [CONFIG ...] [--runs 2] [--lossless]
        [--work /tmp/bench_graph_configs] [--variant "LABEL: --graph-option value ..."]

`bench/bench_graph_cpu.py` compares two trees on one config; this compares configs on one tree, e.g. the
detector's thread count: copies of `config/sim.yaml` with a `detector:` section appended. Runs alternate
between the configs so that other load on a shared machine hits them alike. `--graph-arg=OPTION` (repeatable) is
passed to every `graph` run: for thread counts from the configs, `--graph-arg=--detector-threads --graph-arg=-1`
(in real time `graph` gives the detector one thread whatever the config says). Per config it prints the median
over runs of the detection rate, CPU per detection, tracking CPU per tracked frame, total CPU per bag frame,
poses, latency and ATE (`bench_graph_cpu.figures`).

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_graph_cpu import REPO, figures, run_graph  # noqa: E402

KEYS = (
    "detection Hz", "detection ms/detection", "tracking ms/tracked frame", "total ms/frame", "poses",
    "latency median ms", "ATE cm",
)  # fmt: skip


def main() -> None:
    """Parse the options, measure, print the table.

    `--variant "LABEL: OPTIONS"` (repeatable) compares sets of `graph` options instead, all on the first config, e.g.
    `--variant "fp32: --detector-model ssd_mobilenet_v2_coco" --variant "int8: " --variant "int8 15Hz: --detection-max-hz 15"`.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag")
    parser.add_argument("configs", nargs="+", help="config names or YAML paths")
    parser.add_argument("--runs", type=int, default=2, help="runs per config (alternating)")
    parser.add_argument("--lossless", action="store_true")
    parser.add_argument("--graph-arg", action="append", default=[], metavar="OPTION",
                        help="an option passed to every graph run (repeatable)")
    parser.add_argument("--work", default="", help="folder for the runs (default: a temp dir)")
    parser.add_argument("--variant", action="append", default=[], metavar="LABEL: OPTIONS",
                        help="graph options of one variant, all on the first config (repeatable)")
    a = parser.parse_args()
    runs = _runs(a)
    work = Path(a.work or tempfile.mkdtemp(prefix="bench_graph_configs_"))
    work.mkdir(parents=True, exist_ok=True)
    bag = str(Path(a.bag).resolve())
    results: dict[str, list[dict[str, float]]] = {label: [] for label, _, _ in runs}
    for i in range(a.runs):
        for k, (label, config, extra) in enumerate(runs):
            s = run_graph(REPO, bag, work / f"run_{k}_{i}", config, a.lossless, (*a.graph_arg, *extra))
            f = figures(s)
            f["detection Hz"] = float(s.get("detection_rate_hz") or float("nan"))
            results[label].append(f)
            print(f"{label} run {i + 1}: " + ", ".join(f"{n} {v:.1f}" for n, v in f.items()), flush=True)
    print(f"\nmedian over {a.runs} run(s), {bag}, {'lossless' if a.lossless else '1x'}:")
    print(f"{'':28s}" + "".join(f"{label:>20s}" for label in results))
    for key in KEYS:
        row = [statistics.median([r.get(key, float("nan")) for r in results[label]]) for label in results]
        print(f"{key:28s}" + "".join(f"{v:20.1f}" for v in row))
    for key in ("ATE cm", "poses"):  # per run too: a 1x run's ATE swings between identical runs
        cells = [" ".join(f"{r.get(key, float('nan')):.4g}" for r in results[label]) for label in results]
        print(f"{key + ' per run':28s}" + "".join(f" {c:>19s}" for c in cells))


def _runs(a: argparse.Namespace) -> list[tuple[str, str, tuple[str, ...]]]:
    """(label, config, extra graph options) per compared run kind: the configs, or the variants on the first."""
    if not a.variant:
        return [(Path(c).stem, c, ()) for c in a.configs]
    out = []
    for spec in a.variant:
        label, sep, options = spec.partition(":")
        if not sep or not label.strip():
            raise SystemExit(f"--variant {spec!r}: expected 'LABEL: OPTIONS', e.g. 'int8 15Hz: --detection-max-hz 15'")
        out.append((label.strip(), a.configs[0], tuple(options.split())))
    return out


if __name__ == "__main__":
    main()
