"""Pybullet simulator of Roger-the-Crab: robot, servo controllers, Phong retinas, haptics, world files."""
