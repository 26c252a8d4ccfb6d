"""The functional core: pure numpy/scipy, never imports rclpy (a test proves it)."""
