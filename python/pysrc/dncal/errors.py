"""The exceptions dncal raises. Each is a :class:`DncalError` and also the built-in
exception a Python user would catch for it; the message is the one the ``dncal``
command prints for the same fault.

Arguments of the wrong type or layout (a float array where uint16 frames are needed, a
non-contiguous view) raise the built-in :class:`TypeError` or :class:`ValueError`
directly, naming the argument.
"""


class DncalError(Exception):
    """Any error of the dncal library."""


class InputError(DncalError, ValueError):
    """Bad input data: a file's or an array's contents break a rule (a LUT the core
    refuses, a histogram too sparse to flatten, a linearity set without light)."""


class DncalIOError(DncalError, OSError):
    """A file could not be read or written, or a path cannot be read or written as
    asked (a directory where a file is needed)."""


class OverBudgetError(DncalError, MemoryError):
    """The work would need more memory than the budget allows (see ``--max-memory``)."""


class ToolError(DncalError, RuntimeError):
    """A program the work needs (QEMU, numpy for a benchmark) failed or is missing."""


__all__ = ["DncalError", "InputError", "DncalIOError", "OverBudgetError", "ToolError"]
