"""Offline tools: paper, bench, demo, report, analysis, plots, bag I/O."""
