"""Which floating-point platform a pinned digest was made on.

The pinned tests hash seeded sessions to the bit. A trial's outcome (what was found, reported, how many ticks) is
the same on every machine, but the last bits of a force trace are not: numpy picks its SIMD kernels and OpenBLAS
its BLAS kernels by the CPU it runs on, and a newer numpy or scipy may round a libm call differently. Stop 34 met
this: the same commit (39b683e) that passed CI on one VM gave other event and sample hashes on a new VM (AMD EPYC,
AVX2, no AVX-512), with identical trials and identical analysis tables. So bit-level pins are kept per platform,
keyed by what decides those bits; the portable parts are pinned once for all.
"""

from __future__ import annotations

import hashlib
import platform
import warnings


def platform_description() -> str:
    """Machine, the CPU features numpy dispatches on, and the numeric libraries' versions."""
    import numpy as np
    import scipy

    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy < 2
        from numpy.core._multiarray_umath import __cpu_features__ as features
    enabled = ",".join(sorted(name for name, on in features.items() if on))
    blas = np.show_config(mode="dicts").get("Build Dependencies", {}).get("blas", {})
    return (f"{platform.machine()}; cpu {enabled}; numpy {np.__version__}; scipy {scipy.__version__}; "
            f"blas {blas.get('name', '?')} {blas.get('version', '?')}")


def platform_key() -> str:
    """A short, stable name of :func:`platform_description`."""
    return hashlib.sha256(platform_description().encode()).hexdigest()[:12]


def no_pin_here(what: str, where: str) -> None:
    """Say, without failing, that this platform has no bit-level pin yet (the portable parts were still checked)."""
    warnings.warn(f"{what}: no pin for this platform ({platform_key()}: {platform_description()}) in {where}; "
                  "only the portable parts were compared. Pin it with STUDYCTL_REPIN=1 on a commit whose pins "
                  "pass on another platform.", stacklevel=2)
