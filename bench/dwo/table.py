#!/usr/bin/env python3
"""Tables of the Monte Carlo trials of `dwslam experiment dwo` (σ = 1 px).

Stereo spiral (500 keyframes): per seed, cDWO's inner-window and gDWO's global RMSE (means
over the run) against full BA's, with the coarse (eq. 6.2) and the marginal constraint
information, cDWO's time ratio, and the ratio of the means over all seeds.

Double loop (monocular, 2 × 150 keyframes): per seed and method, the all-pairs RMSE of the
first loop just before the closure and at the end, its improvement, and the ratio of the
means over all seeds.

    bench/dwo/table.py PATH [PATH ...]

PATH: summary.json files of `dwslam experiment dwo`, or directories searched for *.json.
BA comes from whichever file has it; for a seed and method the first file found wins."""
import json
import pathlib
import statistics
import sys


def summaries(paths, kind):
    for p in map(pathlib.Path, paths):
        for f in sorted(p.rglob("*.json")) if p.is_dir() else [p]:
            try:
                d = json.loads(f.read_text())
            except (OSError, ValueError):
                continue
            if (d.get("scenario"), d.get("sensor"), d.get("keyframes"), d.get("noise_px", 1.0)) == (
                    *kind, 1.0):
                yield f, d


def double_loop(paths):
    seeds = {}
    for f, d in summaries(paths, ("double-loop", "mono", 300)):
        info = (d.get("constraint_information") or "Coarse").lower()
        s = seeds.setdefault(d["seed"], {})
        for name, m in d["methods"].items():
            if "loop_closure" in m and name in ("BA", "cDWO", "gDWO"):
                s.setdefault(name if name == "BA" else f"{name} {info}", m["loop_closure"])
    if not seeds:
        return
    names = sorted({k for s in seeds.values() for k in s}, key=lambda k: (k != "BA", k))
    print("| seed | " + " | ".join(f"{n}: before → end (×)" for n in names)
          + " | local scale spread before |")
    print("|---" * (len(names) + 2) + "|")
    for seed in sorted(seeds):
        s, cells = seeds[seed], []
        for n in names:
            c = s.get(n)
            cells.append(f"{c['rmse_all_pairs_before']:.2e} → {c['rmse_all_pairs_first_loop_at_end']:.2e}"
                         f" ({c['improvement_first_loop']:.2f})" if c else "–")
        spread = next(iter(s.values()))["local_scale_spread_before"]
        print(f"| {seed} | " + " | ".join(cells) + f" | {spread:.3f} |")
    print()
    for n in names:
        cs = [s[n] for s in seeds.values() if n in s]
        before = statistics.mean(c["rmse_all_pairs_before"] for c in cs)
        after = statistics.mean(c["rmse_all_pairs_first_loop_at_end"] for c in cs)
        per = [c["improvement_first_loop"] for c in cs]
        print(f"{n}: mean before {before:.3e} / mean at the end {after:.3e} = {before / after:.2f}× "
              f"({len(cs)} seeds; per seed {min(per):.2f}–{max(per):.2f}×)")
    print()


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    double_loop(sys.argv[1:])
    seeds = {}
    for f, d in summaries(sys.argv[1:], ("spiral", "stereo", 500)):
        info = (d.get("constraint_information") or "Coarse").lower()
        s = seeds.setdefault(d["seed"], {})
        for name, m in d["methods"].items():
            key = "BA" if name == "BA" else f"{name} {info}"
            s.setdefault(key, m)  # the first file found wins
    if not seeds:
        return
    rows, cols = [], [("cDWO", "mean_rmse_inner"), ("gDWO", "mean_rmse_global")]
    print("| seed | BA inner | BA global | BA time ratio "
          + "".join(f"| {m} {c.split('_')[-1]} / BA, coarse → marginal " for m, c in cols)
          + "| cDWO time ratio, marginal |")
    print("|---" * 7 + "|")
    for seed in sorted(seeds):
        s = seeds[seed]
        ba = s.get("BA")
        if ba is None:
            print(f"| {seed} | no BA run |")
            continue
        cells = [f"{ba['mean_rmse_inner']:.3e}", f"{ba['mean_rmse_global']:.3e}",
                 f"{ba['time_ratio_400_500_over_100_200']:.2f}"]
        row = {"BA": ba}
        for m, c in cols:
            r = []
            for info in ("coarse", "marginal"):
                x = s.get(f"{m} {info}")
                row[f"{m} {info}"] = x
                r.append(f"{x[c] / ba[c]:.3f}" if x else "–")
            cells.append(" → ".join(r))
        cm = s.get("cDWO marginal")
        cells.append(f"{cm['time_ratio_400_500_over_100_200']:.2f}" if cm else "–")
        rows.append(row)
        print(f"| {seed} | " + " | ".join(cells) + " |")

    def mean_ratio(key, c):
        xs = [(r[key][c], r["BA"][c]) for r in rows if r.get(key)]
        if not xs:
            return "–"
        return f"{statistics.mean(a for a, _ in xs) / statistics.mean(b for _, b in xs):.3f} ({len(xs)} seeds)"

    print()
    for m, c in cols:
        for info in ("coarse", "marginal"):
            print(f"{m} {info}: mean {c} / BA's = {mean_ratio(f'{m} {info}', c)}")
    ratios = [r["cDWO marginal"]["time_ratio_400_500_over_100_200"] for r in rows if r.get("cDWO marginal")]
    if ratios:
        print(f"cDWO marginal time ratio 400–500 / 100–200: {min(ratios):.2f}–{max(ratios):.2f}")


if __name__ == "__main__":
    main()
