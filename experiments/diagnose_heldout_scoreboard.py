"""Every seed set scored so far, side by side, and its misses by kind and by how they missed
(where the 15/16 goal stands and why).

Reads the stored JSON of `diagnose_heldout_hard.py` runs (no diagnosis is run). A *fresh* set
was scored once, with the code of its day; sets 14-19 and 21 then fed constants or rules of the
diagnosis (`diagnose_heldout_hard.DEVELOPMENT_SETS`): they are development sets, their rows
development scores, not held-out ones, and a sum over sets adds different code versions; later code changed
some answers, so a row is that day's score, not today's (set 24 rerun with the fits spread over
threads, committed in 344910e, gave the same 19/19: `diagnose_heldout_same_fresh24_mz9_vs_s42shares_set24.md`). A miss is

- `quiet`: nothing named (no candidate passed both tests at the 1 % family-wise level);
- `tie`: another mechanism named first, the truth among its rivals (reported uncertain);
- `wrong`: another mechanism named and the truth not among its rivals.

    .venv/bin/python experiments/diagnose_heldout_hard.py --seed-set S --out DIR_S   # each set
    .venv/bin/python experiments/diagnose_heldout_scoreboard.py DIR_14/diagnose_heldout_hard.json ...

Writes `experiments/results/diagnose_heldout_scoreboard.md` and `.json`; a set is labelled by its
JSON's seed set.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_heldout_hard import DEVELOPMENT_SETS

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"


def miss_kind(rec: dict) -> str:
    """How a mechanism case was missed: `quiet`, `tie` or `wrong` (module docstring)."""
    if not rec["named"]:
        return "quiet"
    return "tie" if set(rec["counted"]) & set(rec["rivals"]) else "wrong"


def score(paths) -> dict:
    """Per set: top-1, nulls quiet, confident wrong names; per kind: cases, hits and misses."""
    sets, kinds, misses = [], collections.defaultdict(collections.Counter), []
    for path in paths:
        d = json.loads(Path(path).read_text())
        tag = f"set {d['records'][0]['seed_set']}" if d["records"] else Path(path).stem
        s = d["summary"]
        sets.append({"tag": tag, "top1": s["top1"], "nulls_quiet": s["nulls_quiet"],
                     "confident_wrong": s["confident_wrong"],
                     "truth_among_top_or_rivals": s["truth_among_top_or_rivals"],
                     "median_gain": s["median_gain"], "commit": (d.get("meta") or {}).get("commit")})
        for r in d["records"]:
            if r["kind"] == "null":
                continue
            k = kinds[r["kind"]]
            k["cases"] += 1
            if r["correct"]:
                k["hits"] += 1
                continue
            how = miss_kind(r)
            k[how] += 1
            misses.append({"tag": tag, "case": r["case"], "kind": r["kind"], "zones": r["zones"],
                           "ts": r["ts"], "how": how, "named": r["top"], "rivals": r["rivals"],
                           "confidence": r["confidence"]})
    return {"sets": sets, "kinds": {k: dict(v) for k, v in sorted(kinds.items())}, "misses": misses}


def total_line(res: dict) -> str:
    """The sets' top-1 summed, against the goal."""
    hits = sum(s["top1"][0] for s in res["sets"])
    total = sum(s["top1"][1] for s in res["sets"])
    return f"top-1 over the sets {hits}/{total} ({100 * hits / max(total, 1):.0f} %); the goal is 15/16 (94 %)."


def seed_set(tag: str) -> int | None:
    """The seed set a row's tag names (`set 14`, `fresh14_mz9`), or None."""
    m = re.search(r"(\d+)", tag)
    return int(m.group(1)) if m else None


def set_role(tag: str) -> str:
    """`development` where the set fed a constant or rule (`DEVELOPMENT_SETS`), else `scored once`."""
    return "development" if seed_set(tag) in DEVELOPMENT_SETS else "scored once"


def render(res: dict, argv: str) -> str:
    dev = [s for s in res["sets"] if set_role(s["tag"]) == "development"]
    once = [s for s in res["sets"] if set_role(s["tag"]) != "development"]
    out = ["# Seed sets scored so far: development sets and sets scored once, kept apart", "",
           f"Made by `python experiments/diagnose_heldout_scoreboard.py{argv}` from the stored JSON of "
           "`diagnose_heldout_hard.py` (each set scored once, with the code of its day, not one code; see the "
           "script's docstring). A development set fed a constant or rule of the diagnosis "
           f"(`DEVELOPMENT_SETS`: {', '.join(map(str, DEVELOPMENT_SETS[1:]))}): its row is a development score. "
           "The commit of a set is named where its JSON recorded one. Goal: top-1 >= 15/16 per set, nulls 3/3. "
           "The loop's set (`diagnose_fresh_loop.md`, seed tag 1) was scored once at its commit; its cases "
           "03, 05 and 08 then fed rules of the diagnosis (the pooled records' drift test, the ties of forward "
           "selection: `diagnose_fresh_case.py`), so it is a development set since, and a score of today's code "
           "needs new seeds (`--seed-tag`).", "",
           "Development sets: " + total_line({"sets": dev}),
           "Sets scored once (each at the code of its day) and not tuned on: " + total_line({"sets": once}), "",
           "| set | role | commit | top-1 | nulls quiet | truth first or a rival | confident wrong names | median gain pts |",
           "|---|---|---|---|---|---|---|---|"]
    for s in res["sets"]:
        name = s["tag"] if seed_set(s["tag"]) is None else f"set {seed_set(s['tag'])}"
        out.append(f"| {name} | {set_role(s['tag'])} | {s.get('commit') or 'not recorded'} | "
                   f"{s['top1'][0]}/{s['top1'][1]} | {s['nulls_quiet'][0]}/{s['nulls_quiet'][1]} | "
                   f"{s['truth_among_top_or_rivals'][0]}/{s['truth_among_top_or_rivals'][1]} | "
                   f"{s['confident_wrong']} | {s['median_gain']:.2f} |")
    out += ["", "By kind (misses: quiet = nothing named, tie = truth among the named one's rivals, "
            "wrong = truth not among them):", "",
            "| kind | cases | right | quiet | tie | wrong |", "|---|---|---|---|---|---|"]
    for k, v in res["kinds"].items():
        out.append(f"| {k} | {v.get('cases', 0)} | {v.get('hits', 0)} | {v.get('quiet', 0)} | "
                   f"{v.get('tie', 0)} | {v.get('wrong', 0)} |")
    out += ["", "| set | case | N | Ts s | miss | named | rivals | confidence |", "|---|---|---|---|---|---|---|---|"]
    for m in res["misses"]:
        conf = "" if m["confidence"] is None else f"{m['confidence']:.3f}"
        out.append(f"| {m['tag']} | {m['case']} | {m['zones']} | {m['ts']:.2f} | {m['how']} | {m['named'] or '-'} | "
                   f"{', '.join(m['rivals']) or '-'} | {conf} |")
    return "\n".join(out) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="*", help="JSON files written by diagnose_heldout_hard.py")
    ap.add_argument("--render", action="store_true",
                    help="only render the stored scoreboard JSON again (no JSON of the sets needed)")
    args = ap.parse_args(argv)
    if args.render:
        res = json.loads((RESULTS / "diagnose_heldout_scoreboard.json").read_text())
        (RESULTS / "diagnose_heldout_scoreboard.md").write_text(render(res, " --render"))
        return
    if not args.results:
        ap.error("give the JSON files of the sets, or --render")
    res = score(args.results)
    (RESULTS / "diagnose_heldout_scoreboard.json").write_text(json.dumps(res, indent=1))
    (RESULTS / "diagnose_heldout_scoreboard.md").write_text(render(res, " " + " ".join(args.results)))
    print(total_line(res))


if __name__ == "__main__":
    main()
