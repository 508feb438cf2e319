"""Choosing the torch device a job runs on."""

from __future__ import annotations

from rawsim.errors import ParameterError, check_choice


def resolve_device(name: str):
    """``auto`` → CUDA when available, else CPU; ``cuda`` without a GPU is an error.

    Returns a ``torch.device``; ``cpu`` is answered without importing torch (the
    string ``"cpu"``, which torch accepts wherever a device goes).
    """
    check_choice("device", name, ("auto", "cpu", "cuda"))
    if name == "cpu":
        return "cpu"
    import torch

    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise ParameterError("--device cuda: no CUDA device is available")
    return torch.device(name)
