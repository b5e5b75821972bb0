"""Controllers for the N-zone bed and their classical design rules."""

from ._base import AbstractController as AbstractController
from .pi import DiagonalPI as DiagonalPI, PIState as PIState
from .decoupled import (DecoupledPI as DecoupledPI, design_decoupled_pi as design_decoupled_pi,
                        design_lambda_pi as design_lambda_pi, design_untuned_pi as design_untuned_pi)
from .design import FAMILIES as FAMILIES, design as design
from .feedforward import FeedForward as FeedForward, design_feedforward as design_feedforward
from .gated import Gated as Gated, gated as gated
from .imc import IMC as IMC, design_imc as design_imc
from .lqg import LQG as LQG, design_lqg as design_lqg, solve_dare as solve_dare
from .rules import (decoupling_matrix as decoupling_matrix, fit_step_model as fit_step_model,
                    lambda_gains as lambda_gains, needs_decoupling as needs_decoupling, rga as rga,
                    step_models as step_models)
from .mimo_pi import MIMOPI as MIMOPI, mimo_from as mimo_from, neighbour_mask as neighbour_mask
from .schedule_ff import ScheduleFF as ScheduleFF, with_schedule as with_schedule
from .relay import (DiagonalPID as DiagonalPID, design_pid_relay as design_pid_relay,
                    relay_test as relay_test)
