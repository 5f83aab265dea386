"""Which shared-memory segments an rclpy node maps (results/LIVE_GRAPH.md, thirteenth session); run with the venv
under different ROS_AUTOMATIC_DISCOVERY_RANGE, FASTRTPS_DEFAULT_PROFILES_FILE, FASTDDS_BUILTIN_TRANSPORTS."""
import os
import time

import rclpy
from std_msgs.msg import String

rclpy.init()
n = rclpy.create_node("shmcheck")
p = n.create_publisher(String, "chatter_x", 10)
s = n.create_subscription(String, "chatter_x", lambda m: None, 10)
time.sleep(1.0)
maps = sorted({line.split()[-1] for line in open("/proc/self/maps") if "/dev/shm" in line})
print(os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE"), len(maps), maps[:4])
rclpy.shutdown()
