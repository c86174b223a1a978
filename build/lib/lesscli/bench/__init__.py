"""Benchmarks (``less bench NAME``): one module per benchmark, ``lesscli.bench.<name>``, holding what is
measured and the baseline measured beside it in the same run; ``timing`` holds the shared helpers.

A benchmark may use any library layer (sim, models, train, infer, metrics, mri, vision) but never the
CLI; its command ``lesscli.cli.bench_<name>`` parses options, calls the benchmark and emits the records.
Their figures live in ``lesscli.plots.sweeps``.
"""
