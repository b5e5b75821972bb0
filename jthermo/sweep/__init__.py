"""Sweeps: grid or random search over identification orders, controller families, tuning weights.

A sweep is a TOML file (or the embedded `DEFAULT_CONFIG`):

```toml
[sweep]
name = "arx-orders"
kind = "arx"            # trial kind: "arx" (fast least squares), "identify", "tune"
method = "grid"         # or "random" (then `samples` draws)
samples = 20
seed = 0
objective = "mean_fit_percent"
direction = "max"       # or "min"

[data]                  # kind-specific settings shared by every trial
zones = 2
duration = 600

[space]                 # one list per parameter (grid: the Cartesian product)
na = [1, 2, 3]
nb = [1, 2]
nk = [0, 1]
```

In a random sweep a parameter may also be a range table `{low = 1e-3, high = 1.0, log = true}`
(floats) or `{low = 1, high = 5}` (integers). Each trial has a stable id (a hash of its
parameters), runs locally (in-process, or a process pool with `workers > 1`) or as a Ray task
(`ray_address`), and its result is appended to a JSON-lines file as soon as it finishes
(flushed and fsynced). Re-running the same sweep skips the trial ids already in the file, so a
killed sweep resumes without redoing or losing finished trials.
"""

from .config import (
    DEFAULT_CONFIG as DEFAULT_CONFIG, KINDS as KINDS, check_config as check_config,
    count_trials as count_trials, default_config as default_config, load_config as load_config,
    parse_config as parse_config, trial_id as trial_id, trials as trials,
)
from .tasks import run_trial as run_trial
from .runner import (
    append_result as append_result, best_trials as best_trials,
    default_results_path as default_results_path, format_summary as format_summary,
    read_results as read_results, run_sweep as run_sweep,
)
