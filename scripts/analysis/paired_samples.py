#!/usr/bin/env python3
"""Paired per-sample differences between checkpoints scored on the same samples by
`inssplat-train validate --csv F` (with `--depth-abs-rel` for the depth's AbsRel).

    python3 scripts/analysis/paired_samples.py F.csv BASE NEW [column ...]

BASE and NEW are substrings of the checkpoint column. For each column (default: abs_rel,
geometry, instance, semantic, total) prints both means and the mean of NEW − BASE with its
standard error over the samples both scored.
"""
import csv
import math
import sys

DEFAULT = ["abs_rel", "geometry", "instance", "semantic", "total"]


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    rows = list(csv.DictReader(open(sys.argv[1])))
    checkpoints = list(dict.fromkeys(r["checkpoint"] for r in rows))

    def pick(part):
        found = [c for c in checkpoints if part in c]
        if len(found) != 1:
            sys.exit(f"{len(found)} checkpoints match {part!r} among {checkpoints}")
        return found[0]

    base, new = pick(sys.argv[2]), pick(sys.argv[3])
    print(f"NEW − BASE, mean ± s.e. over the samples; base {base}, new {new}")
    for column in sys.argv[4:] or DEFAULT:
        score = lambda c: {r["sample"]: float(r[column]) for r in rows if r["checkpoint"] == c and r.get(column)}
        a, b = score(base), score(new)
        both = sorted(set(a) & set(b), key=int)
        if len(both) < 2:
            print(f"{column}: fewer than two samples scored by both")
            continue
        d = [b[s] - a[s] for s in both]
        mean = sum(d) / len(d)
        se = math.sqrt(sum((x - mean) ** 2 for x in d) / (len(d) - 1) / len(d))
        mean_a, mean_b = (sum(x[s] for s in both) / len(both) for x in (a, b))
        print(f"{column}: {len(both)} samples, base {mean_a:.4f}, new {mean_b:.4f}, new − base {mean:+.4f} ± {se:.4f}")


if __name__ == "__main__":
    main()
