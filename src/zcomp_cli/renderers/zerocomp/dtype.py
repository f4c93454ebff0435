"""Device and dtype policy of the zerocomp renderer, in one place.

GPU: bf16 where supported, else fp16 (SD 2.1 overflows in fp16 less often with bf16).
CPU: fp32 (half precision on CPU is slow and poorly supported).
Every model output that reaches an image goes through ``check_finite``: half precision
can overflow to Inf/NaN, and a NaN decoded as black must never be written.
"""

from __future__ import annotations

from zcomp_cli.errors import NumericalError, UsageError

DTYPES = ("auto", "fp32", "fp16", "bf16")


def resolve_device(device: str = "auto") -> str:
    """'auto' -> 'cuda' when available else 'cpu'; any other torch device string passes."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise UsageError(f"device {device!r} requested but CUDA is not available")
    return device


def resolve_dtype(dtype: str, device: str):
    """Map a dtype setting to a torch dtype for ``device``."""
    import torch

    if dtype not in DTYPES:
        raise UsageError(f"unknown dtype {dtype!r}; choose one of {', '.join(DTYPES)}")
    if dtype == "auto":
        if not device.startswith("cuda"):
            return torch.float32
        return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
    return {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}[dtype]


def check_finite(x, stage: str):
    """Raise NumericalError if tensor ``x`` holds NaN/Inf (names the stage)."""
    import torch

    if not bool(torch.isfinite(x).all()):
        n = int((~torch.isfinite(x)).sum())
        raise NumericalError(
            f"zerocomp: {n} non-finite values after {stage} (dtype {x.dtype}); "
            "try --dtype fp32 or another device"
        )
    return x
