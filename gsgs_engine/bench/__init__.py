"""Measured benchmarks, one module each (`gsgs bench NAME`): each prints a table and writes JSON."""
