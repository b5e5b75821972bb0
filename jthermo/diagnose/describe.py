"""Words and evidence for a finding: the one-line summary and the figures behind it."""

from __future__ import annotations

from .decide import CONFIDENT


def summary(mech, zones, params, uncertain=False, rivals=(), small=None):
    """One line on the finding; an uncertain one (`decide.uncertain`) says so and names its
    rivals; one whose effect is below the sensor noise (`small`: (effect, noise) in °C,
    `decide.below_noise`) says that too."""
    line = _summary(mech, zones, params)
    if small is not None:
        line = (f"Small effect ({small[0]:.3g} °C RMS on the prediction, below the sensor noise "
                f"{small[1]:.3g} °C): {line}")
    if not uncertain:
        return line
    why = (f"the data do not separate it from {', '.join(rivals)}" if rivals
           else f"its confidence is below {CONFIDENT:g}")
    return f"Uncertain ({why}): {line}"


def _summary(mech, zones, params):
    z = ", ".join(str(v) for v in zones)
    where = f"zone{'s' if len(zones) > 1 else ''} {z}"
    if mech == "lateral_conduction":
        return f"Heat flows between neighbouring zones (lateral conduction), strongest in {where}; the isolated-zone model leaves it out."
    if mech == "radiative_loss":
        if params.get("steeper_than_radiation", False):
            return (f"Heat loss grows faster than linearly with temperature, more steeply than radiation "
                    f"alone (convection h(T) or radiation with convection) in {where}.")
        return f"Heat loss grows faster than linearly with temperature (radiation, T^4 in kelvin) in {where}."
    if mech == "heat_accumulation":
        return (f"A slow shared body (walls/chamber, time constant about {params.get('time_constant_s', float('nan')):.0f} s) "
                f"stores heat and feeds it back to {where}.")
    if mech == "heater_lag":
        return f"The heaters respond with a first-order lag of about {params.get('time_constant_s', float('nan')):.1f} s before heating {where}."
    if mech == "input_delay":
        return f"The heater inputs act after a dead time of {params.get('delay_s', 0):.2g} s on {where}."
    if mech == "input_nonlinearity":
        return f"Heater power is not proportional to the command: it follows u^{params.get('exponent', float('nan')):.2f} ({where})."
    if mech == "recoat_cooling" and params.get("events") and params.get("spacing_cv", 1.0) >= 0.1:
        return (f"Cooling drops of about {params.get('drop_C', float('nan')):.2f} °C at {params['events']} "
                f"events about {params.get('mean_interval_s', float('nan')):.0f} s apart, not periodic "
                f"(recoat of cold powder, layer by layer) hit {where}.")
    if mech == "recoat_cooling":
        return (f"Periodic cooling drops of about {params.get('drop_C', float('nan')):.2f} °C every "
                f"{params.get('period_s', float('nan')):.0f} s (recoat of cold powder) hit {where}.")
    if mech == "ambient_variation":
        return f"The surroundings temperature drifts during the run and moves {where} with it."
    return mech


def mechanism_evidence(mech, loc, per_ev, drops=None):
    if mech == "recoat_cooling" and drops is not None:
        return {"drop_statistic": round(drops["statistic"], 2), "drop_level": round(drops["level"], 2),
                "events": len(drops["times_s"])}
    if mech == "recoat_cooling":
        return {"periodic_drop_statistic": round(per_ev["statistic"], 2),
                "period_s": per_ev["period_s"]}
    if mech == "input_delay":
        return {"delay_scan": loc["delay_scan"]}
    if mech == "lateral_conduction":
        return {"neighbour_difference_correlation": loc["neighbour_difference_correlation"]}
    if mech in ("ambient_variation", "heat_accumulation"):
        return {"common_mode_share": loc["common_mode_share"],
                "slow_band_share": loc["band_share"]["below_1_over_600s"]}
    if mech == "radiative_loss":
        return {"temperature_level_correlation": loc["temperature_level_correlation"]}
    if mech in ("heater_lag", "input_nonlinearity"):
        return {"input_correlation": loc["input_correlation"]}
    return {}


__all__ = ["mechanism_evidence", "summary"]
