"""Exceptions of exo_has_runtime: message types, replay, containers and the DDS settings.

Every error raised on purpose by this package derives from :class:`NodeRuntimeError`. The
conditions rclpy knows (a parameter of the wrong type, a shutdown while spinning) are rclpy's
own exceptions, raised by rclpy. Bag, joint-name and parameters-file errors are
exo_has_common's (:mod:`exo_has_common.errors`).
"""

from __future__ import annotations

from exo_has_common.errors import CommandLineError, ExoHasError


class NodeRuntimeError(ExoHasError):
    """Base of every error raised by exo_has_runtime."""


class MalformedMessageError(NodeRuntimeError, ValueError):
    """Serialized bytes that do not deserialize as the message type they are said to be."""


class ContainerArgumentError(NodeRuntimeError, CommandLineError):
    """A container command line that names no node, or a node class that cannot be found."""


class ReplayError(NodeRuntimeError, ValueError):
    """Replay options that cannot be honoured: a rate that is not positive, an unknown topic."""


class DdsConfigurationError(NodeRuntimeError, ValueError):
    """DDS settings in the environment that a process cannot start with (the message names it)."""
