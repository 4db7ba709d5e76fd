"""The application, in folders by role (see docs/architecture.md).

- :mod:`server.cli` — the ``cutwatch`` command line;
- :mod:`server.service` — the FastAPI app, its routers, the live loop and the client hub;
- :mod:`server.pipeline` — the live pipeline, its parts and the measurement sources;
- :mod:`server.records` — measured-log files and residual reports;
- :mod:`server.experiments` — reproductions of the papers and benchmarks.

Composes :mod:`machine` and :mod:`estimators`; nothing imports it. Arrows point down the
list above (cli and service above pipeline above records), checked by import-linter in
``make lint``. This package imports none of its sub-packages: the command line must start
fast.
"""
