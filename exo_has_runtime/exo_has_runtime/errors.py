"""Exceptions of exo_has_runtime: bags, replay, message types and command lines.

Every error raised on purpose by this package derives from :class:`RuntimeSeamError` (the name
is kept from the time this package was a seam between backends: other packages catch it). The
conditions rclpy knows (a parameter of the wrong type, a shutdown while spinning) are rclpy's
own exceptions, raised by rclpy.
"""

from __future__ import annotations


class RuntimeSeamError(Exception):
    """Base of every error raised by exo_has_runtime."""


class UnknownJointError(RuntimeSeamError, ValueError):
    """A joint name that is not one of the exoskeleton's, or not a hip's or a knee's."""


class UnknownMessageTypeError(RuntimeSeamError, LookupError):
    """A message type name that no known package defines, or that is malformed."""


class MalformedMessageError(RuntimeSeamError, ValueError):
    """Serialized bytes that do not deserialize as the message type they are said to be."""


class CommandLineError(RuntimeSeamError, ValueError):
    """Malformed ROS command-line arguments or parameters file."""


class ContainerArgumentError(CommandLineError):
    """A container command line that names no node, or a node class that cannot be found."""


class BagError(RuntimeSeamError):
    """A bag that cannot be written, read or recovered."""


class BagNotFoundError(BagError, FileNotFoundError):
    """A bag path that does not exist."""

    def __str__(self) -> str:  # OSError would format its arguments as a tuple
        return str(self.args[0]) if self.args else ''


class MalformedBagError(BagError, ValueError):
    """Files that are not a readable rosbag2 bag, or not an MCAP file at all."""


class UnfinishedBagError(BagError):
    """A bag its writer never closed (no metadata.yaml): it must be recovered first."""


class ReplayError(RuntimeSeamError, ValueError):
    """Replay options that cannot be honoured: a rate that is not positive, an unknown topic."""


class HostsUnavailableError(RuntimeSeamError):
    """Two virtual hosts cannot be made here: not root, or a tool missing (the message says)."""


class DdsConfigurationError(RuntimeSeamError, ValueError):
    """DDS settings in the environment that a process cannot start with (the message names it)."""
