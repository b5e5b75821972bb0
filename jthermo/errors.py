"""The jthermo error family: every user-facing failure is one of these, with a one-line reason."""


class JThermoError(Exception):
    """Base of every error jthermo raises on purpose (the CLI turns it into exit status 2)."""


class DataError(JThermoError, ValueError):
    """Input data that cannot be used: malformed file, NaN, non-uniform time, too short, not exciting."""


class ModelError(JThermoError, ValueError):
    """A model structure that is impossible or inconsistent (orders, shapes, unstable result)."""


class FitError(JThermoError, RuntimeError):
    """An estimation that cannot give a usable model (diverged, NaN, no start point converged)."""


class ControlError(JThermoError, ValueError):
    """A controller that cannot be designed or tuned (singular gain, unstable loop, NaN)."""


class ConfigError(JThermoError, ValueError):
    """A command-line option, configuration file or saved file that cannot be used."""
