"""Closed-loop simulation: controller × plant × scenario, one `lax.scan` over time.

```
y_k = g(x_k) + v_k                      (measured, °C; v = measurement noise)
u_k, c_{k+1} = controller.step_schedule(c_k, y_k, r_k, s_k);   u_k <- clip(u_k, 0, 1)
x_{k+1} = f(x_k, u_k, d_k)              (plant, one sample Ts)
```

Plants are the virtual printer (`jthermo.printer.Printer`, disturbances `PrinterDisturbance`:
recoat flags, laser power per zone, surroundings) or any fitted `AbstractModel`. A fitted
model is a plant in its own right: `model_scenario` builds its tests from its recording
(`models.Envelope`: sample time, set points in the recorded range, input-referred load steps,
noise). Its scenario carries `ModelDisturbance`: the measured signals `w` it was fitted with
and an additive *output* disturbance `dy` (the load's response; with a `reference` printer,
the printer's open-loop response to the same recoat/laser events — superposition: exact for
a linear plant). Batches come from `rollouts` (vmap over scenarios and,
with `plant_axis=0`, over a stacked batch of plants). Everything is pure and differentiable with
respect to controller gains and plant parameters.
"""

from .scenarios import (
    DEFAULT_DURATION as DEFAULT_DURATION, KINDS as KINDS, REALISTIC_EFFECTS as REALISTIC_EFFECTS,
    STEP_C as STEP_C, WINDOW_C as WINDOW_C, ModelDisturbance as ModelDisturbance,
    Scenario as Scenario, Trajectory as Trajectory, make_scenario as make_scenario,
    compiled_make_scenario as compiled_make_scenario,
    PREVIEW_S as PREVIEW_S, event_schedule as event_schedule,
    MODEL_KINDS as MODEL_KINDS, model_duration as model_duration,
    model_scenario as model_scenario, unlabelled as unlabelled,
)
from .scoring import (
    DEFAULT_WEIGHTS as DEFAULT_WEIGHTS, METRICS as METRICS, RunningMetrics as RunningMetrics,
    cost as cost, metric_arrays as metric_arrays, metrics as metrics,
)
from .compact import CompactScenario as CompactScenario, Events as Events
from .engine import (
    initial_state as initial_state,
    rollout_costs as rollout_costs, rollouts as rollouts, rollouts_and_cost as rollouts_and_cost,
    rollout_metrics as rollout_metrics, run as run, prepare_run as prepare_run,
    simulate as simulate,
    simulate_cost as simulate_cost, simulate_metrics as simulate_metrics,
)
