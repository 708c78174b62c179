#!/usr/bin/env python3
"""The per-scene baseline's accuracy against its time, beside the feed-forward model's.

    python3 scripts/analysis/fit_against.py --fit FIT.json [--fit FIT.json ...] EVAL.json[=LABEL] ... [--chart OUT.png]

Each FIT.json is `inssplat-train fit-scene --score-at ... --json FIT.json`; several runs of
the same scenes (say, one stopped at 10 steps and scored at 1, 2 and 5, one run to
convergence) pool their scored points, since a fit repeats step for step. Each EVAL.json
is an `inssplat-eval score --out` run on the same scenes (its reports at fit-scene's view count).
Prints, for every evaluation, its mean instance mIoU and seconds a scene; fit-scene's means
at each scored step count (a fit that converged before a count keeps its final score there)
and at convergence, with the scenes on which the fit already matches the feed-forward score;
the seconds fit-scene's mean curve takes to reach the feed-forward mean (linear between
scored points, from zero at zero) and the ratio of the two. `--chart` draws fit-scene's mean
curve and each evaluation as a point (named LABEL, else by its path), instance mIoU against
seconds a scene on a log axis (needs matplotlib).
"""
import json
import sys


def take(args, flag):
    """Removes every `flag VALUE` pair from args and returns the values."""
    values = []
    while flag in args:
        i = args.index(flag)
        if i + 1 >= len(args):
            sys.exit(f"{flag} needs a file name")
        values.append(args[i + 1])
        del args[i:i + 2]
    return values


def load_fits(paths):
    """Per scene: its longest run's report, with every run's scored points pooled by step."""
    fits = {}
    for path in paths:
        with open(path) as f:
            for r in json.load(f):
                prior = fits.get(r["scene"])
                points = {p["steps"]: p for p in r["curve"]}
                if not r["converged"]:
                    # A run stopped at its cap: its end is a point of any longer run's curve.
                    points[r["steps"]] = r
                if prior is not None:
                    if prior["views"] != r["views"]:
                        sys.exit(f"{path}: {r['scene']} fitted at {r['views']} views, elsewhere at {prior['views']}")
                    points = {**prior["points"], **points}
                    if prior["steps"] > r["steps"]:
                        r = prior
                fits[r["scene"]] = {**r, "points": points}
    return fits


def at(r, n):
    """(seconds, mIoU) of fit r after n steps: its point there, or its end if it converged before."""
    if n in r["points"]:
        return r["points"][n]["seconds"], r["points"][n]["instance_miou"]
    if r["converged"] and r["steps"] <= n:
        return r["seconds"], r["instance_miou"]
    return None


def main():
    args = sys.argv[1:]
    fit_paths = take(args, "--fit")
    charts = take(args, "--chart")
    if not fit_paths or not args:
        sys.exit(__doc__)
    fits = load_fits(fit_paths)
    views = {r["views"] for r in fits.values()}
    if len(views) != 1:
        sys.exit(f"fits at several view counts {sorted(views)}")
    views = views.pop()
    steps = sorted({n for r in fits.values() for n in r["points"]})
    drawn = []
    for arg in args:
        path, _, label = arg.partition("=")
        with open(path) as f:
            report = json.load(f)
        ff = {s["scene"]: s for s in report["scenes"] if s["views"] == views and s.get("instance_miou") is not None}
        scenes = sorted(s for s in ff if s in fits and fits[s]["instance_miou"] is not None)
        if not scenes:
            sys.exit(f"{path}: no scene in common with the fits at {views} views")
        n = len(scenes)
        ff_miou = sum(ff[s]["instance_miou"] for s in scenes) / n
        ff_s = sum(ff[s]["seconds"] for s in scenes) / n
        print(f"{path}: {n} scenes at {views} views, feed-forward instance mIoU {100 * ff_miou:.1f} in {ff_s:.3f} s a scene (mean)")
        print("| fit-scene steps | seconds (mean) | inst mIoU (mean) | scenes where the fit ≥ feed-forward |")
        print("|---|---|---|---|")
        curve = []
        for k in steps + ["converged"]:
            pts = [at(fits[s], k) if k != "converged" else (fits[s]["seconds"], fits[s]["instance_miou"]) for s in scenes]
            if any(p is None for p in pts):
                continue
            sec = sum(p[0] for p in pts) / n
            miou = sum(p[1] for p in pts) / n
            wins = sum(p[1] >= ff[s]["instance_miou"] for p, s in zip(pts, scenes))
            curve.append((sec, miou))
            print(f"| {k} | {sec:.2f} | {100 * miou:.1f} | {wins} of {n} |")
        drawn.append((label or path, ff_s, ff_miou, curve))
        reach, prev = None, (0.0, 0.0)
        for sec, miou in curve:
            if miou >= ff_miou:
                reach = prev[0] + (sec - prev[0]) * (ff_miou - prev[1]) / (miou - prev[1]) if miou > prev[1] else sec
                break
            prev = (sec, miou)
        if reach is None:
            print(f"fit-scene's mean curve never reaches {100 * ff_miou:.1f}\n")
        else:
            print(f"fit-scene's mean curve reaches {100 * ff_miou:.1f} after {reach:.2f} s: feed-forward is {reach / ff_s:.2f}x as fast at equal instance mIoU "
                  f"({curve[-1][0] / ff_s:.0f}x against the converged fit's {curve[-1][0]:.1f} s)\n")
    for out in charts:
        draw(out, drawn)


def draw(out, drawn):
    """fit-scene's mean curve (over the first evaluation's scenes) and each evaluation's point."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    curve = drawn[0][3]
    ax.plot([c[0] for c in curve], [100 * c[1] for c in curve], "o-", color="tab:blue", label="fit-scene (true cameras, depth and masks), after 1, 2, 5, ... steps and converged")
    for (label, sec, miou, _), colour in zip(drawn, ["tab:red", "tab:orange", "tab:green", "tab:purple"]):
        ax.plot([sec], [100 * miou], "s", color=colour, markersize=8, label=label)
        ax.axhline(100 * miou, color=colour, linewidth=0.6, linestyle=":")
    ax.set_xscale("log")
    ax.set_xlabel("seconds a scene")
    ax.set_ylabel("instance mIoU of the target views")
    ax.grid(True, which="both", linewidth=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out)
    print(f"chart: {out}")


if __name__ == "__main__":
    main()
