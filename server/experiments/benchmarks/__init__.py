"""One module per benchmark group for ``cutwatch bench``.

A module ``bench_<group>.py`` is the group ``<group>`` with underscores written as
hyphens (``bench_tool_wear`` -> ``tool-wear``; :func:`server.cli.commands.bench.group_name`).
It defines ``measure(*, repeats: int, quick: bool) -> dict``; the dict holds medians (and
the configuration measured). The stage group's ``realtime_factor`` is reported at the top
level of ``cutwatch bench --json``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeAlias

#: what a group's result holds under a name, as ``cutwatch bench --json`` writes it: a
#: median, a count, a label or a flag, or lists and tables of them (never an array or
#: an object ``json.dumps`` refuses)
Figure: TypeAlias = float | int | str | bool | Sequence["Figure"] | Mapping[str, "Figure"] | None
#: a group's result (:func:`measure`'s): the figures by name
Figures: TypeAlias = dict[str, Figure]
