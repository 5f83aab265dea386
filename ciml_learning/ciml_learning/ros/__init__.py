"""The ROS runtime: executor, node helpers, real-time, containers, launch files, probe, replay, publishers."""
