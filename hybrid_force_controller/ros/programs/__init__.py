"""Programs around the nodes: demo, bench, physics bench, recorder, trackers, load, CLI."""
