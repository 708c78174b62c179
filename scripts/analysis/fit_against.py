#!/usr/bin/env python3
"""The per-scene baseline's accuracy against its time, beside the feed-forward model's.

    python3 scripts/analysis/fit_against.py FIT.json EVAL.json [EVAL.json ...]

FIT.json is `inssplat-train fit-scene --score-at ... --json FIT.json`; each EVAL.json an
`inssplat eval --out` run on the same scenes (its reports at fit-scene's view count). For
every scene both cover, the fit's instance mIoU at each scored step count (a fit that
converged before a count keeps its final score there) and at its end; then, for each
evaluation, its mean instance mIoU and seconds a scene, the seconds fit-scene's mean curve
takes to reach that mean (linear between scored points), the ratio of the two, and the
scenes on which the fit already matches the feed-forward score at each step count.
"""
import json
import sys


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as f:
        fits = {r["scene"]: r for r in json.load(f)}
    views = {r["views"] for r in fits.values()}
    if len(views) != 1:
        sys.exit(f"{sys.argv[1]}: fits at several view counts {sorted(views)}")
    views = views.pop()
    steps = sorted({p["steps"] for r in fits.values() for p in r["curve"]} | set(next(iter(fits.values()))["score_at"]))

    def at(r, n):
        """(seconds, mIoU) of fit r after n steps: its point there, or its end if it stopped before."""
        for p in r["curve"]:
            if p["steps"] == n:
                return p["seconds"], p["instance_miou"]
        if r["steps"] <= n:
            return r["seconds"], r["instance_miou"]
        return None

    for path in sys.argv[2:]:
        with open(path) as f:
            report = json.load(f)
        ff = {s["scene"]: s for s in report["scenes"] if s["views"] == views and s.get("instance_miou") is not None}
        scenes = sorted(s for s in ff if s in fits and fits[s]["instance_miou"] is not None)
        if not scenes:
            sys.exit(f"{path}: no scene in common with {sys.argv[1]} at {views} views")
        n = len(scenes)
        ff_miou = sum(ff[s]["instance_miou"] for s in scenes) / n
        ff_s = sum(ff[s]["seconds"] for s in scenes) / n
        print(f"{path}: {n} scenes at {views} views, feed-forward instance mIoU {100 * ff_miou:.1f} in {ff_s:.3f} s a scene")
        print("| fit-scene steps | seconds (mean) | inst mIoU (mean) | scenes where the fit ≥ feed-forward |")
        print("|---|---|---|---|")
        curve = []
        for k in steps + ["end"]:
            pts = [at(fits[s], k) if k != "end" else (fits[s]["seconds"], fits[s]["instance_miou"]) for s in scenes]
            if any(p is None for p in pts):
                continue
            sec = sum(p[0] for p in pts) / n
            miou = sum(p[1] for p in pts) / n
            wins = sum(p[1] >= ff[s]["instance_miou"] for p, s in zip(pts, scenes))
            curve.append((sec, miou))
            print(f"| {k} | {sec:.1f} | {100 * miou:.1f} | {wins} of {n} |")
        reach = None
        prev = (0.0, 0.0)
        for sec, miou in curve:
            if miou >= ff_miou:
                t = prev[0] + (sec - prev[0]) * (ff_miou - prev[1]) / (miou - prev[1]) if miou > prev[1] else sec
                reach = t
                break
            prev = (sec, miou)
        if reach is None:
            print(f"fit-scene's mean curve never reaches {100 * ff_miou:.1f}\n")
        else:
            print(f"fit-scene's mean curve reaches {100 * ff_miou:.1f} after {reach:.2f} s: feed-forward is {reach / ff_s:.1f}x faster at equal instance mIoU "
                  f"({curve[-1][0] / ff_s:.0f}x against the converged fit's {curve[-1][0]:.1f} s)\n")


if __name__ == "__main__":
    main()
