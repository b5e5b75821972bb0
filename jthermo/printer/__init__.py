"""The virtual printer: a nonlinear, higher-fidelity model of a Powder Bed Fusion bed.

It is the plant jthermo makes data with and tests controllers against, richer than any model
it fits. With no effect switched on it *is* the linear grey-box bed model of the thesis
(Eriksson & Hanses 2019, eq. 3.5):

$$C_i \\dot T_i = -G_i (T_i - T_s) + \\sum_j n_{ij} u_j ,$$

zones on a near-square grid, each heater reaching every zone through a Gaussian footprint
$n_{ij}$. Each physical effect is switched on by name with its own parameters
(`make_printer(effects={"radiative_loss": {"emissivity": 0.8}, "heater_lag": True})`):

| effect | what it adds | parameters (defaults in `EFFECTS`) |
| --- | --- | --- |
| `lateral_conduction` | heat flow between grid neighbours $k (T_j - T_i)$ | `conductance_W_K` |
| `radiative_loss` | $\\varepsilon\\sigma A (T^4 - T_s^4)$ in kelvin | `emissivity`, `area_m2` |
| `heat_accumulation` | a slow shared chamber/wall state the zones lose heat to | `share`, `time_constant_s`, `loss_ratio` |
| `heater_lag` | first-order lamp lag | `time_constant_s` |
| `input_delay` | dead time in whole samples | `delay_s` |
| `input_nonlinearity` | lamp power $u^p$ | `exponent` |
| `recoat_cooling` | a cold layer spread every `period_s`, sweeping the columns in `duration_s`, pulling zones towards `temperature_C` (a drop of `drop_C` at the window centre) | `period_s`, `drop_C`, `duration_s`, `temperature_C`, `phase_s` |
| `laser_exposure` | absorbed laser power on a per-layer pattern of zones | `power_W`, `exposure_s`, `fraction`, `start_s`, `period_s` |
| `ambient_variation` | drift of the surroundings (sinusoid + random walk) | `amplitude_C`, `period_s`, `walk_C`, `measured` |
| `sensor_noise` | white + AR(1) coloured measurement noise | `white_std_C`, `coloured_std_C`, `pole` |
| `sensor_offset` | a constant bias per zone sensor | `std_C` (or `offsets_C`) |

Conventions that keep the operating point where the data are taken: with `radiative_loss`,
`loss` stays the total loss conductance at the window centre (the linear part gives up the
radiation's secant share); with `heat_accumulation`, `loss` stays the steady-state loss of a
uniform bed; with `input_nonlinearity`, power = $0.5^{1-p} u^p$ (equal to u at the nominal input
0.5). Default parameters (PA12, seed 0): C ≈ 36 J/K, G ≈ 0.6 W/K (τ = C/G ≈ 60 s), heater
footprint width 0.7 zone, surroundings 145 °C, so that u ≈ 0.5 holds the 172–176 °C window.

`areas=True` adds the thesis' areas 1–3 (wall heaters, build plate, powder container) as extra
states, each with its own heater input and thermocouple output (inputs/outputs N+1..N+3).

Integration: the linear part (zones, chamber, lamps, areas) is discretised exactly (zero-order
hold, a matrix exponential); radiation and the recoat sweep enter through fixed sub-steps of an
exponential Runge–Kutta scheme (ETD2RK, Cox & Matthews 2002). Without those effects one step is
the exact ZOH step, so the effect-free printer equals `BedModel.from_physical` to round-off.

Disturbances enter `step` through `PrinterDisturbance` (per sample: a recoat-start flag, laser
power per zone in W, surroundings temperature in °C); `disturbances(...)` builds them for a run.
"""

from .geometry import (
    AREA_NAMES as AREA_NAMES, HEATED_DEPTH as HEATED_DEPTH, KELVIN as KELVIN,
    NOMINAL_INPUT as NOMINAL_INPUT, POWDERS as POWDERS, SIGMA as SIGMA, ZONE_AREA as ZONE_AREA,
    Powder as Powder, grid_edges as grid_edges, grid_positions as grid_positions,
    grid_shape as grid_shape,
)
from .effects import EFFECTS as EFFECTS
from .state import PrinterDisturbance as PrinterDisturbance, PrinterState as PrinterState
from .discrete import DiscretePrinter as DiscretePrinter
from .plant import (
    Printer as Printer, SMOOTH_SUBSTEPS as SMOOTH_SUBSTEPS, steady_state as steady_state,
)
from .build import make_printer as make_printer
from .runs import (
    disturbances as disturbances, generate as generate, input_names as input_names,
    simulate_open_loop as simulate_open_loop,
)
