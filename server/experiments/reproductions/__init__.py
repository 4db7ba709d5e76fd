"""One module per reproduced paper experiment (see :mod:`server.experiments.reproduction`)."""
