"""Exception types and small argument checks shared by the whole package.

Every error a user can cause derives from :class:`RawsimError`; the CLI turns
these into one-line messages and exit codes, and shows tracebacks only with
``--debug``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

_CHECK_VALUES: ContextVar[bool] = ContextVar("rawsim_check_values", default=True)


class RawsimError(Exception):
    """Base class of every error rawsim raises on purpose."""


class ProfileError(RawsimError):
    """A sensor profile is missing, malformed or inconsistent."""


class UnsupportedInputError(RawsimError):
    """An input file cannot be read or is of a kind rawsim does not handle."""


class ParameterError(RawsimError, ValueError):
    """A function or option got a value outside its documented domain."""


class RawsimWarning(UserWarning):
    """What the Python API warns (:func:`warnings.warn`) where the command line prints a
    ``warning:`` line: an option asked for that cannot act on the data, a fallback."""


def check_choice(name: str, value: str, valid: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``valid``, else raise listing the valid names."""
    valid = tuple(valid)
    if value not in valid:
        raise ParameterError(f"unknown {name} {value!r}; valid: {', '.join(valid)}")
    return value


@contextmanager
def values_checked(enabled: bool) -> Iterator[None]:
    """Turn the NaN/inf scan of :func:`check_image` on or off inside the block.

    Pipelines check their input once, then run the stages over many strips with
    the scan off; shapes and dtypes are always checked.
    """
    token = _CHECK_VALUES.set(enabled)
    try:
        yield
    finally:
        _CHECK_VALUES.reset(token)


def check_image(x, name: str = "input", channels: int | None = None) -> None:
    """Check that ``x`` is a finite floating (B, C, H, W) tensor with ``channels`` channels."""
    import torch  # here, so that the torch-free paths can import this module

    if not isinstance(x, torch.Tensor):
        raise ParameterError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.ndim != 4:
        raise ParameterError(f"{name} must have shape (B, C, H, W), got {tuple(x.shape)}")
    if channels is not None and x.shape[1] != channels:
        raise ParameterError(f"{name} must have {channels} channel(s), got shape {tuple(x.shape)}")
    if not x.is_floating_point():
        raise ParameterError(f"{name} must be a floating tensor, got {x.dtype}")
    # A sum is one fast pass and is finite exactly when every element is (barring
    # overflow, which the exact check below then settles).
    if not _CHECK_VALUES.get():
        return
    if not bool(torch.isfinite(x.sum())) and not bool(torch.isfinite(x).all()):
        raise ParameterError(f"{name} contains NaN or infinite values")


def shown(path: str | os.PathLike) -> str:
    """A path as messages print it: quoted (Python's escapes) if it holds control
    characters or bytes that are not UTF-8, so one message stays one line."""
    text = str(path)
    return text if text.isprintable() else repr(text)
