"""rclpy nodes, one Node class per module, each with ``main()``."""
