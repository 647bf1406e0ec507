"""Benchmarks for `manus bench NAME`: one module each (see runs/cmd_bench.py)."""
