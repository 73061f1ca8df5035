"""The errors an input can legitimately cause, one class each; anything else raised inside circcal is a bug.

The command line prints an :class:`InputError` as one line and exits with :data:`EXIT_BAD_INPUT`; any other
exception keeps its traceback and exits with :data:`EXIT_INTERNAL_ERROR`, so a bug is never mistaken for a bad
file. Library callers catch :class:`InputError` (a ``ValueError``) for everything a user can fix.
"""

from __future__ import annotations

__all__ = [
    "InputError",
    "ImageError",
    "ModelFileError",
    "CalibrationError",
    "DegenerateViewsError",
    "EXIT_OK",
    "EXIT_FAILED",
    "EXIT_BAD_INPUT",
    "EXIT_INTERNAL_ERROR",
    "EXIT_INTERRUPTED",
    "EXIT_TERMINATED",
]

#: Exit codes of every ``circcal`` command.
EXIT_OK = 0
#: The job ran but its answer is negative: a check failed, no model could be made, an image was not found.
EXIT_FAILED = 1
#: The input is unusable (a file, a value, an option): the message says which and why.
EXIT_BAD_INPUT = 2
#: A bug in circcal (an exception no input should cause); the traceback is printed. (BSD sysexits' EX_SOFTWARE.)
EXIT_INTERNAL_ERROR = 70
#: Interrupted (Ctrl-C, SIGINT: 128 + 2): outputs already written are complete, nothing is half-written.
EXIT_INTERRUPTED = 130
#: Terminated (SIGTERM: 128 + 15, as a shell reports a process the signal ended), with the same guarantees.
EXIT_TERMINATED = 143


class InputError(ValueError):
    """Input a user can fix: a file, a value, an image, a set of views. The message names the culprit and says
    what was expected."""


class ImageError(InputError):
    """An image that cannot be used: unreadable, not decodable, or of a shape, type or size the detector cannot
    take."""


class ModelFileError(InputError):
    """A camera-model file that cannot be read, or that holds a value outside the model (the message names the
    file and the field)."""


class CalibrationError(InputError):
    """The observations cannot give a trustworthy camera model (the message says why and what is needed)."""


class DegenerateViewsError(CalibrationError):
    """The views leave the focal length (or the principal point) unobservable, e.g. all boards nearly
    fronto-parallel. ``views`` lists the offending view indices, ``condition`` the condition number measured."""

    def __init__(self, message: str, views: list[int], condition: float):
        super().__init__(message)
        self.views = views
        self.condition = condition
