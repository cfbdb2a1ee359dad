"""The ROS 2 adapters: a backend over real lifecycle nodes (:mod:`~sm_bt.ros.backend` and the modules
it is built from), the mode manager node, the runtime that embeds a manager, simulated lifecycle
nodes, the CLI's client, ``/diagnostics`` and the snapshot streams. Needs the ``ros`` extra (rclpy
and system_modes_msgs); the CLI and the demo import the ones that need it only when asked for ROS."""
