"""The benchmarks: `gridrt bench core|build|frame|trade|peers`, their scenes, reports, plots and
the brute-force reference caster they measure accuracy against."""
