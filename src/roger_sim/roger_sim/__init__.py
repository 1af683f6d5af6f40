"""Pybullet simulator of Roger-the-Crab: robot, servos, Phong retinas, haptics, world files."""
