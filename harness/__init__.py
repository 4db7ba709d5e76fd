"""The simulation harness: simulated machines driven with the estimators in a loop.

Below the application (``server``) and above ``machine`` and ``estimators``, which it
joins: the eccentricity loop (seed 003's milling machine on its feed drives with the ESC,
the fast tuner and the force observers), the accelerated wear clock (seed 004's wear model
with its observer and tool-life monitor), the rolling accuracy of force estimates, and the
plant's sharding of machines over workers. The live pipeline's parts, the reproductions
and the benchmarks run them; nothing here knows the service, its files or its wire
(``pyproject.toml``'s import contracts).
"""
