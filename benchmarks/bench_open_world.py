"""Open-world validation of the loop diagnosis on fresh seeds (issue 11, point 5).

    PYTHONPATH=. nice -n 10 python benchmarks/bench_open_world.py [--seeds 61001,61002,61003] [--workers 2]

Runs :func:`afmsim.diagnosis.loops.open_world.validate_open_world` (34 cases per seed, spread over
the worker processes) and writes ``benchmarks/results/open_world.json``: the machine, the git
revision (the diagnosis that was scored), the headline,
the pooled and per-seed scores and every case; prints the headline and the Markdown tables of
docs/diagnosis.md ("Open-world validation"). Seeds 1–6 were the development seeds; the published
figures come from fresh seeds run once after the method was frozen (7001–7003, then 8001–8003, 9001–9003,
then 10001–10003, 11001–11003, 12001–12003, 13001–13003, 14001–14003, 15001–15003, 16001–16003, 17001–17003, 18001–18003, 19001–19003, 20001–20003, 21001–21003, 22001–22003, 23001–23003, 24001–24003, 25001–25003, 26001–26003, 27001–27003, 28001–28003, 29001–29003, 30001–30003, 31001–31003, 32001–32003, 33001–33003, 34001–34003, 35001–35003, 36001–36003, 37001–37003, 38001–38003, 39001–39003, 40001–40003, 41001–41003, 42001–42003, 43001–43003, 44001–44003, 45001–45003, 46001–46003, 47001–47003, 48001–48003, 49001–49003, 50001–50003, 51001–51003, 52001–52003, 53001–53003, 54001–54003, 55001–55003, 56001–56003, 57001–57003, 58001–58003, 59001–59003, 60001–60003, 61001–61003 and 62001–62003: see FRESH_SEEDS in open_world.py).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from afmsim.diagnosis.loops.open_world import FRESH_SEEDS, PLANTS, headline, proportion_text, validate_open_world
from afmsim.runio import git_revision, write_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import machine_info  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def tables(scores: dict) -> str:
    """The Markdown tables of the docs section, from the pooled scores."""
    lines = ["| score | value (k/n; 95 % Wilson interval) | target |", "|---|---|---|"]
    rows = [("effect cases: top-1", "effect_top1", "≥ 90 %"), ("effect cases: exact set", "effect_exact_set", ""),
            ("visible effect cases: top-1", "effect_top1_visible", ""),
            ("datasheet-magnitude effect cases: top-1", "effect_top1_datasheet", ""),
            ("null cases: false attribution", "null_false_attribution", "≤ 10 %"),
            ("null cases: plausible effect named (findings)", "null_false_findings", ""),
            ("null cases: status explained", "null_explained", ""),
            ("distractor cases: false attribution", "distractor_false_attribution", "≤ 10 %"),
            ("distractor cases: plausible effect named (findings)", "distractor_false_findings", ""),
            ("distractor cases: status explained", "distractor_explained", "0"),
            ("null cases within 2× noise", "nulls_within_2x", "all")]
    lines += [f"| {name} | {proportion_text(scores[key])} | {target} |" for name, key, target in rows]
    lines += ["", "| case type | nothing_missing | explained | partly_explained | unexplained |", "|---|---|---|---|---|"]
    for cat, counts in scores["status_counts"].items():
        lines.append(f"| {cat} | " + " | ".join(str(v) for v in counts.values()) + " |")
    lines += ["", "| null plant | cases | baseline gap/noise (median, max) | within 2× |", "|---|---|---|---|"]
    for plant in PLANTS:
        g = scores["null_gap_to_noise"].get(plant)
        if g:
            lines.append(f"| {plant} | {g['n']} | {g['median']:.1f}×, {g['max']:.1f}× | {g['within_2x']['k']}/{g['n']} |")
    lines += ["", "| effect | magnitude | scale | detected (named) | top-1 | visible to the oracle |",
              "|---|---|---|---|---|---|"]
    for effect, rows_ in scores["detection_vs_magnitude"].items():
        for label, r in rows_.items():
            lines.append(f"| {effect} | {label} | {r['scale']} | {proportion_text(r['detected'])} | "
                         f"{proportion_text(r['top1'])} | {r['visible']}/{r['detected']['n']} |")
    lines += ["", "| distractor | false attribution | status counts (nm/ex/partly/unex) | verdicts |",
              "|---|---|---|---|"]
    for name, d in scores["distractors"].items():
        verdicts = "; ".join(",".join(v) or "–" for v in d["verdicts"])
        lines.append(f"| {name} | {proportion_text(d['false_attribution'])} | "
                     f"{'/'.join(str(v) for v in d['status_counts'].values())} | {verdicts} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default=",".join(map(str, FRESH_SEEDS)))
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "open_world.json")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    done = lambda index, n_done, total: print(f"\r{n_done}/{total} cases", end="", flush=True)  # noqa: E731
    result = validate_open_world(seeds, workers=args.workers, on_done=done)
    print()
    head = headline(result)
    out = {"machine": machine_info(), "git": git_revision(), "headline": head, **result}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, out)
    print(json.dumps(head, indent=1, ensure_ascii=False))
    print(tables(result["scores"]))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
