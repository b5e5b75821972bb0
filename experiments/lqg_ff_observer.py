"""What the LQG's observer should see of a schedule feed-forward. Held-out costs of
the untuned `lqg_ff` start (LQG design + feed-forward taps from `tune.ff_init`) with the
observer fed the feedback's part of the input (`ScheduleFF`, now) against the whole applied
input (before), with the LQG and the `pi_ff` start beside them, on the PA12 printer (design)
and PA11 (unseen), the held-out seed of `tune_report`.

    .venv/bin/python experiments/lqg_ff_observer.py [--rollouts 4] [--duration 300]

Writes experiments/results/lqg_ff_observer.md (and .json).
"""

import argparse
import json
import os
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx

from jthermo.closedloop import REALISTIC_EFFECTS
from jthermo.control import ScheduleFF, design
from jthermo.printer import make_printer
from jthermo.tune import HELD_OUT, printer_model
from jthermo.tune.ff_init import init_schedule_ff
from jthermo.tune.report import held_out_terms

OUT = Path("experiments/results/lqg_ff_observer.md")


class WholeInputObserver(ScheduleFF):
    """`lqg_ff` as it was: the observer also predicts the feed-forward's heating."""

    def step_schedule(self, state, y, r, schedule):
        u, st = ScheduleFF.step_schedule(self, state, y, r, schedule)
        back = jax.lax.stop_gradient(self.feedback.B) @ self.feedforward(st.events)
        return u, eqx.tree_at(lambda s: s.feedback.x, st, st.feedback.x + back)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rollouts", type=int, default=4)
    ap.add_argument("--duration", type=float, default=300.0)
    args = ap.parse_args(argv)
    t0, c0 = time.perf_counter(), time.process_time()
    pa12 = make_printer(4, REALISTIC_EFFECTS, powder="PA12", seed=0)
    pa11 = make_printer(4, REALISTIC_EFFECTS, powder="PA11", seed=0)
    model = printer_model(pa12)
    now = init_schedule_ff(design("lqg_ff", model), pa12)
    before = WholeInputObserver(feedback=now.feedback, h_recoat=now.h_recoat,
                                h_laser=now.h_laser)
    ctrls = {"lqg": design("lqg", model), "lqg_ff, observer sees the whole input (before)": before,
             "lqg_ff, observer sees the feedback's part (now)": now,
             "pi_ff start": init_schedule_ff(design("pi_ff", model), pa12)}
    res = held_out_terms(ctrls, {"PA12": pa12, "PA11": pa11}, (HELD_OUT,),
                         rollouts=args.rollouts, duration=args.duration)
    wall, cpu, load = time.perf_counter() - t0, time.process_time() - c0, os.getloadavg()
    rows = [("| controller (untuned) | PA12 cost | PA11 cost | PA12 tracking | PA12 powder "
             "| PA12 print | PA12 vs LQG % | PA11 vs LQG % |"), "|---|---|---|---|---|---|---|---|"]
    lq = res["lqg"]
    for name, v in res.items():
        sc = v["PA12"]["scenarios"]
        rows.append(f"| {name} | {v['PA12']['cost']:.4f} | {v['PA11']['cost']:.4f} | "
                    f"{sc['tracking']['cost']:.4f} | {sc['powder']['cost']:.4f} | "
                    f"{sc['print']['cost']:.4f} | "
                    f"{100 * (1 - v['PA12']['cost'] / lq['PA12']['cost']):.1f} | "
                    f"{100 * (1 - v['PA11']['cost'] / lq['PA11']['cost']):.1f} |")
    md = (f"# LQG + schedule feed-forward: what the observer sees\n\n"
          f"`.venv/bin/python experiments/lqg_ff_observer.py --rollouts {args.rollouts} "
          f"--duration {args.duration:g}`: held-out seed {HELD_OUT}, {args.rollouts} rollouts "
          f"per scenario, {args.duration:g} s scenarios, costs (`closedloop.cost`) per scenario "
          f"and their mean; no tuning.\n\n" + "\n".join(rows)
          + f"\n\n{wall:.0f} s wall, {cpu:.0f} s CPU, load {'/'.join(f'{x:.1f}' for x in load)} "
          "(2 shared cores).\n")
    OUT.write_text(md)
    OUT.with_suffix(".json").write_text(json.dumps(
        {"results": res, "wall_s": wall, "cpu_s": cpu, "load": load, "settings": vars(args)},
        indent=1) + "\n")
    print(md)


if __name__ == "__main__":
    main()
