"""gsp_platform_bridge: the suite's platform protocol over a ros2_control joint_trajectory_controller."""
