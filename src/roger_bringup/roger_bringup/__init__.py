"""Orchestrator, roger command line, experiments and in-process core loop."""
