"""The process monitors: ``process`` (teach-in limits per program block and three event
detectors over any monitored signal) and ``spindle_power`` (the spindle's cutting power: its
power less the idle power taught in air at each speed)."""

from estimators.monitoring import process, spindle_power

__all__ = ["process", "spindle_power"]
