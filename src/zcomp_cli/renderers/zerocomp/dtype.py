"""Device and dtype policy of the zerocomp renderer, in one place.

GPU: bf16 where supported, else fp16. bf16 is the default because it keeps fp32's
exponent range: SD 2.1 in fp16 can overflow to Inf/NaN (black images, DESIGN.md section 7)
and bf16 runs at the same tensor-core rate on Ampere and later. ``fp16-autocast`` is the
official ZeroComp setting (fp16 weights, ``torch.autocast(float16)``: norms and softmax
in fp32), for reproducing the official numbers exactly.
CPU: fp32 (half precision on CPU is slow and poorly supported).
Every model output that reaches an image goes through ``check_finite``: half precision
can overflow to Inf/NaN, and a NaN decoded as black must never be written.
"""

from __future__ import annotations

from zcomp_cli.errors import NumericalError, UsageError

DTYPES = ("auto", "fp32", "fp16", "bf16", "fp16-autocast")


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
    return {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16,
            "fp16-autocast": torch.float16}[dtype]


def autocast_context(dtype_setting: str, device: str):
    """The ``torch.autocast`` context for ``fp16-autocast`` (official), else a no-op."""
    import contextlib

    import torch

    if dtype_setting != "fp16-autocast":
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.split(":")[0], dtype=torch.float16)


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


# channels per map of the conditioning (``conventions.CONDITIONING_VARIANTS`` names them in order)
MAP_CHANNELS = {"depth": 1, "normals": 3, "albedo": 3, "shading": 3, "mask": 1, "roughness": 1, "metallic": 1}


def check_conditioning(cond, dtype) -> None:
    """Raise NumericalError, naming the map, where the conditioning (B x C x R x R, float32)
    does not fit ``dtype``: fp16's largest value is 65504, so a depth map in metres past
    65 km (or one in millimetres past 65 m) would be Inf and every step after NaN (the
    error then named the UNet's first step, not the depth)."""
    import numpy as np
    import torch

    from zcomp_cli.conventions import CONDITIONING_VARIANTS

    top = float(torch.finfo(dtype).max) if dtype.is_floating_point else float("inf")
    c = np.asarray(cond)
    big = np.abs(c) > top
    if not big.any():
        return
    names = [m for m in CONDITIONING_VARIANTS.get(c.shape[1], ()) for _ in range(MAP_CHANNELS[m])]
    k = int(np.flatnonzero(big.any(axis=(0, 2, 3)))[0])
    name = names[k] if k < len(names) else f"channel {k}"
    unit = " m" if name == "depth" else ""
    raise NumericalError(f"zerocomp: the {name} map reaches {float(np.abs(c[:, k]).max()):.4g}{unit}, past "
                         f"{dtype}'s largest value ({top:.0f}): it would be Inf in the model; use --dtype bf16 "
                         "or fp32" + (", or a depth map in metres" if name == "depth" else ""))
