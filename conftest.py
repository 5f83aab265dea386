"""Test-session setup shared by every package's tests.

DDS must never leave the machine, and parallel test runs must not see each other:
every ROS process started by the tests inherits LOCALHOST discovery and this run's
own ROS_DOMAIN_ID (the Makefile picks one per run; a random one otherwise).
"""
import os
import random

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; RANGE is the setting
if not os.environ.get("ROS_DOMAIN_ID"):
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
