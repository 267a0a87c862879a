"""The controller node and its real-time path: the control thread, telemetry, diagnostics."""
