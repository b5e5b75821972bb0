"""Where `jthermo simulate` spends its time, cold and warm, stage by stage.

Each compiled program of the command is split into its three parts: trace + lower to
StableHLO (done on every run, warm or cold: the persistent cache is keyed by the lowered
module), backend compile (cold) or the load of the executable from the persistent cache
(warm), and the execution. Beside them: the imports, the size of each program (StableHLO
characters, the cache entry's bytes) and the measurement noise drawn alone.

One command runs the whole study: a child process with an empty compilation cache (cold),
then a second child with the cache the first one filled (warm), both as the command runs
(`runtime.enable_cache`, `runtime.unroll_threefry`, float64, the design model with
`runtime.one_shot()` options and the run program as `closedloop.run` compiles it), then writes
`benchmarks/results/simulate_stages.md`:

    python benchmarks/simulate_stages.py                      # N = 16, B = 256, T = 3600
    python benchmarks/simulate_stages.py --rollouts 32 --duration 600 --out -   # quick look
    python benchmarks/simulate_stages.py --command

`--command` times the command's own steps instead (`cli.control`'s design model and
`closedloop.run`, with `runtime.one_thread_backend` and the programs kept by
`stored.exported_call`): no split of a program into trace / compile / execute there, but the
path `jthermo simulate` takes, stage by stage, cold and warm.

CPU seconds (user + system of the child, all threads) are less sensitive than wall seconds to
other jobs on a shared machine; the 1-minute load is recorded for each child.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

T_START = time.perf_counter()
CPU_START = time.process_time()

HERE = Path(__file__).resolve().parent


def _load() -> str:
    return Path("/proc/loadavg").read_text().split()[0]


class _Clock:
    """Rows `{stage, wall_s, cpu_s, cache_bytes}` of consecutive stages of this process."""

    def __init__(self, cache: Path | None):
        self.rows: list[dict] = []
        self.cache = cache
        self.seen = self._entries()
        self.w, self.c = T_START, CPU_START

    def _entries(self) -> dict[str, int]:
        if self.cache is None or not self.cache.is_dir():
            return {}
        return {p.name: p.stat().st_size for p in self.cache.iterdir() if p.name.endswith("-cache")}

    def mark(self, stage: str, **extra) -> None:
        import jax  # noqa: F401  (loaded by then)

        w, c = time.perf_counter(), time.process_time()
        now = self._entries()
        new = sum(v for k, v in now.items() if k not in self.seen)
        self.seen = now
        self.rows.append({"stage": stage, "wall_s": w - self.w, "cpu_s": c - self.c,
                          "cache_bytes": new, **extra})
        self.w, self.c = time.perf_counter(), time.process_time()


def command_child(args) -> None:
    """The stages of `cli.control.cmd_simulate` (one-thread backend, exported programs)."""
    from jthermo import runtime

    cache = runtime.enable_cache()
    runtime.unroll_threefry()
    import jax

    jax.config.update("jax_enable_x64", True)
    clock = _Clock(cache)
    clock.mark("import jax, jthermo.runtime")
    clock.mark("one-thread CPU backend", applied=runtime.one_thread_backend())
    from jthermo import closedloop as cl
    from jthermo.cli import control
    from jthermo.control.design import design
    from jthermo.printer import make_printer

    clock.mark("import closedloop, cli.control, control.design")
    plant = jax.block_until_ready(make_printer(args.zones, cl.REALISTIC_EFFECTS, powder="PA12",
                                               seed=0))
    clock.mark("make_printer")
    model = jax.block_until_ready(control.stored_printer_model(plant))
    clock.mark("design model (exported program)")
    ctrl = jax.block_until_ready(design("pi_lambda", model))
    clock.mark("design pi_lambda (small programs, eager)")
    out = cl.run("tracking", ctrl, plant, rollouts=args.rollouts, duration=args.duration, seed=0)
    clock.mark("closedloop.run (exported run program)")
    print(json.dumps({"rows": clock.rows, "mse": out["metrics"]["mse"], "load": _load()}))


def child(args) -> None:
    from jthermo import runtime

    cache = runtime.enable_cache()
    if args.threefry == "unrolled":
        runtime.unroll_threefry()
    import jax

    jax.config.update("jax_enable_x64", True)
    clock = _Clock(cache)
    clock.mark("import jax, jthermo.runtime")
    import equinox as eqx

    from jthermo import closedloop as cl
    from jthermo.closedloop import engine
    from jthermo.control.design import design
    from jthermo.printer import make_printer
    from jthermo.tune import printer_model

    clock.mark("import closedloop, control.design, tune")
    plant = jax.block_until_ready(make_printer(args.zones, cl.REALISTIC_EFFECTS, powder="PA12",
                                               seed=0))
    clock.mark("make_printer")

    def program(name: str, fn, *a):
        lowered = fn.lower(*a)
        size = len(lowered.as_text())
        clock.mark(f"{name}: trace + lower", stablehlo_chars=size)
        compiled = lowered.compile()
        clock.mark(f"{name}: compile (cold) / cache load (warm)")
        out = jax.block_until_ready(compiled(*a))
        clock.mark(f"{name}: execute")
        return out

    model = program("design model (tune.printer_model)",
                    eqx.filter_jit(printer_model, compiler_options=runtime.one_shot()), plant)
    ctrl = jax.block_until_ready(design("pi_lambda", model))
    clock.mark("design pi_lambda (small programs, eager)")
    key = jax.random.key(0)
    out = program("run program (scenarios + lean metrics)", engine._quick_scenario_metrics(),
                  "tracking", plant, ctrl, args.duration, key, args.rollouts)
    T = round(args.duration / plant.ts)
    noise = eqx.filter_jit(lambda k: jax.vmap(lambda kk: plant.sample_noise(kk, T, 0.05))(
        jax.random.split(k, args.rollouts)))
    program("measurement noise alone (sample_noise x B)", noise, key)
    print(json.dumps({"rows": clock.rows, "mse": float(out[0]["mse"]), "load": _load()}))


def run_child(args, cache: str) -> dict:
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env.pop("JTHERMO_NO_CACHE", None)
    env["JTHERMO_CACHE_DIR"] = cache
    load0 = _load()
    cmd = [sys.executable, __file__, "--child", "--zones", str(args.zones), "--rollouts",
           str(args.rollouts), "--duration", str(args.duration), "--threefry", args.threefry]
    if args.command:
        cmd.append("--command")
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    rep = json.loads(r.stdout.strip().splitlines()[-1])
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    rep.update(load0=load0, wall_s=wall, cpu_total=ru.ru_utime + ru.ru_stime)
    return rep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--threefry", choices=("unrolled", "rolled"), default="unrolled",
                    help="Threefry's CPU lowering (the command unrolls it)")
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_stages.md"))
    ap.add_argument("--command", action="store_true",
                    help="time the command's own steps (exported programs, one-thread backend)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return command_child(args) if args.command else child(args)
    with tempfile.TemporaryDirectory(prefix="jthermo-stages-") as tmp:
        cold = run_child(args, tmp)
        cpu_cold = cold["cpu_total"]
        warm = run_child(args, tmp)
        warm["cpu_total"] -= cpu_cold
    lines = [(f"# `jthermo simulate` stage by stage: N = {args.zones}, B = {args.rollouts}, "
              f"T = {args.duration:g} s"), "",
             (f"`python benchmarks/simulate_stages.py --zones {args.zones} --rollouts "
              f"{args.rollouts} --duration {args.duration:g}"
              + (" --threefry rolled" if args.threefry == "rolled" else "")
              + (" --command" if args.command else "") + "`: "
              "cold = a process with an empty compilation cache, warm = a second process with "
              "the cache the first filled. Wall / CPU s (user + system, all threads) per stage; "
              f"1-minute load {cold['load0']} before the cold process, {warm['load0']} before "
              "the warm one (2 shared cores: wall seconds scale with the load, CPU seconds less "
              f"so). mse {cold['mse']:.8f} cold, {warm['mse']:.8f} warm."), "",
             ("| stage | cold wall s | cold CPU s | warm wall s | warm CPU s | StableHLO chars | "
              "cache entry bytes |"), "|---|---|---|---|---|---|---|"]
    for a, b in zip(cold["rows"], warm["rows"]):
        lines.append(f"| {a['stage']} | {a['wall_s']:.2f} | {a['cpu_s']:.2f} | {b['wall_s']:.2f} "
                     f"| {b['cpu_s']:.2f} | {a.get('stablehlo_chars', '')} | "
                     f"{a['cache_bytes'] or ''} |")
    lines.append(f"| whole process (interpreter start to exit) | {cold['wall_s']:.2f} | "
                 f"{cold['cpu_total']:.2f} | {warm['wall_s']:.2f} | {warm['cpu_total']:.2f} | | |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out != "-":
        Path(args.out).write_text(text)


if __name__ == "__main__":
    sys.exit(main())
