"""gridrt applications: the viewer, the headless frame dump and the benchmarks (``gridrt ...``)."""
