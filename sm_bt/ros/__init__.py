"""The ROS 2 adapters: a backend over real lifecycle nodes, the mode manager node, simulated pilot
nodes. Needs the ``ros`` extra (rclpy and system_modes_msgs); nothing else in sm_bt imports this."""
