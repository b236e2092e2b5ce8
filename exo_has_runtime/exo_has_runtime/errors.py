"""Exceptions of the exo_has runtime seam.

Every error raised on purpose by this package derives from :class:`RuntimeSeamError`. Where rclpy
has an exception for the same condition, the class here carries rclpy's name, so that node code
that catches it works on both backends.
"""

from __future__ import annotations


class RuntimeSeamError(Exception):
    """Base of every error raised by exo_has_runtime."""


class BackendError(RuntimeSeamError):
    """The requested backend cannot be used."""


class MessageDefinitionError(RuntimeSeamError):
    """A message definition (.msg file) is malformed or refers to an unknown type."""


class UnknownMessageTypeError(RuntimeSeamError, LookupError):
    """A message type name that no known package defines."""


class NameValidationError(RuntimeSeamError, ValueError):
    """A node name, namespace or topic name that ROS 2 would reject."""


class CommandLineError(RuntimeSeamError, ValueError):
    """Malformed ROS command-line arguments or parameters file."""


class TopicTypeMismatchError(RuntimeSeamError, TypeError):
    """A topic used with two different message types."""


class ParameterException(RuntimeSeamError):
    """Base of the parameter errors, named as in rclpy.exceptions."""


class ParameterNotDeclaredException(ParameterException, KeyError):
    """A parameter that was not declared."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ''


class ParameterAlreadyDeclaredException(ParameterException):
    """A parameter declared twice."""


class InvalidParameterTypeException(ParameterException, TypeError):
    """A parameter value of another type than the declared one."""


class InvalidParameterValueException(ParameterException, ValueError):
    """A parameter value outside its declared range or rejected by a callback."""


class ParameterImmutableException(ParameterException):
    """An attempt to change a read-only parameter."""


class ExternalShutdownException(RuntimeSeamError):
    """The context was shut down from outside (a signal or another thread) while spinning."""


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
