"""Exceptions of exo_has_bringup: sessions, the hosts they run on, and what they are given."""

from __future__ import annotations

from exo_has_common.errors import ExoHasError


class BringupError(ExoHasError):
    """Base of every error raised on purpose by exo_has_bringup."""


class DomainInUseError(BringupError):
    """Nodes of another session (or started by hand) already run on a session's ROS domain."""


class HostsUnavailableError(BringupError):
    """Two virtual hosts cannot be made here: not root, or a tool missing (the message says)."""
