#!/usr/bin/env bash
# The README tour's kind of record at N = 16 (lateral conduction, radiation, heater lag concealed):
# one hour of estimation (--seed 1) and 30 min of validation (--seed 2) of printer 0, diagnosed
# from the shell with the default options; prints each finding's effect beside the sensor noise.
#   bash experiments/diagnose_tour16.sh
# Writes experiments/results/diagnose_tour16.md (the findings table and the command's time); the
# records and the command's JSON stay in a temporary folder.
set -eu
out=$(mktemp -d /tmp/jthermo-tour16.XXXX)
report=experiments/results/diagnose_tour16.md
J=.venv/bin/jthermo
fx=lateral_conduction,radiative_loss,heater_lag
$J generate --experiment prbs --zones 16 --duration 3600 --effects $fx --seed 1 --out "$out/est.csv" --quiet
$J generate --experiment prbs --zones 16 --duration 1800 --effects $fx --seed 2 --out "$out/val.csv" --quiet
la=$(cut -d' ' -f1-3 /proc/loadavg)
{ time $J diagnose "$out/est.csv" --validation "$out/val.csv" --json "$out/diagnose_n16.json" --quiet ; } 2> "$out/time.txt"
rm -f "$out/est.csv" "$out/val.csv"
.venv/bin/python - "$out" "$la" <<'PY' | tee "$report"
import json, sys
d = json.load(open(f"{sys.argv[1]}/diagnose_n16.json"))
print(f"# N = 16 tour record: `bash experiments/diagnose_tour16.sh` (load at start {sys.argv[2]})\n")
print(f"verdict {d['verdict']}, fit {d['baseline']['mean_fit_percent']:.2f} -> "
      f"{d['augmented']['mean_fit_percent']:.2f} %, {d['seconds']:.0f} s in the command\n")
print("| finding | confidence | effect °C RMS | sensor noise °C | below noise | summary |\n|---|---|---|---|---|---|")
for f in d["findings"]:
    e = f["evidence"]
    print(f"| {f['mechanism']} | {f['confidence']} | {e['effect_rms_C']} | {e['sensor_noise_C']} | "
          f"{f['below_noise']} | {f['summary'][:120]} |")
PY
{ echo; echo "Time of the command:"; echo; sed 's/^/    /' "$out/time.txt"; } >> "$report"
rm -rf "$out"
