"""Attention window, interest, spatial map, straightforward and Q-learning policies."""
