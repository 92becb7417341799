"""The benchmarks, ``gridrt bench NAME``: main.py makes the ``bench`` parser with the options every
benchmark has and registers the benchmarks; each benchmark's module adds its subcommand, runs it and
writes its report (core.py, build.py, frame.py, trade.py, peers.py, start.py, packets.py,
looks.py; ``bench cluster`` is gridrt.app.cluster.scaling).  Beside them: the scenes and cameras
they use (scenes.py), shared option checks (options.py), statistics (stats.py), the machine record
(machine.py), files and figures (output.py), CPU pinning for the peers (affinity.py), the peers'
adapters (sides.py) and the brute-force reference caster (reference.py)."""
