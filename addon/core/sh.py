"""The real spherical-harmonics constants of the reference 3DGS code (forward.cu,
computeColorFromSH): the one place they are written in Python.

Colour = SH_C0 * sh[0] + 0.5 + (higher bands); file formats that store a DC colour in [0, 1]
(`.splat`, SuperSplat's compressed ply, glTF's fallback colour) convert with `dc_colour` and
`dc_from_colour`.
"""

from __future__ import annotations

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def dc_colour(f_dc):
    """The colour a DC coefficient gives alone, `0.5 + SH_C0 * f_dc` (in f_dc's float type)."""
    return 0.5 + SH_C0 * f_dc


def dc_from_colour(colour):
    """The DC coefficient of a colour, `(colour - 0.5) / SH_C0`: `dc_colour`'s inverse."""
    return (colour - 0.5) / SH_C0
