"""One module per benchmark group for ``cutwatch bench``.

Each module defines ``NAME`` and ``measure(*, repeats: int, quick: bool) -> dict``; the
dict holds medians (and the configuration measured). The stage module's
``realtime_factor`` is reported at the top level of ``cutwatch bench --json``.
"""
