"""Sub-commands of ``cutwatch`` (one module each; see :mod:`server.cli.main`)."""
