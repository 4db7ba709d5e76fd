"""One module per benchmark group for ``cutwatch bench``.

A module ``bench_<group>.py`` is the group ``<group>`` with underscores written as
hyphens (``bench_tool_wear`` -> ``tool-wear``; :func:`server.cli.commands.bench.group_name`).
It defines ``measure(*, repeats: int, quick: bool) -> dict``; the dict holds medians (and
the configuration measured). The stage group's ``realtime_factor`` is reported at the top
level of ``cutwatch bench --json``.
"""
