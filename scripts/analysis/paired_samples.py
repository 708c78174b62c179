#!/usr/bin/env python3
"""Paired per-sample differences of the depth AbsRel that `inssplat-train validate --matching
--depth-csv F` writes, between checkpoints scored on the same samples.

    python3 scripts/analysis/paired_samples.py F.csv [BASE NEW]

BASE and NEW are substrings of the checkpoint column (default: the first two checkpoints in the
file). Prints both means and the mean of NEW − BASE with its standard error over the samples
both scored.
"""
import csv
import math
import sys


def main():
    if len(sys.argv) not in (2, 4):
        sys.exit(__doc__)
    rows = list(csv.DictReader(open(sys.argv[1])))
    checkpoints = list(dict.fromkeys(r["checkpoint"] for r in rows))
    if len(sys.argv) == 4:
        pick = lambda part: next((c for c in checkpoints if part in c), None) or sys.exit(f"no checkpoint matches {part}")
        base, new = pick(sys.argv[2]), pick(sys.argv[3])
    elif len(checkpoints) >= 2:
        base, new = checkpoints[:2]
    else:
        sys.exit("the file scores fewer than two checkpoints")
    score = lambda c: {r["sample"]: float(r["abs_rel"]) for r in rows if r["checkpoint"] == c and r["abs_rel"]}
    a, b = score(base), score(new)
    both = sorted(set(a) & set(b), key=int)
    if len(both) < 2:
        sys.exit("fewer than two samples scored by both")
    d = [b[s] - a[s] for s in both]
    mean = sum(d) / len(d)
    se = math.sqrt(sum((x - mean) ** 2 for x in d) / (len(d) - 1) / len(d))
    print(f"{len(both)} samples; depth AbsRel base {sum(a[s] for s in both) / len(both):.4f} ({base}), "
          f"new {sum(b[s] for s in both) / len(both):.4f} ({new}); new − base {mean:+.4f} ± {se:.4f}")


if __name__ == "__main__":
    main()
