#!/usr/bin/env python3
"""Paired comparison of one method across two benchmark runs on the same runs.

    python3 docs/experiments/paired.py out/a/results.csv out/b/results.csv [--method human2nav]

Pairs rows on (suite, scenario, episode, robot, seed) and prints, per suite and robot: the
success rates with the runs only one side solved and the exact McNemar p, and for the minimum
clearance, the time within 0.45 m of a pedestrian, the mean jerk and the time to the goal (runs both
sides solved) the medians (the mean for the time within 0.45 m) of both sides with the exact sign test p of their paired differences. Standard library
only.
"""
import argparse
import csv
import math
import statistics
from collections import defaultdict

KEY = ("suite", "scenario", "episode", "robot", "seed")


def load(path, method):
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["method"] == method]
    return {tuple(r[k] for k in KEY): r for r in rows}


def binom_two_sided(k, n):
    """Exact two-sided binomial test of k successes in n at p = 1/2."""
    if n == 0:
        return 1.0
    k = min(k, n - k)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2 * tail)


def number(v):
    return float(v) if v not in ("", None) else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--method", default="human2nav")
    args = ap.parse_args()
    a, b = load(args.a, args.method), load(args.b, args.method)
    common = sorted(set(a) & set(b))
    groups = defaultdict(list)
    for k in common:
        groups[(k[0], k[3])].append(k)
    print(f"{len(common)} paired runs ({len(a)} in a, {len(b)} in b)\n")
    print("| suite | robot | n | SR a | SR b | only a | only b | McNemar p "
          "| min clearance a / b (median, m) | p | time < 0.45 m a / b (mean, s) | p "
          "| jerk a / b (median) | p | time to goal a / b (median, both succeeded, s) | p |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    groups[("all", "all")] = common
    for (suite, robot), keys in sorted(groups.items(), key=lambda g: g[0] == ("all", "all")):
        n = len(keys)
        sa = [int(a[k]["success"]) for k in keys]
        sb = [int(b[k]["success"]) for k in keys]
        only_a = sum(1 for x, y in zip(sa, sb) if x and not y)
        only_b = sum(1 for x, y in zip(sa, sb) if y and not x)
        cells = [suite, robot, str(n), f"{100 * sum(sa) / n:.1f}", f"{100 * sum(sb) / n:.1f}",
                 str(only_a), str(only_b), f"{binom_two_sided(only_a, only_a + only_b):.3g}"]
        for col, agg in (("min_clearance", statistics.median),
                         ("time_within_0_45", statistics.fmean),
                         ("mean_jerk", statistics.median),
                         ("time_to_goal", statistics.median)):
            both = [k for k in keys if col != "time_to_goal"
                    or (a[k]["success"] == "1" and b[k]["success"] == "1")]
            pairs = [(number(a[k][col]), number(b[k][col])) for k in both]
            pairs = [(x, y) for x, y in pairs if x is not None and y is not None]
            if not pairs:
                cells += ["–", "–"]
                continue
            up = sum(1 for x, y in pairs if y > x)
            down = sum(1 for x, y in pairs if y < x)
            cells.append(f"{agg([x for x, _ in pairs]):.3f} / {agg([y for _, y in pairs]):.3f}")
            cells.append(f"{binom_two_sided(up, up + down):.3g} ({down}↓ {up}↑)")
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
