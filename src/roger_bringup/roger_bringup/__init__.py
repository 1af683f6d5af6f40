"""The launcher: orchestrator, the roger command line, and the monitor, recorder and view
nodes."""
