"""The paper's experiments without ROS: the in-process core loop, scoring, Table 2 and the
figures, Q-learning training, the Gymnasium environment and the view's composition."""
