"""Typed exceptions of the Roger core. Each carries one line a user can act on."""

from __future__ import annotations


class RogerError(Exception):
    """Base of every error the core raises on purpose."""


class WorldFileError(RogerError):
    """A world file cannot be used. The message names the file, the object and the field."""

    def __init__(self, source: str, where: str, problem: str) -> None:
        self.source = source
        self.where = where
        self.problem = problem
        super().__init__(f"{source}: {where}: {problem}" if where else f"{source}: {problem}")


class ConfigError(RogerError, ValueError):
    """A configuration value is out of range; the message names the field and the value."""


class MemoryFileError(RogerError):
    """A long-term memory or Q-table file is missing, corrupt or incompatible."""


class MessageError(RogerError, ValueError):
    """A message a node received cannot be used (wrong encoding, size, NaN...)."""
