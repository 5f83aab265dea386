"""Logs: bag IO, the readers of a robot's own topics, inspect, the log → samples pipeline."""
