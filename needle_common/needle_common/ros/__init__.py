"""The rclpy side shared by every node of the suite: command line, parameter declaration, the node runner."""
