"""Sweeps: grid or random search over identification orders and options, controller families,
tuning weights.

A sweep is a TOML file (or the embedded `DEFAULT_CONFIG`):

```toml
[sweep]
name = "arx-orders"
kind = "arx"            # trial kind: "arx", "identify" or "tune"
method = "grid"         # or "random" (then `samples` draws)
samples = 20
seed = 0
objective = "mean_fit_percent"
direction = "max"       # or "min"

[data]                  # where the data (or plant) comes from, shared by every trial
data = "est.csv"        # default: a simulated coupled bed (arx), the virtual printer (identify)
validation = "val.csv"  # default: the second half of `data`

[fixed]                 # parameters every trial gets (part of the trial ids)
n_starts = 4

[space]                 # one list per parameter (grid: the Cartesian product)
na = [1, 2, 3]
nb = [1, 2]
nk = [0, 1]
```

Every kind fits and scores the way a script would: `arx` and `identify` trials call
`identify.fit(est, family, orders, **options)` and score the model with `validate.compare` on
the validation record (`mean_fit_percent`); `arx` is `identify` with the family fixed to ARX.
Parameters are the order names (`na`, `nb`, `nk`, `nc`, `nd`, `nf`, `n`), `family`, `seed`,
`n_starts`, `criterion` and any option of `fit` (`max_steps`, `offset`, `rest_level`,
`focus`, ...), passed through. A `tune` trial tunes `controller` (`rollouts`, `steps`,
`seed`, `lr`, `duration`, a cost weight `w_<term>` per term) on the virtual printer, or, with
`[data] model = "fit.jtm"` (and/or `plant`, `validation_plant`), on the user's own fitted
model at its `setpoint` (`tune.tune_own_plant`). Names are checked when the configuration is
read: a `[data]` key or a parameter that the kind does not read is a `ConfigError`
(`DATA_KEYS`, `trial_settings`). Trial settings may also sit in `[data]`, the same for every
trial and outside the trial ids; the other way round, the keys of a simulated record
(`RECORD_KEYS`: `zones`, `samples` or `duration`, `data_seed`, ...) may be parameters, a sweep
over record lengths and zone counts.

In a random sweep a parameter may also be a range table `{low = 1e-3, high = 1.0, log = true}`
(floats) or `{low = 1, high = 5}` (integers). Each trial has a stable id (a hash of its
parameters, salted with the jthermo version and `TRIAL_FORMAT`: `trial_salt`), runs locally (in-process, or a process pool with `workers > 1`) or as a Ray task
(`ray_address`), in float64 inside a scoped `jax.enable_x64` (the caller's JAX configuration
is never changed), and its result is appended to a JSON-lines file as soon as it finishes
(flushed and fsynced). Re-running the same sweep skips the trial ids already in the file, so a
killed sweep resumes without redoing or losing finished trials; after an upgrade of jthermo
the ids change, so the trials run again (the old rows stay in the file, each with its
`jthermo_version`, and are left out of the best trials).

`run_sweep(...).to_dataframe()` (or `results_frame(read_results(path), cfg)`) gives the trials
as a pandas DataFrame, best first; `history_frame` a tuning run's cost per iteration.
"""

from .config import (
    DEFAULT_CONFIG as DEFAULT_CONFIG, KINDS as KINDS, check_config as check_config,
    count_trials as count_trials, default_config as default_config, load_config as load_config,
    parse_config as parse_config, trial_id as trial_id, trials as trials, DATA_KEYS as DATA_KEYS,
    SETTINGS as SETTINGS, RECORD_KEYS as RECORD_KEYS, trial_settings as trial_settings,
    TRIAL_FORMAT as TRIAL_FORMAT,
    trial_salt as trial_salt, current_rows as current_rows,
)
from .tasks import run_trial as run_trial
from .runner import (
    append_result as append_result, best_trials as best_trials,
    default_results_path as default_results_path, format_summary as format_summary,
    read_results as read_results, run_sweep as run_sweep, SweepResult as SweepResult,
)
from .frames import history_frame as history_frame, results_frame as results_frame
