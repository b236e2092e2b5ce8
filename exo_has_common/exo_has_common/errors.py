"""Exceptions of exo_has_common, and :class:`ExoHasError`, the root of every exo_has error.

Each package's own base (``NodeRuntimeError``, ``SimError``, ``DriverError``,
``BringupError``) derives from :class:`ExoHasError`, so that a command line can catch what any
package raises on purpose in one clause and let everything else surface as the bug it is.
"""

from __future__ import annotations


class ExoHasError(Exception):
    """Base of every error raised on purpose by an exo_has package."""


class UnknownJointError(ExoHasError, ValueError):
    """A joint name that is not one of the exoskeleton's, or not a hip's or a knee's."""


class UnknownMessageTypeError(ExoHasError, LookupError):
    """A message type name that no known package defines, or that is malformed."""


class CommandLineError(ExoHasError, ValueError):
    """Malformed ROS command-line arguments or parameters file."""


class BagError(ExoHasError):
    """A bag that cannot be written, read or recovered."""


class BagNotFoundError(BagError, FileNotFoundError):
    """A bag path that does not exist."""

    def __str__(self) -> str:  # OSError would format its arguments as a tuple
        return str(self.args[0]) if self.args else ''


class MalformedBagError(BagError, ValueError):
    """Files that are not a readable rosbag2 bag, or not an MCAP file at all."""


class UnfinishedBagError(BagError):
    """A bag its writer never closed (no metadata.yaml): it must be recovered first."""
