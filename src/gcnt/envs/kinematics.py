"""Body state helpers shared by the featurisers: positions relative to the torso and the linear
velocity of each body-frame origin, vectorised over sub-envs and limbs."""

from __future__ import annotations

import numpy as np

# a × b = a[_ROLL1] * b[_ROLL2] - a[_ROLL2] * b[_ROLL1]
_ROLL1 = np.array([1, 2, 0])
_ROLL2 = np.array([2, 0, 1])


def torso_relative_position(xpos: np.ndarray, mask: np.ndarray, out: np.ndarray) -> None:
    """Body positions [n, K, 3] into ``out``, x relative to the torso's (row 0) x; padded
    limbs' x (``mask`` 0) zeroed."""
    out[...] = xpos
    x = out[..., 0]
    x -= xpos[:, :1, 0]
    x *= mask


def origin_velocity(xpos: np.ndarray, com: np.ndarray, cvel: np.ndarray, out: np.ndarray) -> None:
    """Linear velocity of each body-frame origin p into ``out`` [n, K, 3]: v(c) + ω × (p − c),
    from MuJoCo's ``cvel`` [n, K, 6] (about the subtree centre of mass ``com`` [n, 3])."""
    w = cvel[..., :3]
    r = xpos - com[:, None, :]
    np.multiply(w[..., _ROLL1], r[..., _ROLL2], out=out)
    out -= w[..., _ROLL2] * r[..., _ROLL1]
    out += cvel[..., 3:]
