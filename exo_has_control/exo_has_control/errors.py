"""Exceptions of exo_has_control: sessions and what they are given."""

from __future__ import annotations


class ControlError(Exception):
    """Base of every error raised on purpose by exo_has_control."""


class DomainInUseError(ControlError):
    """Nodes of another session (or started by hand) already run on a session's ROS domain."""
