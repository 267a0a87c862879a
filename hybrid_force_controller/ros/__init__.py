"""rclpy adapters: nodes, parameter binding, diagnostics, recorder."""
