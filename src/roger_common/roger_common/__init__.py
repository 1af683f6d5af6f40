"""Shared plain-Python types and errors of the Roger packages (no ROS)."""
