"""Pure core: numpy and pinocchio only (no rclpy, no tools)."""
