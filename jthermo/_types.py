"""jaxtyping aliases shared by the package. Arrays are time-major: (T, n)."""

from jaxtyping import Array, Float, PRNGKeyArray

State = Float[Array, " nx"]            # model state (°C above reference for thermal models)
Input = Float[Array, " nu"]            # heater power fraction in [0, 1]
Output = Float[Array, " ny"]           # sensor temperatures, °C
Disturbance = Float[Array, " nw"]      # measured/known external signals (e.g. surroundings, °C)
Setpoint = Float[Array, " ny"]         # °C
Inputs = Float[Array, "T nu"]
Outputs = Float[Array, "T ny"]
Key = PRNGKeyArray

__all__ = ["Array", "Float", "Key", "State", "Input", "Output", "Disturbance", "Setpoint",
           "Inputs", "Outputs"]
