"""Engine layer: lifecycle planning, inference, mode manager and rules (pure Python, no rclpy)."""
