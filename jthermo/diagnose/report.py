"""The diagnosis report: Markdown with figures (residuals before/after, per-zone fit, evidence).

Figures come from `jthermo.plots` where it has them (`plot_residuals`, `plot_compare`) and are
otherwise built here as matplotlib `Figure` objects (no pyplot, headless).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..data import atomic_write_text
from ..errors import ConfigError
from .select import to_json


def _evidence_figure(result, est, path):
    from matplotlib.figure import Figure

    from ..plots import save_figure

    fig = Figure(figsize=(8, 3.2), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2)
    cands = [c for c in result.get("candidates", []) if "+" not in c["mechanism"]]
    names = [c["mechanism"] for c in cands]
    vals = [100 * c["val_reduction"] for c in cands]
    ax1.barh(names[::-1], np.clip(vals[::-1], -100, 100), color="tab:blue")
    ax1.axvline(0, color="k", lw=0.6)
    ax1.set_xlabel("validation MSE reduction (%)")
    ax1.set_title("candidate refits", fontsize="small")
    ax1.tick_params(labelsize="x-small")
    top = result["findings"][0]["mechanism"] if result["findings"] else None
    loc = result.get("localisation", {})
    arrays = result.get("_arrays", {})
    if top == "input_delay" and "delay_scan" in loc:
        ax2.plot(loc["delay_scan"]["delays_s"], loc["delay_scan"]["cost"], "o-")
        ax2.axhline(loc["delay_scan"]["baseline_cost"], color="tab:red", lw=0.8, label="no delay")
        ax2.set_xlabel("dead time (s)")
        ax2.set_ylabel("simulation MSE (°C²)")
        ax2.legend(fontsize="x-small")
        ax2.set_title("dead-time scan of the baseline", fontsize="small")
    elif top == "recoat_cooling" and "resid_est" in arrays:
        R = np.asarray(arrays["resid_est"])
        P = round(result["findings"][0]["parameters"].get("period_s", 0) / est.ts)
        if P > 1:
            m = (len(R) // P) * P
            ax2.plot(np.arange(P) * est.ts, R[:m].mean(axis=1).reshape(-1, P).mean(axis=0))
            ax2.set_xlabel("time within period (s)")
            ax2.set_ylabel("mean residual (°C)")
            ax2.set_title(f"baseline residual folded at {P * est.ts:g} s", fontsize="small")
    elif "resid_est" in arrays:
        R = np.asarray(arrays["resid_est"])
        f = np.fft.rfftfreq(len(R), est.ts)[1:]
        S = (np.abs(np.fft.rfft(R - R.mean(axis=0), axis=0)) ** 2).mean(axis=1)[1:]
        ax2.loglog(f, S, lw=0.7)
        ax2.set_xlabel("frequency (Hz)")
        ax2.set_ylabel("residual power")
        ax2.set_title("baseline residual spectrum (estimation)", fontsize="small")
    save_figure(fig, path)
    return fig


def _pooled_lines(result: dict) -> list[str]:
    """The pooled records' table: each record's share of every finding's estimation evidence."""
    recs = result.get("estimation_records", [])
    shown = [f for f in result["findings"] if f["evidence"].get("records")]
    if len(recs) < 2:
        return []
    lines = ["## Pooled estimation records", "",
             f"{len(recs)} records fitted jointly (shared physical parameters; each record its own "
             "initial state, surroundings level and drift); the tests are on their pooled residuals.", ""]
    if not shown:
        return lines
    lines += ["| record | samples | " + " | ".join(f"`{f['mechanism']}` share (LR)" for f in shown) + " |",
              "| --- | --- | " + " | ".join("---" for _ in shown) + " |"]
    for r, rec in enumerate(recs):
        cells = [f"{f['evidence']['records'][r]['sse_share']:.2f} "
                 f"({f['evidence']['records'][r]['likelihood_ratio']:.1f})" for f in shown]
        lines.append(f"| {r + 1} | {rec['samples']} | " + " | ".join(cells) + " |")
    return lines + ["", "Share: the record's part of the pooled squared error the mechanism removes "
                        "on the estimation records; LR: its own likelihood ratio.", ""]


def write_report(result: dict, directory: str | os.PathLike, est, val) -> Path:
    """Write `report.md`, `diagnosis.json` and PNG figures for a `diagnose` result.

    **Returns:** the path of `report.md`.
    """
    from ..plots import plot_compare, plot_residuals

    if not isinstance(result, dict) or "verdict" not in result:
        raise ConfigError("write_report: `result` must be the dict returned by `diagnose`")
    est = est[0] if isinstance(est, (list, tuple)) else est       # pooled: their common sample time
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    arrays = result.get("_arrays", {})
    figs = []
    if "yhat_baseline" in arrays:
        yb, ya = np.asarray(arrays["yhat_baseline"]), np.asarray(arrays["yhat_augmented"])
        y = np.asarray(val.y)
        plot_residuals(val.t, y - yb, y - ya, labels=("baseline", "augmented"),
                       path=d / "residuals.png")
        figs.append(("Validation residuals before and after", "residuals.png"))
        plot_compare(val, {"baseline": yb, "augmented": ya},
                     {"baseline": result["baseline"]["fit_percent"],
                      "augmented": result["augmented"]["fit_percent"]}, path=d / "fit.png")
        figs.append(("Per-zone simulation fit on validation data", "fit.png"))
    _evidence_figure(result, est, d / "evidence.png")
    figs.append(("Evidence behind the top finding", "evidence.png"))
    js = to_json(result)
    atomic_write_text(d / "diagnosis.json", json.dumps(js, indent=1, default=float))
    lines = ["# Mismatch diagnosis", "",
             f"**Verdict:** `{result['verdict']}`", "",
             (f"Baseline ({result['baseline']['model']}): mean validation simulation fit "
             f"{result['baseline']['mean_fit_percent']:.1f} % "
             f"(per zone: {', '.join(f'{v:.1f}' for v in result['baseline']['fit_percent'])})."), ""]
    if result["findings"]:
        lines += ["## Findings (most likely first)", "",
                  "| # | mechanism | confidence | zones | summary |", "| --- | --- | --- | --- | --- |"]
        for k, f in enumerate(result["findings"]):
            lines.append(f"| {k + 1} | `{f['mechanism']}` | {f['confidence']:.2f} | "
                         f"{', '.join(map(str, f['zones']))} | {f['summary']} |")
        aug = result["augmented"]
        lines += ["", (f"Augmented model ({' + '.join(aug['mechanisms'])}): mean validation fit "
                  f"{aug['mean_fit_percent']:.1f} % (gain "
                  f"{aug['mean_fit_percent'] - result['baseline']['mean_fit_percent']:+.1f} points)."), "",
                  "Parameters: `" + json.dumps(aug["parameters"], default=float)[:600] + "`", ""]
        if result["findings"][0].get("rivals"):
            lines += ["Within the test's resolution of the top finding (rivals): "
                      + ", ".join(f"`{m}`" for m in result["findings"][0]["rivals"]) + ".", ""]
    lines += _pooled_lines(result)
    exp = result.get("experiment")
    if exp:
        lines += ["## Next experiment", "",
                  (f"Designed to separate {', '.join(f'`{m}`' for m in exp['rivals'])} ({exp['why']}): "
                   f"{exp['duration_s']:g} s within inputs {exp['limits']['u_min']}–{exp['limits']['u_max']}, "
                   f"expected separation (weakest pair) {exp['separation_designed']:.3g} noise units against "
                   f"{exp['separation_prbs']:.3g} for a PRBS of the same length"
                   + (f"; written to `{exp['path']}`." if exp.get("path") else ".")), ""]
    for f in result.get("flagged", []):
        lines += [f"Flagged, not named: `{f['mechanism']}` improves the fit, but {f['reason']}.", ""]
    if not result["findings"]:
        lines += ["No candidate mechanism improved the validation simulation by a significant margin:",
                  "nothing the library knows is missing from the baseline model.", ""]
    if result.get("candidates"):
        lines += ["## Candidate refits", "",
                  ("| mechanism | validation z (critical) | estimation LR (critical) | significant | "
                   "validation MSE reduction % | fit gain (points) |"),
                  "| --- | --- | --- | --- | --- | --- |"]
        for c in result["candidates"]:
            lines.append(f"| {c['mechanism']} | {c['validation_z']:.2f} ({c['validation_z_critical']:.2f}) | "
                         f"{c['estimation_lr']:.1f} ({c['estimation_lr_critical']:.1f}) | "
                         f"{'yes' if c['significant'] else 'no'} | "
                         f"{100 * c['val_reduction']:.1f} | {c['fit_gain']:.2f} |")
        lines.append("")
    loc = result.get("localisation")
    if loc:
        lines += ["## Where the baseline residuals live (estimation data)", "",
                  f"- RMS per zone (°C): {loc['zones_rms_C']}",
                  f"- power share by band: {loc['band_share']}",
                  f"- common-mode share: {loc['common_mode_share']}",
                  f"- periodic drops: {loc.get('periodic')}",
                  f"- worst windows: {loc['worst_windows']}", ""]
    for title, fn in figs:
        lines += [f"### {title}", "", f"![{title}]({fn})", ""]
    path = d / "report.md"
    atomic_write_text(path, "\n".join(lines))
    return path


__all__ = ["write_report"]
