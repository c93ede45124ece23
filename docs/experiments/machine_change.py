"""Do a stress experiment's verdicts survive a change of machine? Its report re-made with every run moved.

No training: the experiment's own runs, read as `liquidgs experiment report` reads them. A change of
machine sends each run's training elsewhere (float rounding), which moves the run's test PSNR; a
cluster counts by its mean difference, so what matters is how far each run's mean PSNR moves. Here
every run (each CfC run once, shared by the sde variants it is compared with, and the clean runs once,
shared by every perturbation) is moved by its own N(0, s^2) shift, the verdicts are taken again by the
report's rule (significance.call with the report's floor, held fixed), and the share of draws whose
verdicts all equal the measured ones is printed, with each comparison's flip rate. Shifts s:
- 0.05 and 0.1 dB: what issue 22's AVX-512 machine moved stress-mini's runs by (its 4-cluster mean
  differences moved 0.03-0.13 dB; a mean of 4 cluster differences, each the difference of two runs
  moved by s, moves by s / sqrt(2), so s is about 0.04-0.18 dB, 0.1 dB for a typical 0.07);
- sigma, the CfC's seed-to-seed spread the report measures: every run re-drawn as a new seed would be,
  the worst case the README's simulation (verdict_stability.py) assumes;
- 2 sigma: pessimistic.

    .venv/bin/python docs/experiments/machine_change.py outputs/experiments/stress-24     # about 10 s
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from liquidgs.experiments.report.collect import collect
from liquidgs.experiments.report.significance import cluster_difference
from liquidgs.experiments.report.stress import BASELINE, paired_clusters, perturbations, tie_floor


def comparisons(directory: Path):
    """(floor, its source, {(variant, strength text): {run key of the CfC and sde runs: mean difference}})."""
    collection = collect(directory)
    floor, source = tie_floor(collection)
    table: dict[tuple[str, str], dict[tuple, float]] = {}
    for perturb in perturbations(collection):
        for (variant, strength), clusters in paired_clusters(collection, perturb).items():
            cell = "clean" if strength == 0 else f"{perturb} {strength:g}"
            # A cluster's two runs by name: the same CfC run serves every variant of its cell.
            table[(variant, cell)] = {
                ((BASELINE, cell, *cluster), (variant, cell, *cluster)): float(d.mean())
                for cluster, d in clusters.items()
            }
    return floor, source, table


def verdicts(table, floor: float, shifts: dict | None = None) -> list[str]:
    out = []
    for clusters in table.values():
        means = [m + (shifts[b] - shifts[a] if shifts else 0.0) for (a, b), m in clusters.items()]
        out.append(cluster_difference(means, floor).verdict)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment", type=Path)
    parser.add_argument("--draws", type=int, default=2000)
    args = parser.parse_args()
    floor, source, table = comparisons(args.experiment)
    measured = verdicts(table, floor)
    runs = sorted({run for clusters in table.values() for pair in clusters for run in pair})
    clusters = sorted({len(c) for c in table.values()})
    print(f"{Path(args.experiment).name}: {len(table)} distinct comparisons on "
          f"{' / '.join(map(str, clusters))} clusters, {len(runs)} runs; floor {floor:.3f} dB ({source})")  # fmt: skip
    sigma = floor / 2
    sizes = {"0.05 dB": 0.05, "0.1 dB": 0.1, f"sigma {sigma:.3f}": sigma, f"2 sigma {2 * sigma:.3f}": 2 * sigma}
    rng = np.random.default_rng(0)
    flips, agree = {}, {}
    for label, s in sizes.items():
        flips[label], agree[label] = np.zeros(len(table)), 0
        for _ in range(args.draws):
            shifts = dict(zip(runs, s * rng.standard_normal(len(runs))))
            changed = np.array([a != b for a, b in zip(verdicts(table, floor, shifts), measured)])
            flips[label] += changed / args.draws
            agree[label] += (not changed.any()) / args.draws
    print(f"\nshare of {args.draws} draws whose verdict differs from the measured one, every run moved by N(0, s^2):")
    print("comparison (measured verdict)".ljust(44) + "".join(f"{label:>16}" for label in sizes))
    for k, ((variant, cell), verdict) in enumerate(zip(table, measured)):
        print(f"{variant} at {cell} ({verdict})".ljust(44) + "".join(f"{flips[label][k]:>16.3f}" for label in sizes))
    print("all verdicts as measured".ljust(44) + "".join(f"{agree[label]:>16.3f}" for label in sizes))

if __name__ == "__main__":
    main()
