"""The rclpy side shared by every node of the suite: command line, parameter declaration, the node runner, input
reports on /diagnostics, TF output."""
